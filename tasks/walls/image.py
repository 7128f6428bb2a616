"""From the furniture slice to line segments (thesis 5.2.1-5.2.4.1): the projection image (eq 5.3),
binarization (eq 5.4 / 5.5), closing and Zhang-Suen skeleton (eq 5.6), probabilistic Hough."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.cloud import DegenerateInputError
from tasks.walls.config import WallsConfig


@dataclass(frozen=True)
class Grid:
    """The projection image's raster: square cells of `size` metres, pixel (col, row) <-> x, y."""

    origin: NDArray  # x, y of the lower-left corner of pixel (row 0, col 0)
    size: float
    shape: tuple[int, int]  # rows (y), cols (x)

    def to_metres(self, px: NDArray) -> NDArray:
        """Pixel coordinates (col, row), cell centres at integers, to x, y."""
        return self.origin + (np.asarray(px, dtype=np.float64) + 0.5) * self.size

    def to_pixels(self, xy: NDArray) -> NDArray:
        return (np.asarray(xy, dtype=np.float64) - self.origin) / self.size - 0.5


@dataclass(frozen=True)
class Projection:
    """The projection image (eq 5.3's N) and what the later steps need from the voxels."""

    counts: NDArray[np.float64]
    """(H, W) occupied voxels above each cell (row 0 = smallest y)."""
    wall_like: NDArray[np.bool_]
    """(H, W) cells whose data spans at least `min_column_height_m` and reaches the slice top."""
    tall: NDArray[np.bool_]
    """(H, W) cells whose data spans at least `min_column_height_m` (wherever their top is)."""
    top: NDArray[np.bool_]
    """(H, W) cells with data near the slice top (all True with the top-reach test off)."""
    low: NDArray[np.bool_]
    """(H, W) cells with data within `top_reach_m` of the slice bottom."""
    grid: Grid
    n_levels: int
    """Voxel layers in the slice (the largest possible count)."""
    cell: NDArray[np.int64]
    """(N,) every point's flat cell index."""
    open_top: bool = False
    """Nothing was seen above the slice (its top within `top_clear_m` of the given ceiling, which is then
    the walls' top: a handheld scan without a ceiling): furniture reaches the top like the walls."""


