"""Wall modelling of one room (thesis 5.2): from the furniture slice of a levelled cloud to a topologically
correct 2D model of the inner wall faces, extruded from floor to ceiling.

`model_walls(slice_points, floor_z_m, ceiling_z_m, cfg) -> WallModel` is pure: it reads and writes
nothing. Steps (thesis section in brackets):

1. projection image (5.2.1, eq 5.3): the number of occupied voxels above each grid cell, so that the
   image measures wall height rather than point density (overlapping frames count once);
2. binarization (5.2.2): eq 5.5 keeps the cells whose column is at least α = H_noise / H_filter full, i.e.
   clutter shorter than α of the slice disappears (eq 5.4, μ - 1.65σ, as the alternative). Cells' data
   must span some height (`min_column_height_m`): table tops and ceiling patches are flat. α is chosen
   automatically (see `choose alpha` below);
3. 3×3 closing, Zhang-Suen skeleton (5.2.3);
4. probabilistic Hough (5.2.4.1) with β1 votes, β2 minimum length, β3 maximum gap given in metres;
5. 3-level clustering and regression averaging (5.2.4.2, `tasks.lines.merge_segments`), then the
   top-reach test on the merged lines: walls go on up to the ceiling, furniture (a 2 m cabinet) and
   plants stop below it, so a line is kept when at least `min_top_share` of it has data near the slice
   top (`top_reach_shares`). Judged per line, not per cell: a partition's face seen from close range
   holds data only up to the camera's vertical view over most of its length, and reaches the top only
   where it was seen from farther away; a cabinet reaches it nowhere (its parts in another wall's
   noisy band, and lone flying pixels above it, do not count). A face seen only from close range, below
   the top on its whole length, stays when it is the other face of a thin free-standing wall whose first
   face reaches the top (`thin_wall_faces`). A long line that reaches the top nowhere stays when no wall
   reaching the top runs parallel and close behind it (`unshadowed_lines`): furniture is seen in front of
   a wall seen above it, while the walls of a corridor captured from a metre away never reach the top;
6. regularization (5.2.5.1, eq 5.9, `tasks.lines.regularize`), then each wall's offset is refined to the
   median of the slice points near it (the skeleton is only good to a pixel), and its ends are moved out
   along it as far as its data goes (`extend_to_data`: the skeleton stops short of a band's end);
7. topology (5.2.5.2, `tasks.lines.connect`): extension / trimming (trimming only overshoot, `trim_m`:
   not a wall's observed data back to a partition standing on it), perpendicular joins of free ends onto
   parallel walls (an oblique wall's corner is closed by extension), removal of extensions with less
   than `min_overlap` of data, one at a time (judged with the regularization rotation undone; an
   extension that closes a corner stays, see `tasks.lines.connect_detailed`), wall graph and room
   polygon. A join across an unseen wall between two parallel walls goes where the data holds it (the
   unseen wall's few points), else at the end of the one nearer the room's interior (its reflex corner,
   seen from anywhere in the room). The room is the largest face the walls enclose when the walls on or
   inside it hold most of the wall length; walls outside it (seen through doors and windows) are
   dropped, and so are dangling walls shorter than `min_wall_length_m`. Walls are turned to have the
   room on their left;
8. extrusion (5.2.6) to a triangle mesh, and a preview picture.

Choosing α: the thesis has a person raise α until the clutter disappears. Here every candidate α runs
steps 2-7 (without the point-level offset refinement) and the model is summarised as its set of walls.
Walls are stable over a wide range of α (their columns are full), clutter and noise are not (they fade
out gradually), and too large an α breaks the walls apart. The chosen α is the smallest of the longest
run of consecutive candidates that give a closed wall graph and the same walls (same count, every wall
end within `stable_tol_m` of a wall of the neighbour's model); without any closed model, the longest
run of equal models. The chosen α is then run again with the refinement. The choice, the reason and
the per-candidate summaries go to `metrics`. Occupancy alone cannot tell a tall cabinet from the wall
above a window (both fill part of the slice): the top-reach test does that, not α.

Measured (`python -m bench.walls_survey --split tune`, survey generator's rooms, Kinect v1 frames fused
with true poses): the per-cell top-reach test cut the partition stubs' faces seen from close range (2 of
6 rooms with a stub failed); per line, the stubs' faces scored 0.36-0.50 and every furniture line at
most 0.06 against `min_top_share` 0.25. Rooms meeting every target 20/24 -> 23/24 with the end extension and
the interior-first join (alcove accuracy 12.3 -> 11.0 mm). On the held-out buildings (`--split heldout`,
never tuned on), 17/24 -> 20/24 with the thin-wall faces, the one-at-a-time removal, `trim_m` and the
parallel-only joins; the remaining accuracy misses (15.5-16.2 mm, every wall 1-2 cm towards the room) were
the Kinect's radial depth error, which the register stage now takes out (`tasks.register.RadialDepthError`):
22/24, mean accuracy 10.4 -> 2.1 mm. The two rooms left each have a wall the capture never saw.
`unshadowed_lines` changed none of those 60 rooms (tune 23/24, held out 22/24, TLS 6/6 each); on data/mini's
hallway (placed by the IMU-track fallback, walls seen from a metre away: the long walls' top share 0.20
and 0.51, the end walls' 0) it took the model from 1 wall (completeness 0.42) to the 4 walls that close it
(completeness 1.00, correctness 1.00).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.cloud import DegenerateInputError
from tasks.lines import (
    OBSERVED,
    LinesConfig,
    angles,
    connect_detailed,
    is_closed,
    lengths,
    merge_segments,
    point_segment_distances,
    regularize,
    room_polygons,
    rotate_segments,
    sample_segments,
    transform_segments,
    wall_graph,
)


@dataclass(frozen=True)
class WallsConfig:
    """Settings of the wall modelling stage (thesis 5.2, table 6.3)."""

    grid_size_m: float = 0.01
    """Projection image pixel size = voxel size of the occupancy count (m)."""
    gray_levels: int = 255
    """G in eq 5.3 / 5.5."""
    binarization: Literal["alpha", "gaussian"] = "alpha"
    """"alpha": eq 5.5 with α = H_noise / H_filter; "gaussian": eq 5.4 (μ - 1.65σ of the occupied cells)."""
    alpha: float | None = None
    """Fixed α for eq 5.5; None chooses it automatically among `alpha_candidates`."""
    alpha_candidates: tuple[float, ...] = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5)
    """α values tried by the automatic choice, ascending."""
    top_reach_m: float | None = 0.25
    """Data within this distance below the top of the slice reaches the top (walls reach the ceiling,
    furniture does not; judged per merged line with `min_top_share`); None switches the test off."""
    top_max_gap_m: float = 0.1
    """A cell's data near the slice top counts only when the cell holds more data at most this far below it
    (a lone voxel up there is a flying pixel)."""
    top_clear_m: float = 0.1
    """When the slice reaches within this of the ceiling, the top-reach test looks for data from
    `top_reach_m` below the top up to this distance below the ceiling (a ceiling's stray points fall into
    every column above that)."""
    min_top_share: float = 0.25
    """A merged line is a wall when at least this share of its length lies on cells with data near the
    slice top (`top_reach_m`); the rest of it may stop lower (the sensor's view cut it off there)."""
    top_share_tol_m: float = 0.03
    """A point of a line counts as reaching the top when such a cell lies within this distance."""
    thin_wall_max_m: float = 0.3
    """A line below the slice top is still a wall when it is the other face of a free-standing wall at most
    this thick whose first face reaches the top (`thin_wall_faces`); 0 switches that off."""
    thin_wall_end_tol_m: float = 0.15
    """The two faces of such a wall end within this distance of each other, at the wall's free end."""
    thin_wall_clear_m: float = 0.3
    """...where no wall runs on beside the end, outward of either face, this far (a corner's wall would)."""
    shadow_m: float = 1.0
    """A line below the slice top is still a wall when it is at least `open_min_length_m` long and data
    reaching the top lies within this distance beside it (further than `shadow_gap_m`) along less than half
    its length (`unshadowed_lines`): furniture stands in front of a wall that is seen above it, while a
    corridor seen from close range holds no data near the top anywhere (a cabinet's depth is under this,
    a corridor's width over it). 0 switches that off."""
    shadow_gap_m: float = 0.05
    """Top-reaching data nearer than this beside a line is the line's own (its noisy band)."""
    open_min_length_m: float = 0.75
    """...and longer than furniture is deep (wardrobes and kitchen units 0.6 m): a cabinet's side stands on
    the wall behind, which is not parallel to it."""
    min_column_height_m: float = 0.1
    """A wall cell's data must span at least this height (flat things: table tops, ceiling patches, stray
    points are not walls, however the counts compare)."""
    closing_kernel_px: int = 3
    """Morphological closing kernel (thesis: 3×3)."""
    hough_votes_m: float = 0.15
    """β1: minimum votes of a Hough line, as a length of skeleton (m)."""
    hough_min_length_m: float = 0.15
    """β2: minimum Hough segment length (m)."""
    hough_max_gap_m: float = 0.2
    """β3: maximum gap between points of one Hough segment (m)."""
    hough_min_px: int = 8
    """Floor under β1 and β2 in pixels: on a coarse grid a few pixels of a staircase skeleton are not a
    line (at 1 cm the metre values are larger and rule)."""
    hough_theta_deg: float = 0.5
    """Angular resolution of the Hough accumulator (degrees)."""
    lines: LinesConfig = field(default_factory=LinesConfig)
    """Clustering, regularization and topology thresholds (metres; `tasks.lines`)."""
    refine_band_m: float = 0.06
    """Slice points within this distance of a wall refine its offset (median); 0 switches it off."""
    support_tol_m: float = 0.05
    """A point of a wall counts as backed by data when a wall pixel lies within this distance."""
    end_tol_m: float = 0.02
    """A line's end is moved out along it while wall data lies within this distance of it (the Hough
    segments stop short of the data's end; `extend_to_data`)."""
    end_gap_m: float = 0.05
    """Gaps in that data up to this length do not stop the end (m)."""
    bridge_gaps_m: tuple[float, ...] = (1.2, 1.6, 2.0)
    """When the walls do not enclose the room, collinear pieces are joined across these larger gaps, and
    ends are extended to intersections this far, in turn (a wall hidden behind a partition or furniture, a
    corner the capture did not see in the slice), keeping the first that closes it; a bridged span between
    two junctions still needs data (the mouth of an alcove stays open), and so does a wall made only by
    extension that is longer than `lines.extend_m`."""
    stable_tol_m: float = 0.05
    """Two candidate models (automatic α) are equal when their walls lie within this of each other."""
    min_wall_length_m: float = 0.2
    """Dangling walls (one end free) shorter than this are dropped: skeleton spurs, not partitions (short
    walls joined at both ends, such as a reveal or a column face, stay)."""
    min_points: int = 100
    """Fewer slice points than this is a degenerate input."""
    min_slice_height_m: float = 0.2
    """A slice thinner than this (a single horizontal plane) is a degenerate input."""
    max_image_px: int = 36_000_000
    """Largest projection image (pixels); a larger extent is a degenerate input."""


@dataclass(frozen=True)
class WallModel:
    """A room's walls in the x-y frame of the levelled cloud (metres), extruded from floor to ceiling."""

    walls: NDArray[np.float64]
    """(M, 4) x0 y0 x1 y1 of the inner wall faces."""
    origin: NDArray[np.str_]
    """(M,) "observed" or "extended" (made only by extension, e.g. a perpendicular join)."""
    support: NDArray[np.float64]
    """(M,) share of each wall's length backed by data (0..1)."""
    floor_z_m: float
    ceiling_z_m: float
    polygon: Any
    """shapely Polygon of the room when the walls enclose one, else None."""
    mesh_vertices: NDArray[np.float64]
    """(V, 3) extruded walls (and floor and ceiling when closed)."""
    mesh_triangles: NDArray[np.int64]
    """(T, 3) vertex indices, counter-clockwise seen from inside the room."""
    preview: NDArray[np.uint8]
    """(H, W, 3) RGB: the projection image with the walls drawn over it, north up."""
    alpha: float | None
    """α used for eq 5.5 (None with eq 5.4)."""
    metrics: dict[str, Any]
    """Counts per step, α choice and reason, timings (s), warnings."""

    @property
    def height_m(self) -> float:
        return self.ceiling_z_m - self.floor_z_m

    @property
    def closed(self) -> bool:
        return self.polygon is not None

    def transformed(self, rotation_rad: float, translation_xy: NDArray) -> WallModel:
        """The model moved by the 2D rigid transform p -> R(rotation) p + t (z unchanged)."""
        import shapely.affinity

        c, s = math.cos(rotation_rad), math.sin(rotation_rad)
        r = np.array([[c, -s], [s, c]])
        t = np.asarray(translation_xy, dtype=np.float64).reshape(2)
        verts = self.mesh_vertices.copy()
        verts[:, :2] = verts[:, :2] @ r.T + t
        poly = None
        if self.polygon is not None:
            poly = shapely.affinity.affine_transform(self.polygon, [c, -s, s, c, t[0], t[1]])
        return replace(self, walls=transform_segments(self.walls, r, t), polygon=poly, mesh_vertices=verts)


# --------------------------------------------------------------------------------- projection image


@dataclass(frozen=True)
class _Grid:
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
    grid: _Grid
    n_levels: int
    """Voxel layers in the slice (the largest possible count)."""
    cell: NDArray[np.int64]
    """(N,) every point's flat cell index."""


def projection_image(points: NDArray, cfg: WallsConfig, ceiling_z_m: float = math.inf) -> Projection:
    """Count the occupied voxels above each cell (eq 5.3) and mark the wall-like cells."""
    g = cfg.grid_size_m
    lo = points[:, :2].min(axis=0) - 2 * g
    hi = points[:, :2].max(axis=0) + 2 * g
    shape = (math.ceil((hi[1] - lo[1]) / g), math.ceil((hi[0] - lo[0]) / g))
    if shape[0] * shape[1] > cfg.max_image_px:
        raise DegenerateInputError(
            f"slice spans {hi[0] - lo[0]:.1f} m x {hi[1] - lo[1]:.1f} m: over {cfg.max_image_px} pixels at "
            f"{g} m (not one room, or far outliers)"
        )
    grid = _Grid(lo, g, shape)
    z = points[:, 2]
    z_lo = float(z.min())
    col = np.floor((points[:, 0] - lo[0]) / g).astype(np.int64)
    row = np.floor((points[:, 1] - lo[1]) / g).astype(np.int64)
    lev = np.floor((z - z_lo) / g).astype(np.int64)
    n_levels = int(lev.max()) + 1
    cell = row * shape[1] + col
    keys = np.sort(cell * n_levels + lev)  # a sort and a diff: much faster than np.unique's hashing here
    voxels = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
    vcell, vlev = voxels // n_levels, voxels % n_levels
    counts = np.bincount(vcell, minlength=shape[0] * shape[1]).reshape(shape).astype(np.float64)
    # voxels are sorted by cell, then level: each cell's lowest and highest voxel are its run's ends
    first = np.concatenate([[True], vcell[1:] != vcell[:-1]])
    last = np.concatenate([vcell[1:] != vcell[:-1], [True]])
    tall = np.zeros(shape[0] * shape[1], dtype=bool)
    extent = (vlev[last] - vlev[first]) * g
    tall[vcell[first][extent >= cfg.min_column_height_m]] = True
    reach = cfg.top_reach_m if cfg.top_reach_m is not None else 0.25
    low = np.zeros_like(tall)
    low[vcell[first][vlev[first] <= math.floor(reach / g)]] = True
    top = np.ones_like(tall)
    if cfg.top_reach_m is not None:
        z_top = float(np.quantile(z, 0.999))
        lo_lev = math.floor((z_top - cfg.top_reach_m - z_lo) / g)
        hi_lev = n_levels
        if ceiling_z_m - z_top < cfg.top_clear_m:
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
    )