def projection_image(points: NDArray, cfg: WallsConfig, ceiling_z_m: float = math.inf) -> Projection:
    """Count the occupied voxels above each cell (eq 5.3) and mark the wall-like cells."""
    g = cfg.grid_size_m
    # per column: a min over axis 0 of the (N, 3) array costs ten times as much (the same numbers)
    lo = np.array([points[:, 0].min(), points[:, 1].min()]) - 2 * g
    hi = np.array([points[:, 0].max(), points[:, 1].max()]) + 2 * g
    shape = (math.ceil((hi[1] - lo[1]) / g), math.ceil((hi[0] - lo[0]) / g))
    if shape[0] * shape[1] > cfg.max_image_px:
        raise DegenerateInputError(
            f"slice spans {hi[0] - lo[0]:.1f} m x {hi[1] - lo[1]:.1f} m: over {cfg.max_image_px} pixels at "
            f"{g} m (not one room, or far outliers)"
        )
    grid = Grid(lo, g, shape)
    z = points[:, 2]
    z_lo = float(z.min())
    col = np.floor((points[:, 0] - lo[0]) / g).astype(np.int64)
    row = np.floor((points[:, 1] - lo[1]) / g).astype(np.int64)
    lev = np.floor((z - z_lo) / g).astype(np.int64)
    n_levels = int(lev.max()) + 1
    cell = row * shape[1] + col
    keys = cell * n_levels + lev
    if shape[0] * shape[1] * n_levels < 2**31:
        keys = keys.astype(np.int32)  # the same keys, sorted and divided in half the time
    keys.sort()  # a sort and a diff: much faster than np.unique's hashing here
    voxels = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
    vcell, vlev = np.divmod(voxels, n_levels)
    counts = np.bincount(vcell, minlength=shape[0] * shape[1]).reshape(shape).astype(np.float64)
    # voxels are sorted by cell, then level: each cell's lowest and highest voxel are its run's ends
    first = np.concatenate([[True], vcell[1:] != vcell[:-1]])
    last = np.concatenate([vcell[1:] != vcell[:-1], [True]])
    first_cell, first_lev = vcell[first], vlev[first]
    tall = np.zeros(shape[0] * shape[1], dtype=bool)
    extent = (vlev[last] - first_lev) * g
    tall[first_cell[extent >= cfg.min_column_height_m]] = True
    reach = cfg.top_reach_m if cfg.top_reach_m is not None else 0.25
    low = np.zeros_like(tall)
    low[first_cell[first_lev <= math.floor(reach / g)]] = True
    top = np.ones_like(tall)
    open_top = False
    if cfg.top_reach_m is not None:
        z_top = float(np.quantile(z, 0.999))
        lo_lev = math.floor((z_top - cfg.top_reach_m - z_lo) / g)
        hi_lev = n_levels
        if ceiling_z_m - z_top < cfg.top_clear_m:
            open_top = True
            # the slice holds the ceiling, whose stray points land in every column (a cabinet's too):
            # look for data between top_reach_m and top_clear_m below the ceiling instead
            hi_lev = max(lo_lev, math.floor((ceiling_z_m - cfg.top_clear_m - z_lo) / g))
        # data up there must go on downwards: a stray voxel high above the rest of its column is a flying
        # pixel of the wall behind a cabinet, seen over its top
        below = np.concatenate([[-(10**9)], vlev[:-1]])
        below[first] = -(10**9)
        joined = (vlev - below) * g <= cfg.top_max_gap_m
        in_band = (vlev >= lo_lev) & (vlev <= hi_lev) & joined
        top = np.zeros_like(tall)
        top[vcell[in_band]] = True
    return Projection(
        counts=counts,
        wall_like=(tall & top).reshape(shape),
        tall=tall.reshape(shape),
        top=top.reshape(shape),
        low=low.reshape(shape),
        grid=grid,
        n_levels=n_levels,
        cell=cell,
        open_top=open_top,
    )


def binarize(counts: NDArray, wall_like: NDArray, cfg: WallsConfig, alpha: float | None) -> NDArray[np.bool_]:
    """Eq 5.3 gray image, then eq 5.5 (alpha) or eq 5.4 (alpha None), restricted to the `wall_like` cells.

    Eq 5.5 reads I_T = G (1 - α) on the thesis' dark-is-dense picture; on I = N / N_max G it keeps the
    cells with I >= α G, so that clutter filling less than α of the slice height goes."""
    n_max = counts.max()
    if n_max <= 0:
        return np.zeros(counts.shape, dtype=bool)
    if alpha is None:
        gray = counts / n_max * cfg.gray_levels
        vals = gray[gray > 0]
        thr = vals.mean() - 1.65 * vals.std()
        return (gray >= max(thr, 1e-9)) & wall_like
    # the gray values of the wall-like cells only (a few per cent of the image), each computed as on the
    # whole image: the same cells
    out = np.zeros(counts.shape, dtype=bool)
    cells = np.flatnonzero(wall_like)
    out.flat[cells] = counts.flat[cells] / n_max * cfg.gray_levels >= alpha * cfg.gray_levels
    return out