def binarize(counts: NDArray, wall_like: NDArray, cfg: WallsConfig, alpha: float | None) -> NDArray[np.bool_]:
    """Eq 5.3 gray image, then eq 5.5 (alpha) or eq 5.4 (alpha None), restricted to the `wall_like` cells.

    Eq 5.5 reads I_T = G (1 - α) on the thesis' dark-is-dense picture; on I = N / N_max G it keeps the
    cells with I >= α G, so that clutter filling less than α of the slice height goes."""
    n_max = counts.max()
    if n_max <= 0:
        return np.zeros(counts.shape, dtype=bool)
    gray = counts / n_max * cfg.gray_levels
    if alpha is None:
        vals = gray[gray > 0]
        thr = vals.mean() - 1.65 * vals.std()
        return (gray >= max(thr, 1e-9)) & wall_like
    return (gray >= alpha * cfg.gray_levels) & wall_like


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


def hough_segments(skel: NDArray[np.bool_], grid: _Grid, cfg: WallsConfig) -> NDArray[np.float64]:
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


# --------------------------------------------------------------------------------- lines to walls


def refine_offsets(
    walls: NDArray, xy: NDArray, pix: NDArray, grid: _Grid, band_m: float, iterations: int = 2
) -> NDArray:
    """Each wall moved along its normal to the median signed distance of the points within `band_m`
    of it (away from its ends by `band_m`, so that the neighbouring walls do not pull). `pix` (N,) is
    every point's flat pixel index in `grid`: points are found through a raster of the walls' bands."""
    out = walls.copy()
    if band_m <= 0 or len(xy) == 0 or len(walls) == 0:
        return out
    label = np.zeros(grid.shape, dtype=np.int32)
    px = grid.to_pixels(walls.reshape(-1, 2)).reshape(-1, 4)
    thick = 2 * math.ceil(band_m / grid.size) + 1
    for i, s in enumerate(px):
        cv2.line(label, (round(s[0]), round(s[1])), (round(s[2]), round(s[3])), i + 1, thick)
    owner = label.ravel()[pix] - 1
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(len(walls) + 1))
    for i, s in enumerate(out):
        a, b = s[:2], s[2:]
        L = float(np.hypot(*(b - a)))
        if L <= 2 * band_m:
            continue
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        pts = xy[order[bounds[i] : bounds[i + 1]]] - a
        t, d = pts @ u, pts @ n
        inside = (t > band_m) & (t < L - band_m)
        shift = 0.0
        for _ in range(iterations):
            sel = inside & (np.abs(d - shift) < band_m)
            if sel.sum() < 10:
                break
            shift = float(np.median(d[sel]))
        out[i] = s + np.concatenate([n, n]) * shift
    return out


def extend_to_data(
    lines: NDArray, binary: NDArray[np.bool_], grid: _Grid, tol_m: float, gap_m: float, max_m: float
) -> NDArray:
    """Every line's ends moved outward along the line as far as `binary` holds data within `tol_m` of it
    (gaps up to `gap_m` bridged, at most `max_m`). The skeleton turns off a band before its end (Zhang-Suen
    rounds a corner; a wall end seen against nothing frays), so the Hough segments stop short of where the
    wall's data ends; an end that reaches a perpendicular wall goes on into its band and is trimmed back
    to the intersection by the topology step."""
    out = np.asarray(lines, dtype=np.float64).copy()
    if len(out) == 0 or max_m <= 0:
        return out
    r = max(0, round(tol_m / grid.size))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    near = cv2.dilate(binary.astype(np.uint8), k).astype(bool)
    steps = np.arange(1, int(max_m / grid.size) + 1) * grid.size  # (S,) distances beyond the end
    max_gap = max(1, round(gap_m / grid.size))
    hi = np.array([binary.shape[1] - 1, binary.shape[0] - 1])
    for i, s in enumerate(out):
        a, b = s[:2], s[2:]
        L = float(np.hypot(*(b - a)))
        if L <= 0:
            continue
        u = (b - a) / L
        for end, direction in ((0, -u), (1, u)):
            p = s[2 * end : 2 * end + 2]
            px = np.rint(grid.to_pixels(p + steps[:, None] * direction)).astype(np.int64)
            inside = (px >= 0).all(axis=1) & (px <= hi).all(axis=1)
            hit = np.zeros(len(steps), dtype=bool)
            hit[inside] = near[px[inside, 1], px[inside, 0]]
            # walk out until the first run of more than max_gap samples without data
            miss = np.flatnonzero(~hit)
            run_end = len(steps)
            if len(miss) > max_gap and len(steps) > max_gap:
                runs = np.lib.stride_tricks.sliding_window_view(~hit, max_gap + 1).all(axis=1)
                if runs.any():
                    run_end = int(np.argmax(runs))
            last = np.flatnonzero(hit[:run_end])
            if len(last):
                out[i, 2 * end : 2 * end + 2] = p + steps[last[-1]] * direction
    return out