def skeleton(binary: NDArray[np.bool_], cfg: WallsConfig) -> NDArray[np.bool_]:
    """3x3 closing (eq 5.6), then Zhang-Suen thinning, computed on the occupied bounding box."""
    from skimage.morphology import skeletonize

    out = np.zeros_like(binary)
    rows, cols = np.nonzero(binary.any(axis=1))[0], np.nonzero(binary.any(axis=0))[0]
    if len(rows) == 0:
        return out
    pad = cfg.closing_kernel_px + 1
    r0, r1 = max(rows[0] - pad, 0), min(rows[-1] + pad + 1, binary.shape[0])
    c0, c1 = max(cols[0] - pad, 0), min(cols[-1] + pad + 1, binary.shape[1])
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (cfg.closing_kernel_px, cfg.closing_kernel_px))
    closed = cv2.morphologyEx(binary[r0:r1, c0:c1].astype(np.uint8), cv2.MORPH_CLOSE, k)
    out[r0:r1, c0:c1] = skeletonize(closed.astype(bool), method="zhang")
    return out


def hough_segments(skel: NDArray[np.bool_], grid: Grid, cfg: WallsConfig) -> NDArray[np.float64]:
    """Probabilistic Hough segments (M, 4) in metres; β1..β3 converted from metres to pixels."""
    g = cfg.grid_size_m
    found = cv2.HoughLinesP(
        skel.astype(np.uint8) * 255,
        rho=1.0,
        theta=math.radians(cfg.hough_theta_deg),
        threshold=max(cfg.hough_min_px, round(cfg.hough_votes_m / g)),
        minLineLength=max(float(cfg.hough_min_px), cfg.hough_min_length_m / g),
        maxLineGap=max(0.0, cfg.hough_max_gap_m / g),
    )
    if found is None:
        return np.zeros((0, 4))
    px = found.reshape(-1, 4).astype(np.float64)
    return np.concatenate([grid.to_metres(px[:, :2]), grid.to_metres(px[:, 2:])], axis=1)


@dataclass(frozen=True)
class Coarse:
    """A coarser projection of the same slice, for the walls seen too sparsely for the fine grid (a stretch
    the camera passed quickly): on a 1 cm grid their points, centimetres apart, fill one voxel per cell at
    most, so that no cell is tall or full enough; a cell `factor` times wider gathers them."""

    proj: Projection
    factor: int
    rows: NDArray[np.int64]
    """(H,) the coarse row of each fine row."""
    cols: NDArray[np.int64]
    """(W,) the coarse column of each fine column."""


def coarse_projection(
    points: NDArray, fine: Projection, cfg: WallsConfig, ceiling_z_m: float
) -> Coarse | None:
    """The slice projected on a grid `sparse_grid_ratio` times the fine one (None when that is off or the
    ratio is under 2), with the map from fine to coarse cells."""
    k = round(cfg.sparse_grid_ratio)
    if k < 2:
        return None
    from dataclasses import replace

    proj = projection_image(points, replace(cfg, grid_size_m=k * fine.grid.size), ceiling_z_m)
    g = fine.grid
    centres = g.to_metres(np.column_stack([np.arange(max(g.shape)), np.arange(max(g.shape))]))
    px = np.floor((centres - proj.grid.origin) / proj.grid.size).astype(np.int64)
    rows = np.clip(px[: g.shape[0], 1], 0, proj.grid.shape[0] - 1)
    cols = np.clip(px[: g.shape[1], 0], 0, proj.grid.shape[1] - 1)
    return Coarse(proj, k, rows, cols)


def sparse_cells(binary: NDArray[np.bool_], coarse: Coarse, cfg: WallsConfig, alpha: float | None) -> NDArray:
    """(H, W) fine cells of the coarse wall cells (binarized as the fine ones are, and with data near the
    slice top) that lie further than two coarse cells from every fine wall cell: the sparsely seen walls, as
    bands one coarse cell wide, added where the fine image has nothing (a densely seen wall keeps its
    fine cells)."""
    cb = binarize(coarse.proj.counts, coarse.proj.wall_like, cfg, alpha)
    if not cb.any():
        return np.zeros_like(binary)
    k = coarse.factor
    near = cv2.dilate(binary.astype(np.uint8), np.ones((4 * k + 1, 4 * k + 1), np.uint8)).astype(bool)
    return cb[np.ix_(coarse.rows, coarse.cols)] & ~near