def _near_sampler(binary: NDArray[np.bool_], grid: _Grid, tol_m: float):
    """near(points (P, 2)) -> (P,) bool: a pixel of `binary` lies within tol_m of the point."""
    r = max(0, int(tol_m / grid.size))
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    disk = ((dx**2 + dy**2) * grid.size**2 <= tol_m**2 + 1e-12).astype(np.uint8)
    # one dilation by the disk, then a lookup per point
    reach = cv2.dilate(binary.astype(np.uint8), disk).astype(bool) if r else binary.astype(bool)
    hi = np.array([binary.shape[1] - 1, binary.shape[0] - 1])

    def near(points: NDArray) -> NDArray[np.bool_]:
        # the image border holds no data (a margin of empty cells), so clipping adds none
        px = np.clip(np.rint(grid.to_pixels(points)).astype(np.int64), 0, hi)
        return reach[px[:, 1], px[:, 0]]

    return near


def _support_sampler(binary: NDArray[np.bool_], grid: _Grid, tol_m: float):
    """share(segments (P, 4)) -> (P,): share of each segment's length within tol_m of a wall pixel."""
    near = _near_sampler(binary, grid, tol_m)

    def share(segments: NDArray) -> NDArray:
        if len(segments) == 0:
            return np.zeros(0)
        pts, owner = sample_segments(segments, grid.size)
        return np.bincount(owner, near(pts), len(segments)) / np.bincount(owner, minlength=len(segments))

    return share


class TopCells:
    """The wall cells with data near the slice top (binary & top), their centres in metres and point
    samplers by tolerance: made once per binary image, shared by the top-reach tests of every topology."""

    def __init__(self, cells: NDArray[np.bool_], grid: _Grid) -> None:
        self.cells = cells
        self.grid = grid
        rows, cols = np.nonzero(cells)
        self.xy = grid.to_metres(np.column_stack([cols, rows]))  # (K, 2)
        self._near: dict[float, Any] = {}

    def near(self, tol_m: float):
        """near(points (P, 2)) -> (P,) bool: such a cell lies within tol_m of the point."""
        if tol_m not in self._near:
            self._near[tol_m] = _near_sampler(self.cells, self.grid, tol_m)
        return self._near[tol_m]


@dataclass(frozen=True)
class _Candidate:
    alpha: float | None
    walls: NDArray
    origin: NDArray
    counts: dict[str, int]
    binary: NDArray
    polygon: Any
    """The room, when the walls enclose one (a partition stub may still dangle in it)."""

    @property
    def closed(self) -> bool:
        return self.polygon is not None


def _model_for(
    proj: Projection, cfg: WallsConfig, alpha: float | None, xy: NDArray | None = None
) -> _Candidate:
    """Steps 2-7 for one α; the slice points `xy` (N, 2), when given, refine the wall offsets."""
    grid = proj.grid
    # the tall cells go through the image steps; the top-reach test is made on the lines (`_topology`)
    binary = binarize(proj.counts, proj.tall, cfg, alpha)
    skel = skeleton(binary, cfg)
    hough = hough_segments(skel, grid, cfg)
    low_share = _support_sampler(proj.low, grid, cfg.support_tol_m)
    top = TopCells(binary & proj.top, grid)
    found = _topology(hough, cfg.lines, cfg, grid, binary, top, proj, low_share, xy)
    bridged = None
    for gap in cfg.bridge_gaps_m if found.polygon is None else ():
        # the unseen span may be a corner as well as a stretch of one wall: ends reach as far
        lines = replace(cfg.lines, max_gap_m=gap, extend_m=max(cfg.lines.extend_m, gap))
        wider = _topology(hough, lines, cfg, grid, binary, top, proj, low_share, xy)
        # a wall made only by extension (a perpendicular join) longer than the usual reach needs data:
        # without it the wider reach would cut off a poorly seen part of the room (behind a partition)
        made = wider.origin != OBSERVED
        long_made = made & (lengths(wider.walls) > cfg.lines.extend_m)
        if (
            wider.polygon is not None
            and not (wider.share(wider.walls[long_made]) < cfg.lines.min_overlap).any()
        ):
            found, bridged = wider, gap
            break
    stats = {
        "binary_px": int(found.binary.sum()),
        "skeleton_px": int(skel.sum()),
        "hough_segments": len(hough),
        "orientation_clusters": len(found.merged.orientation_deg),
        "merged_lines": len(found.merged.segments),
        "lines_below_top": found.below_top,
        "removed_extensions": len(found.conn.removed),
        "walls_outside_room": found.outside,
        "walls_hung_from_ceiling": int(found.hung.sum()),
        "bridged_gap_m": bridged,
        "walls": len(found.walls),
    }
    return _Candidate(alpha, found.walls, found.origin, stats, found.binary, found.polygon)


@dataclass(frozen=True)
class _Topology:
    merged: Any
    conn: Any
    walls: NDArray
    origin: NDArray
    polygon: Any
    outside: int
    hung: NDArray
    below_top: int
    """Merged lines dropped by the top-reach test."""
    binary: NDArray
    """The wall data: cells near the top, and the other tall cells along the kept lines."""
    share: Any
    """share(segments) -> (P,) support of segments by `binary`."""


def top_reach_shares(lines: NDArray, top: TopCells, tol_m: float, angle_tol_deg: float) -> NDArray:
    """(M,) share of each line's length within `tol_m` of a wall cell with data near the slice top.

    Every line is judged without its parts lying in the data band of a longer line that reaches the top
    on at least half its length (and is not parallel to it): there the other wall's top-reaching data covers
    it (a cabinet's side standing against a wall, and seen from across a large room, range noise spreads
    a wall over decimetres), which says nothing about its own top. A band's half-width is the 90th
    percentile of the distance of the top-reaching cells along that line, plus `tol_m`. A line lying
    entirely in such bands gets 0."""
    if len(lines) == 0:
        return np.zeros(0)
    pts, owner = sample_segments(lines, top.grid.size)
    hit = top.near(tol_m)(pts)
    count = np.bincount(owner, minlength=len(lines)).astype(np.float64)
    shares = np.bincount(owner, hit, len(lines)) / count
    strong = np.flatnonzero(shares >= 0.5)
    if len(strong) == 0:
        return shares
    cell_xy = top.xy
    th = angles(lines)
    L = lengths(lines)
    sin_tol = math.sin(math.radians(angle_tol_deg))
    band: dict[int, float] = {}
    for i in range(len(lines)):
        others = strong[(np.abs(np.sin(th[strong] - th[i])) > sin_tol) & (L[strong] > L[i])]
        if len(others) == 0:
            continue
        mine = np.flatnonzero(owner == i)
        covered = np.zeros(len(mine), dtype=bool)
        for j in others:
            if j not in band:
                band[j] = _band_half_width(lines[j], cell_xy) + tol_m
            covered |= point_segment_distances(pts[mine], lines[j : j + 1])[:, 0] <= band[j]
        free = mine[~covered]
        shares[i] = float(hit[free].mean()) if len(free) else 0.0
    return shares


def thin_wall_faces(
    lines: NDArray, walls: NDArray, top: TopCells, cfg: WallsConfig, angle_tol_deg: float
) -> NDArray[np.bool_]:
    """(M,) lines that fail the top-reach test but are the other face of a thin free-standing wall (a
    partition stub) whose face in `walls` (M,) bool reaches the top. A face seen only from close range
    holds data up to the camera's vertical view, below the slice top; a cabinet's or a shelf's front does
    not reach the top either, but it is deeper than a partition or, when thin, it stands against a wall
    that goes on past it, or in a corner whose other wall closes its end.

    A line is such a face when a wall line parallel to it lies within `thin_wall_max_m` (and further than
    two grid cells), the two overlap on at least half the line's length, and they end together (within
    `thin_wall_end_tol_m`) at a free end: beside that end, outward of either face for `thin_wall_clear_m`,
    no top-reaching data (`top`) crosses the end's line (a corner's closing wall would)."""
    lines = np.asarray(lines, dtype=np.float64)
    out = np.zeros(len(lines), dtype=bool)
    if cfg.thin_wall_max_m <= 0 or not walls.any() or walls.all():
        return out
    grid = top.grid
    near = top.near(grid.size)
    sin_tol = math.sin(math.radians(angle_tol_deg))
    th = angles(lines)
    tol = cfg.thin_wall_end_tol_m
    window = np.arange(-tol / 2, 2 * tol + 1e-9, grid.size)  # along the faces, about the end and beyond
    reach = np.arange(2 * cfg.top_share_tol_m, cfg.thin_wall_clear_m + 1e-9, grid.size)  # outward of a face

    def crossed(p: NDArray, along: NDArray, outward: NDArray) -> bool:
        """Does data cross, on most of `reach` outward from p, the faces' direction `along` (out of the
        end) near the end or a little beyond it?"""
        pts = p + window[:, None, None] * along + reach[None, :, None] * outward
        hit = near(pts.reshape(-1, 2)).reshape(len(window), len(reach)).any(axis=0)
        return bool(hit.mean() >= 0.5)

    for i in np.flatnonzero(~walls):
        a, b = lines[i, :2], lines[i, 2:]
        L = float(np.hypot(*(b - a)))
        if L <= 0:
            continue
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        for j in np.flatnonzero(walls & (np.abs(np.sin(th - th[i])) < sin_tol)):
            pa, pb = lines[j, :2] - a, lines[j, 2:] - a
            offset = 0.5 * float(pa @ n + pb @ n)
            if not 2 * grid.size < abs(offset) <= cfg.thin_wall_max_m:
                continue
            tj = np.sort([pa @ u, pb @ u])
            if min(L, tj[1]) - max(0.0, tj[0]) < 0.5 * L:
                continue
            side = math.copysign(1.0, offset) * n  # from this face towards the other
            for t_end, t_other, along in ((0.0, tj[0], -u), (L, tj[1], u)):
                if abs(t_end - t_other) > tol:
                    continue
                p = a + 0.5 * (t_end + t_other) * u
                if not crossed(p, along, -side) and not crossed(p + offset * n, along, side):
                    out[i] = True
    return out


def unshadowed_lines(
    lines: NDArray, walls: NDArray[np.bool_], top: TopCells, cfg: WallsConfig
) -> NDArray[np.bool_]:
    """(M,) lines outside `walls` (those reaching the slice top) that are at least `open_min_length_m`
    long and that top-reaching data beside them does not shadow: cells of `top` or points of the
    lines in `walls`, between `shadow_gap_m` and `shadow_m` away on either side, along at least half the
    line's length (in 10 cm bins; the wall lines count where the data above a cabinet is sparse, as from a
    distant scanner). The top-reach test needs a sensor that saw up to the slice top; where it
    did not (a corridor's walls seen from a metre away by a camera with a 43° vertical view), nothing says
    that a line is furniture, and the line stays (as it does in the thesis, which has no such test).
    Furniture stands in front of a wall seen above it, so its front is shadowed (a partition's face by its
    other face, which `thin_wall_faces` judges). Nothing is exempted when no line reaches the top: the slice
    then holds no wall to judge against (clutter only)."""
    lines = np.asarray(lines, dtype=np.float64)
    out = np.zeros(len(lines), dtype=bool)
    if cfg.shadow_m <= 0 or not walls.any():
        return out
    cell_xy = np.concatenate([top.xy, sample_segments(lines[walls], top.grid.size)[0]])
    L = lengths(lines)
    bin_m = 0.1
    for i in np.flatnonzero(~walls & (L >= cfg.open_min_length_m)):
        a = lines[i, :2]
        u = (lines[i, 2:] - a) / L[i]
        rel = cell_xy - a
        t, d = rel @ u, np.abs(rel @ np.array([-u[1], u[0]]))
        beside = (t >= 0) & (t < L[i]) & (d > cfg.shadow_gap_m) & (d <= cfg.shadow_m)
        n_bins = max(1, math.ceil(L[i] / bin_m))
        per_bin = np.bincount(np.minimum((t[beside] / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins)
        out[i] = float((per_bin > 0).mean()) < 0.5
    return out


def _band_half_width(line: NDArray, cell_xy: NDArray, window_m: float = 0.3, share: float = 0.9) -> float:
    """The `share` quantile of the distance to `line` of the cells within `window_m` of it, beside the
    middle 80 % of its span (clear of the walls at its ends): how far its data spreads across it."""
    a, b = line[:2], line[2:]
    L = float(np.hypot(*(b - a)))
    if L <= 0 or len(cell_xy) == 0:
        return 0.0
    u = (b - a) / L
    rel = cell_xy - a
    t, d = rel @ u, np.abs(rel @ np.array([-u[1], u[0]]))
    sel = (t >= 0.1 * L) & (t <= 0.9 * L) & (d <= window_m)
    return float(np.quantile(d[sel], share)) if sel.any() else 0.0


def _wall_data(binary: NDArray, top: NDArray, lines: NDArray, grid: _Grid, tol_m: float) -> NDArray:
    """The binary cells that are wall data: those near the slice top, and the others within `tol_m` of
    a kept line (the part of a wall seen below the top). A cabinet's cells, away from every kept line,
    do not back an extension."""
    near = np.zeros(binary.shape, dtype=np.uint8)
    px = grid.to_pixels(lines.reshape(-1, 2)).reshape(-1, 4) if len(lines) else np.zeros((0, 4))
    thick = 2 * math.ceil(tol_m / grid.size) + 1
    for s in px:
        cv2.line(near, (round(s[0]), round(s[1])), (round(s[2]), round(s[3])), 1, thick)
    return binary & (top | near.astype(bool))


def _topology(
    hough: NDArray,
    lcfg: LinesConfig,
    cfg: WallsConfig,
    grid: _Grid,
    binary: NDArray,
    top: TopCells,
    proj: Projection,
    low_share,
    xy: NDArray | None,
) -> _Topology:
    """Steps 5-7 on the Hough segments: merge, the top-reach test, regularize, refine (when `xy` is
    given), connect, then keep the room's walls."""
    merged = merge_segments(hough, lcfg)
    lines = merged.segments
    below_top = 0
    if cfg.top_reach_m is not None and len(lines):
        reach = top_reach_shares(lines, top, cfg.top_share_tol_m, lcfg.angle_tol_deg)
        keep = reach >= cfg.min_top_share
        keep = keep | thin_wall_faces(lines, keep, top, cfg, lcfg.angle_tol_deg)
        keep |= unshadowed_lines(lines, keep, top, cfg)
        below_top = int((~keep).sum())
        lines = lines[keep]
    wall_data = _wall_data(binary, proj.top, lines, grid, cfg.support_tol_m)
    share = _support_sampler(wall_data, grid, cfg.support_tol_m)
    reg, rotation = regularize(lines, lcfg)
    refined = reg if xy is None else refine_offsets(reg, xy, proj.cell, grid, cfg.refine_band_m)
    refined = extend_to_data(refined, wall_data, grid, cfg.end_tol_m, cfg.end_gap_m, lcfg.extend_m)
    centres = 0.5 * (refined[:, :2] + refined[:, 2:])

    def support_fn(pieces: NDArray, parent: NDArray) -> NDArray:
        # undo the regularization rotation about the parent wall's centre before looking at the data
        rot = np.where(parent >= 0, -rotation[np.maximum(parent, 0)], 0.0)
        c = np.where(
            parent[:, None] >= 0, centres[np.maximum(parent, 0)], 0.5 * (pieces[:, :2] + pieces[:, 2:])
        )
        return share(rotate_segments(pieces, rot, c))

    # the room's interior, for the joins across unseen walls: the walls' length-weighted centre
    weight = lengths(refined)
    interior = (centres * weight[:, None]).sum(axis=0) / weight.sum() if weight.sum() > 0 else None
    conn = connect_detailed(refined, lcfg, support_fn, interior)
    walls, origin = _drop_short_stubs(conn.segments, conn.origin, cfg.min_wall_length_m)
    polygon, walls, origin, outside = _room_polygon(walls, origin, grid.size)
    hung = _hung_from_ceiling(walls, polygon, low_share)
    if hung.any():
        walls, origin = walls[~hung], origin[~hung]
        polygon, walls, origin, _ = _room_polygon(walls, origin, grid.size)
    return _Topology(merged, conn, walls, origin, polygon, outside, hung, below_top, wall_data, share)


def _hung_from_ceiling(walls: NDArray, polygon: Any, low_share) -> NDArray[np.bool_]:
    """Walls of free-standing groups (not touching the room's outline) whose data stays clear of the
    slice bottom on most of their length: lamps and shades hanging from the ceiling. A column goes down
    to the floor; furniture standing on it was removed by the top-reach test."""
    hung = np.zeros(len(walls), dtype=bool)
    if polygon is None or len(walls) == 0:
        return hung
    import shapely
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(walls)
    ends = np.concatenate([walls[:, :2], walls[:, 2:]])
    touch = point_segment_distances(ends, walls) <= 1e-6
    i, j = np.nonzero(touch)
    adj = coo_matrix((np.ones(len(i)), (i % n, j)), shape=(n, n))
    _, comp = connected_components(adj, directed=False)
    mid = 0.5 * (walls[:, :2] + walls[:, 2:])
    on_outline = shapely.distance(polygon.exterior, shapely.points(mid)) <= 1e-6
    share = low_share(walls)
    L = lengths(walls)
    for c in np.unique(comp):
        m = comp == c
        if not on_outline[m].any() and (share[m] * L[m]).sum() < 0.5 * L[m].sum():
            hung[m] = True
    return hung


def _drop_short_stubs(walls: NDArray, origin: NDArray, min_length_m: float) -> tuple[NDArray, NDArray]:
    """Walls shorter than min_length_m with a free end go (short connectors between walls stay)."""
    short = lengths(walls) < min_length_m
    if not short.any():
        return walls, origin
    ends = np.concatenate([walls[:, :2], walls[:, 2:]])
    d = point_segment_distances(ends, walls)
    n = len(walls)
    d[np.arange(2 * n), np.tile(np.arange(n), 2)] = np.inf
    free = d.min(axis=1) > 1e-6 if n > 1 else np.ones(2 * n, dtype=bool)
    drop = short & (free[:n] | free[n:])
    return walls[~drop], origin[~drop]


def _room_polygon(walls: NDArray, origin: NDArray, tol_m: float) -> tuple[Any, NDArray, NDArray, int]:
    """The room: the largest face the walls enclose, provided the walls on or inside its outline hold most
    of the wall length (else it is a column or a cupboard, not the room: None). With a room, the walls are
    clipped to its outline (a wall seen through a door, or a wall line running on past the room's
    corner, is not one of its inner faces). Returns (room, walls, origin, walls dropped)."""
    polys = room_polygons(walls) if len(walls) >= 3 else []
    if not polys:
        return None, walls, origin, 0
    import shapely
    from shapely.geometry import Polygon

    shell = Polygon(polys[0].exterior).buffer(tol_m, join_style="mitre")
    lines = shapely.linestrings(walls.reshape(-1, 2, 2))
    inner = shapely.intersection(lines, shell)
    L = lengths(walls)
    kept_len = shapely.length(inner)
    if kept_len.sum() < 0.5 * L.sum():
        return None, walls, origin, 0
    room = polys[0]
    corners = np.concatenate([np.asarray(r.coords) for r in [room.exterior, *room.interiors]])
    out, out_origin = [], []
    for wall, geom, o in zip(walls, inner, origin, strict=True):
        for part in shapely.get_parts(geom):
            # a wall cut in two (its span behind a partition stub lies outside the room) gives two walls
            if part.geom_type != "LineString" or part.length <= tol_m:
                continue
            c = np.asarray(part.coords)[[0, -1]]
            for k in (0, 1):
                # a cut end (the wall ran on past the room's corner) goes to that corner exactly
                if min(np.hypot(*(c[k] - wall[:2])), np.hypot(*(c[k] - wall[2:]))) > 1e-9:
                    d = np.hypot(*(corners - c[k]).T)
                    if d.min() <= 2 * tol_m:
                        c[k] = corners[int(np.argmin(d))]
            out.append([*c[0], *c[1]])
            out_origin.append(o)
    kept = np.array(out, dtype=np.float64).reshape(-1, 4)
    dropped = int((kept_len <= tol_m).sum())
    return polys[0], kept, np.array(out_origin, dtype=origin.dtype), dropped


def same_walls(a: NDArray, b: NDArray, tol_m: float) -> bool:
    """Equal wall sets: same count, and every endpoint of each within tol_m of a wall of the other."""
    if len(a) != len(b):
        return False
    if len(a) == 0:
        return True
    ea = np.concatenate([a[:, :2], a[:, 2:]])
    eb = np.concatenate([b[:, :2], b[:, 2:]])
    return bool(point_segment_distances(ea, b).min(axis=1).max() <= tol_m) and bool(
        point_segment_distances(eb, a).min(axis=1).max() <= tol_m
    )


def choose_alpha(cands: list[_Candidate], tol_m: float) -> tuple[int, str]:
    """Index of the chosen candidate and the reason (see the module docstring). Models closed as they
    are rank before models closed only by bridging wider gaps, which rank before unclosed ones."""
    n = len(cands)
    tiers = (
        ("closed", lambda c: c.closed and c.counts.get("bridged_gap_m") is None),
        ("closed (after bridging wider gaps)", lambda c: c.closed),
        ("unclosed (no candidate gave a closed wall graph)", lambda c: True),
    )
    for what, ok in tiers:
        best, best_len = -1, 0
        i = 0
        while i < n:
            if not ok(cands[i]) or len(cands[i].walls) == 0:
                i += 1
                continue
            j = i
            while j + 1 < n and ok(cands[j + 1]) and same_walls(cands[j].walls, cands[j + 1].walls, tol_m):
                j += 1
            if j - i + 1 > best_len:
                best, best_len = i, j - i + 1
            i = j + 1
        if best >= 0:
            return best, (
                f"smallest alpha of the longest run of equal {what} models: alpha={cands[best].alpha} stable "
                f"over {best_len} of {n} candidates"
            )
    return 0, "no candidate found any wall"


# --------------------------------------------------------------------------------- outputs


def extrude(walls: NDArray, floor_z: float, ceiling_z: float, polygon: Any) -> tuple[NDArray, NDArray]:
    """Wall quads from floor to ceiling (two triangles each), plus floor and ceiling caps when the room
    is closed. Walls must have the room on their left (`orient_walls`); every triangle then faces into
    the room (counter-clockwise seen from inside). Returns vertices (V, 3) and triangles (T, 3)."""
    m = len(walls)
    verts = np.zeros((4 * m, 3))
    verts[0::4, :2], verts[0::4, 2] = walls[:, :2], floor_z
    verts[1::4, :2], verts[1::4, 2] = walls[:, 2:], floor_z
    verts[2::4, :2], verts[2::4, 2] = walls[:, 2:], ceiling_z
    verts[3::4, :2], verts[3::4, 2] = walls[:, :2], ceiling_z
    base = 4 * np.arange(m)[:, None]
    tris = np.concatenate([base + np.array([0, 2, 1]), base + np.array([0, 3, 2])]).astype(np.int64)
    if polygon is not None:
        import shapely

        cap = shapely.constrained_delaunay_triangles(polygon)
        tri_xy = [np.asarray(t.exterior.coords)[:3] for t in shapely.get_parts(cap)]
        if tri_xy:
            txy = np.array(tri_xy)  # (T, 3, 2)
            # counter-clockwise seen from above for the floor (normal up, into the room), reversed above
            area = (txy[:, 1, 0] - txy[:, 0, 0]) * (txy[:, 2, 1] - txy[:, 0, 1]) - (
                txy[:, 2, 0] - txy[:, 0, 0]
            ) * (txy[:, 1, 1] - txy[:, 0, 1])
            txy[area < 0] = txy[area < 0][:, ::-1]
            k = len(txy)
            floor = np.concatenate([txy.reshape(-1, 2), np.full((3 * k, 1), floor_z)], axis=1)
            ceil = np.concatenate([txy.reshape(-1, 2), np.full((3 * k, 1), ceiling_z)], axis=1)
            n0 = len(verts)
            verts = np.concatenate([verts, floor, ceil])
            ft = n0 + np.arange(3 * k).reshape(k, 3)
            ct = (n0 + 3 * k + np.arange(3 * k).reshape(k, 3))[:, ::-1]
            tris = np.concatenate([tris, ft, ct])
    return verts, tris


def orient_walls(walls: NDArray, polygon: Any) -> NDArray:
    """Walls turned so that the room lies on their left (counter-clockwise round the room): judged by the
    room polygon when there is one, else by the side of the walls' length-weighted centre."""
    if len(walls) == 0:
        return walls.copy()
    d = walls[:, 2:] - walls[:, :2]
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    left = np.column_stack([-d[:, 1], d[:, 0]]) / L[:, None]
    mid = 0.5 * (walls[:, :2] + walls[:, 2:])
    if polygon is not None:
        import shapely

        probe = mid + left * np.minimum(0.01, 0.1 * L)[:, None]
        inside = shapely.contains_xy(polygon, probe[:, 0], probe[:, 1])
    else:
        centre = (mid * L[:, None]).sum(axis=0) / L.sum()
        inside = ((centre - mid) * left).sum(axis=1) >= 0
    out = walls.copy()
    out[~inside] = walls[~inside][:, [2, 3, 0, 1]]
    return out


def render_preview(
    counts: NDArray, binary: NDArray, walls: NDArray, origin: NDArray, grid: _Grid, min_side_px: int = 800
) -> NDArray:
    """RGB picture, north up: data in grey (darker = taller column), the cells kept as wall data in light
    blue, observed walls in dark blue, extended ones in orange, wall ends as red dots, a 1 m bar below.
    Coarse grids are enlarged (whole pixels) so that the longer side has at least `min_side_px`."""
    n_max = max(float(counts.max()), 1.0)
    grey = (255 - 140 * np.sqrt(counts / n_max)).astype(np.uint8)
    img = np.repeat(grey[..., None], 3, axis=2)
    img[binary] = (150, 190, 235)
    scale = int(min(10, max(1, math.ceil(min_side_px / max(counts.shape)))))
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = np.ascontiguousarray(img[::-1])  # north up: row 0 is the largest y
    h = img.shape[0]
    shift = 4  # sub-pixel drawing
    thick = 3

    def at(p: NDArray) -> tuple[int, int]:
        col, row = (p[0] + 0.5) * scale - 0.5, h - 1 - ((p[1] + 0.5) * scale - 0.5)
        return round(col * (1 << shift)), round(row * (1 << shift))

    px = grid.to_pixels(walls.reshape(-1, 2)).reshape(-1, 4) if len(walls) else np.zeros((0, 4))
    for s, o in zip(px, origin, strict=True):
        colour = (25, 60, 170) if o == OBSERVED else (240, 140, 20)
        cv2.line(img, at(s[:2]), at(s[2:]), colour, thick, cv2.LINE_AA, shift)
    for s in px:
        for p in (s[:2], s[2:]):
            cv2.circle(img, at(p), 5 << shift, (210, 30, 30), -1, cv2.LINE_AA, shift)
    bar = round(scale / grid.size)
    foot = np.full((34, img.shape[1], 3), 255, dtype=np.uint8)
    if img.shape[1] > bar + 60:
        cv2.rectangle(foot, (10, 14), (10 + bar, 20), (0, 0, 0), -1)
        cv2.putText(foot, "1 m", (16 + bar, 23), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([img, foot])


def _check_input(slice_points: NDArray, floor_z_m: float, ceiling_z_m: float, cfg: WallsConfig) -> NDArray:
    pts = np.asarray(slice_points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DegenerateInputError(f"slice points must be (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise DegenerateInputError(
            f"{int((~np.isfinite(pts).all(axis=1)).sum())} slice points are NaN or infinite"
        )
    if len(pts) < cfg.min_points:
        raise DegenerateInputError(f"slice has {len(pts)} points, at least {cfg.min_points} needed for walls")
    if not (math.isfinite(floor_z_m) and math.isfinite(ceiling_z_m) and ceiling_z_m > floor_z_m):
        raise DegenerateInputError(f"floor {floor_z_m} m and ceiling {ceiling_z_m} m do not bound a room")
    spread = float(np.quantile(pts[:, 2], 0.99) - np.quantile(pts[:, 2], 0.01))
    if spread < cfg.min_slice_height_m:
        raise DegenerateInputError(
            f"slice is {spread:.3f} m thick (a single horizontal plane?), at least {cfg.min_slice_height_m} m needed"
        )
    return pts


def model_walls(slice_points: NDArray, floor_z_m: float, ceiling_z_m: float, cfg: WallsConfig) -> WallModel:
    """The wall model of one room from the furniture slice (N, 3) of its levelled cloud (z up, metres).

    Raises DegenerateInputError (one line) for an input that cannot hold walls: too few points, NaN, a
    flat slice, an extent too large for the grid. A slice in which no wall is found gives an empty model
    with a warning in `metrics["warnings"]`."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pts = _check_input(slice_points, floor_z_m, ceiling_z_m, cfg)
    proj = projection_image(pts, cfg, ceiling_z_m)
    grid, counts = proj.grid, proj.counts
    xy = np.ascontiguousarray(pts[:, :2])
    timings["projection_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    if cfg.binarization == "gaussian":
        alphas: list[float | None] = [None]
    elif cfg.alpha is not None:
        alphas = [float(cfg.alpha)]
    else:
        alphas = sorted(float(a) for a in cfg.alpha_candidates)
    if len(alphas) == 1:
        cands = [_model_for(proj, cfg, alphas[0], xy)]
        chosen, reason = 0, ("eq 5.4 (mean - 1.65 sigma)" if alphas[0] is None else "alpha fixed in config")
        best = cands[0]
    else:
        # candidates are compared on the pixel-accurate model; the chosen one is refined on the points
        cands = [_model_for(proj, cfg, a) for a in alphas]
        chosen, reason = choose_alpha(cands, cfg.stable_tol_m)
        best = _model_for(proj, cfg, alphas[chosen], xy)
        if cands[chosen].closed and not best.closed:
            # the refinement moved a borderline corner out of reach: keep the pixel-accurate model
            best = cands[chosen]
            reason += "; offsets not refined (the refined walls did not close)"
    timings["walls_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    walls, origin = best.walls, best.origin
    share = _support_sampler(best.binary, grid, cfg.support_tol_m)
    support = share(walls)
    polygon = best.polygon
    walls = orient_walls(walls, polygon)
    verts, tris = extrude(walls, floor_z_m, ceiling_z_m, polygon)
    preview = render_preview(counts, best.binary, walls, origin, grid)
    timings["outputs_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0

    warnings = []
    if len(walls) == 0:
        warnings.append("no wall found in the slice")
    elif polygon is None:
        warnings.append("the walls do not enclose a room (open wall graph)")
    elif not is_closed(wall_graph(walls)):
        warnings.append("the walls enclose a room but some walls have free ends")
    metrics: dict[str, Any] = {
        "points": len(pts),
        "image_shape": list(counts.shape),
        "slice_voxel_layers": proj.n_levels,
        "alpha": best.alpha,
        "alpha_reason": reason,
        "alpha_candidates": [{"alpha": c.alpha, "closed": c.closed, **c.counts} for c in cands],
        **best.counts,
        "walls_observed": int((origin == OBSERVED).sum()),
        "walls_extended": int((origin != OBSERVED).sum()),
        "closed": polygon is not None,
        "room_area_m2": float(polygon.area) if polygon is not None else None,
        "orientations_deg": sorted({round(float(a), 2) for a in np.degrees(angles(walls))})
        if len(walls)
        else [],
        "timings": timings,
        "warnings": warnings,
    }
    return WallModel(
        walls=walls,
        origin=origin,
        support=support,
        floor_z_m=float(floor_z_m),
        ceiling_z_m=float(ceiling_z_m),
        polygon=polygon,
        mesh_vertices=verts,
        mesh_triangles=tris,
        preview=preview,
        alpha=best.alpha,
        metrics=metrics,
    )
