"""What the slice's data says about a line: where its offset and its ends lie (`refine_offsets`,
`extend_to_data`), how much of it is backed by data (samplers), and whether it is a wall rather than
furniture: the top-reach test (`top_reach_shares`) and the two kinds of line that stay below the slice top
(`thin_wall_faces`, `unshadowed_lines`)."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.connect import OBSERVED
from tasks.lines import angles, lengths, point_segment_distances, sample_segments
from tasks.walls.config import WallsConfig
from tasks.walls.image import Grid


def _band_points(walls: NDArray, xy: NDArray, pix: NDArray, grid: Grid, band_m: float) -> list[NDArray]:
    """Per wall, the points of `xy` (N, 2) in its band (within `band_m`, through a raster of the walls'
    bands: a point in two bands goes to the later wall). `pix` (N,) is every point's flat pixel index in
    `grid`."""
    label = np.zeros(grid.shape, dtype=np.int32)
    px = grid.to_pixels(walls.reshape(-1, 2)).reshape(-1, 4)
    thick = 2 * math.ceil(band_m / grid.size) + 1
    for i, s in enumerate(px):
        cv2.line(label, (round(s[0]), round(s[1])), (round(s[2]), round(s[3])), i + 1, thick)
    owner = label.ravel()[pix] - 1
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(len(walls) + 1))
    return [xy[order[bounds[i] : bounds[i + 1]]] for i in range(len(walls))]


def _own_points(
    wall: NDArray, pts: NDArray, band_m: float, iterations: int = 2
) -> tuple[NDArray, NDArray, float]:
    """The wall's own points of `pts` (K, 2): those away from its ends by `band_m` (the neighbouring walls
    do not pull) and within `band_m` of their median signed distance from it, found in `iterations` rounds.
    Returns their positions along the wall and signed distances from it (metres, from its first end, the
    distance along its left normal), and that median; none for a wall shorter than 2 `band_m` or with
    fewer than 10 such points."""
    a, b = wall[:2], wall[2:]
    L = float(np.hypot(*(b - a)))
    none = np.zeros(0)
    if L <= 2 * band_m:
        return none, none, 0.0
    u = (b - a) / L
    t, d = (pts - a) @ u, (pts - a) @ np.array([-u[1], u[0]])
    inside = (t > band_m) & (t < L - band_m)
    shift, sel = 0.0, np.zeros(len(pts), dtype=bool)
    for _ in range(iterations):
        sel = inside & (np.abs(d - shift) < band_m)
        if sel.sum() < 10:
            return none, none, shift
        shift = float(np.median(d[sel]))
    return t[sel], d[sel], shift


def refine_offsets(walls: NDArray, xy: NDArray, pix: NDArray, grid: Grid, band_m: float) -> NDArray:
    """Each wall moved along its normal to the median signed distance of the points within `band_m`
    of it (away from its ends by `band_m`, so that the neighbouring walls do not pull). `pix` (N,) is
    every point's flat pixel index in `grid`: points are found through a raster of the walls' bands."""
    out = walls.copy()
    if band_m <= 0 or len(xy) == 0 or len(walls) == 0:
        return out
    for i, pts in enumerate(_band_points(walls, xy, pix, grid, band_m)):
        _, _, shift = _own_points(walls[i], pts, band_m)
        u = (walls[i, 2:] - walls[i, :2]) / max(float(np.hypot(*(walls[i, 2:] - walls[i, :2]))), 1e-12)
        out[i] = walls[i] + np.array([-u[1], u[0], -u[1], u[0]]) * shift
    return out


FACES_MIN_BINS = 5
"""`two_faces`: a wall's two faces are judged along at least this many bins (0.5 m of 10 cm bins, clear of its
ends): a few decimetres of furniture side show peaks as well."""


def two_faces(
    walls: NDArray, xy: NDArray, pix: NDArray, grid: Grid, band_m: float, min_gap_m: float, bin_m: float = 0.1
) -> NDArray[np.float64]:
    """(M, 2) for each wall whose band (`band_m`, away from its ends) holds two faces, their offsets from it
    (along its left normal, metres; NaN for the others): a thin partition whose faces, `min_gap_m` or more
    apart, one binarization took as one wall. Two faces are two peaks of the points' offsets (1 cm bins) at
    least `min_gap_m` apart, with at most a quarter of the smaller peak between them, each running along at
    least half the wall (`bin_m` bins, at least `FACES_MIN_BINS` of them), neither in the band's outermost
    bin (there the band cuts off the tail of a surface beyond it: the partition's other face, found already
    when the line lies on one). A room's wall shows the room one face; a cabinet's front before it stands
    further off or along a part of it."""
    out = np.full((len(walls), 2), np.nan)
    if band_m <= 0 or min_gap_m <= 0 or len(xy) == 0:
        return out
    step = 0.01
    edges = np.arange(-band_m, band_m + step / 2, step)
    centres = 0.5 * (edges[1:] + edges[:-1])
    for i, pts in enumerate(_band_points(walls, xy, pix, grid, band_m)):
        a, b = walls[i, :2], walls[i, 2:]
        L = float(np.hypot(*(b - a)))
        if L - 2 * band_m < FACES_MIN_BINS * bin_m or len(pts) < 20:
            continue
        u = (b - a) / L
        t, d = (pts - a) @ u, (pts - a) @ np.array([-u[1], u[0]])
        inside = (t > band_m) & (t < L - band_m) & (np.abs(d) <= band_m)
        t, d = t[inside], d[inside]
        h = np.histogram(d, edges)[0]
        p1 = int(np.argmax(h))
        # a peak in the band's outermost bin is where the band cuts the tail of a surface beyond it off
        inner = np.ones(len(h), dtype=bool)
        inner[[0, -1]] = False
        if not inner[p1]:
            continue
        far = (np.abs(centres - centres[p1]) >= min_gap_m) & inner
        if not far.any() or h[far].max() == 0:
            continue
        p2 = int(np.flatnonzero(far)[np.argmax(h[far])])
        lo, hi = sorted((p1, p2))
        if h[lo + 1 : hi].min() > 0.25 * min(h[p1], h[p2]):
            continue
        n_bins = max(1, math.floor((L - 2 * band_m) / bin_m))
        faces = []
        for p in (lo, hi):
            on = np.abs(d - centres[p]) <= 0.02
            cover = np.bincount(
                np.minimum(((t[on] - band_m) / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins
            )
            faces.append((float(np.median(d[on])), float((cover > 0).mean())))
        if min(f[1] for f in faces) >= 0.5 and faces[1][0] - faces[0][0] >= min_gap_m:
            out[i] = [faces[0][0], faces[1][0]]
    return out


FACE_FOUND_M = 0.03
"""`split_faces`: a line parallel to a split line, along half of it and this near one of the two faces, is that
face found already."""


def split_faces(
    lines: NDArray, refined: NDArray, faces: NDArray, angle_tol_deg: float, tol_m: float
) -> tuple[NDArray, NDArray[np.intp]]:
    """The refined lines with each line that `two_faces` found two faces in (`faces` (M, 2), offsets from
    `lines`, NaN for the others) replaced by its first face, its second appended, and the lines that lie
    between the two faces along them (within `angle_tol_deg`; the partition's own skeleton pieces) dropped.
    A line one of whose faces is another line already (its band caught the tail of that line's points) stays
    as refined. Returns (lines (K, 4), the index in `lines` each comes from (K,))."""
    out = refined.copy()
    keep = np.ones(len(lines), dtype=bool)
    split = []
    sin_tol = math.sin(math.radians(angle_tol_deg))
    L = lengths(lines)
    d = lines[:, 2:] - lines[:, :2]
    for i in np.flatnonzero(np.isfinite(faces[:, 0])):
        u = d[i] / L[i]
        nrm = np.array([-u[1], u[0]])
        ends = lines.reshape(-1, 2, 2) - lines[i, :2]  # (M, 2 ends, 2)
        t, off = ends @ u, ends @ nrm
        parallel = np.abs(u[0] * d[:, 1] - u[1] * d[:, 0]) <= sin_tol * L
        parallel[i] = False
        overlap = np.clip(t.max(axis=1), 0, L[i]) - np.clip(t.min(axis=1), 0, L[i])
        found = np.abs(off.mean(axis=1)[:, None] - faces[i][None, :]).min(axis=1) <= FACE_FOUND_M
        if (parallel & (overlap >= 0.5 * L[i]) & found).any():
            continue
        between = ((off > faces[i, 0] + tol_m) & (off < faces[i, 1] - tol_m)).all(axis=1)
        along = ((t >= -tol_m) & (t <= L[i] + tol_m)).all(axis=1)
        keep &= ~(parallel & between & along)
        shift = np.tile(nrm, 2)
        out[i] = lines[i] + shift * faces[i, 0]
        split.append((i, lines[i] + shift * faces[i, 1]))
    keep[[i for i, _ in split]] = True
    src = np.concatenate([np.flatnonzero(keep), [i for i, _ in split]]).astype(np.intp)
    return np.concatenate([out[keep], np.array([f for _, f in split]).reshape(-1, 4)]), src


def refine_frames(
    walls: NDArray,
    held: NDArray,
    xy: NDArray,
    pix: NDArray,
    grid: Grid,
    band_m: float,
    max_rad: float,
    bin_m: float = 0.1,
) -> NDArray:
    """(M,) the turn (radians) that fits each frame of the regularized walls (M, 4) to its points: the
    walls sharing one direction or perpendicular to it (not `held`, those the regularization left at their
    own angle: each of them is its own frame). Along each wall, the median offset of its own points
    (`_own_points`) in every `bin_m` bin with at least 3: turning the frame by a small angle tilts every
    wall's offsets by the same slope along it, so the slope is fitted to all the frame's bins at once, each
    wall free in its offset (the pooled within-wall regression). Medians, bin by bin, follow the surface
    most of the points are on (a cabinet front a few cm before the wall over part of it does not tilt it),
    and every stretch of wall counts alike however densely it was seen. The regularization takes its angles
    from the Hough segments of the skeleton, good to a cell over a wall's length (0.1-0.3°: 1-3 cm at the
    ends of a 10 m wall); the points fix it to their noise over the frame's whole length. The two are
    weighed by their variances (the lines' a cell at each end: grid² / the sum of their squared lengths;
    the points' the bins' residual variance over their spread along the walls), so a frame of a few short,
    sparsely seen lines turns little. A turn larger than `max_rad` (the points do not say the same as the
    lines) is not made."""
    m = len(walls)
    out = np.zeros(m)
    if band_m <= 0 or len(xy) == 0 or m == 0:
        return out
    ang = angles(walls)
    key = np.where(held, -1 - np.arange(m), np.round(np.mod(ang, math.pi / 2) * 1e6).astype(np.int64))
    pts = _band_points(walls, xy, pix, grid, band_m)
    for k in np.unique(key):
        group = np.flatnonzero(key == k)
        sxy = sxx = 0.0
        parts: list[tuple[NDArray, NDArray]] = []
        for i in group:
            t, d, _ = _own_points(walls[i], pts[i], band_m)
            if len(t) == 0:
                continue
            cell = np.floor(t / bin_m).astype(np.int64)
            order = np.argsort(cell, kind="stable")
            cell, t, d = cell[order], t[order], d[order]
            starts = np.flatnonzero(np.r_[True, np.diff(cell) > 0])
            counts = np.diff(np.r_[starts, len(cell)])
            full = counts >= 3
            if full.sum() < 2:
                continue
            bins = [slice(s, s + c) for s, c in zip(starts[full], counts[full], strict=True)]
            tb = np.array([np.median(t[part]) for part in bins])
            db = np.array([np.median(d[part]) for part in bins])
            tb, db = tb - tb.mean(), db - db.mean()
            sxy += float(tb @ db)
            sxx += float(tb @ tb)
            parts.append((tb, db))
        if sxx <= 0:
            continue
        slope = sxy / sxx
        n_bins = sum(len(tb) for tb, _ in parts)
        if n_bins <= len(parts) + 1:
            continue
        res = sum(float(((db - slope * tb) ** 2).sum()) for tb, db in parts) / (n_bins - len(parts) - 1)
        var_points = res / sxx
        var_lines = grid.size**2 / float((lengths(walls[group]) ** 2).sum())
        turn = math.atan(slope) * var_lines / (var_lines + var_points)
        if abs(turn) <= max_rad:
            out[group] = turn
    return out


def extend_to_data(
    lines: NDArray, binary: NDArray[np.bool_], grid: Grid, tol_m: float, gap_m: float, max_m: float
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


def _near_sampler(binary: NDArray[np.bool_], grid: Grid, tol_m: float):
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


def support_sampler(binary: NDArray[np.bool_], grid: Grid, tol_m: float):
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

    def __init__(self, cells: NDArray[np.bool_], grid: Grid, data: NDArray[np.bool_] | None = None) -> None:
        self.cells = cells
        self.grid = grid
        rows, cols = np.nonzero(cells)
        self.xy = grid.to_metres(np.column_stack([cols, rows]))  # (K, 2)
        rows, cols = np.nonzero(cells if data is None else data)
        self.data_xy = grid.to_metres(np.column_stack([cols, rows]))
        """(D, 2) the centres of all wall cells (`data`: the binary image, at any height), for `own_band`."""
        self._near: dict[float, Any] = {}

    def near(self, tol_m: float):
        """near(points (P, 2)) -> (P,) bool: such a cell lies within tol_m of the point."""
        if tol_m not in self._near:
            self._near[tol_m] = _near_sampler(self.cells, self.grid, tol_m)
        return self._near[tol_m]


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
            # the faces' separation at this line's middle, off the wall line j (whose direction, over its
            # length, is the better known: a short line a degree or two off, carried to a long j's far end,
            # would put it nearer than it stands)
            uj = (pb - pa) / max(float(np.hypot(*(pb - pa))), 1e-12)
            nj = np.array([-uj[1], uj[0]])
            offset = float((pa - 0.5 * L * u) @ nj) * float(nj @ n)
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
    other face, which `thin_wall_faces` judges); a line of furniture size (`furniture_max_length_m`) is
    shadowed also by the wall lines' extensions (`lines.extend_m`) furniture-deep behind it
    (`furniture_min_depth_m` to `furniture_max_depth_m`): the wall goes on behind a wardrobe in a corner
    that hid it at every height. Nothing is exempted when no line reaches the top: the slice
    then holds no wall to judge against (clutter only)."""
    lines = np.asarray(lines, dtype=np.float64)
    out = np.zeros(len(lines), dtype=bool)
    if cfg.shadow_m <= 0 or not walls.any():
        return out
    cell_xy = np.concatenate([top.xy, sample_segments(lines[walls], top.grid.size)[0]])
    L = lengths(lines)
    bin_m = 0.1
    # a wall's line goes on behind furniture that hides it from the sensor (a wardrobe in a corner, the
    # wall above it unseen): its extension shadows a line standing furniture-deep in front of it
    w = lines[walls]
    wu = (w[:, 2:] - w[:, :2]) / np.maximum(lengths(w), 1e-12)[:, None]
    reach = cfg.lines.extend_m
    ext = np.concatenate(
        [
            np.column_stack([w[:, :2] - reach * wu, w[:, :2]]),
            np.column_stack([w[:, 2:], w[:, 2:] + reach * wu]),
        ]
    )
    ext_xy = sample_segments(ext, top.grid.size)[0]
    g = top.grid.size
    for i in np.flatnonzero(~walls & (L >= cfg.open_min_length_m)):
        a = lines[i, :2]
        u = (lines[i, 2:] - a) / L[i]
        rel = cell_xy - a
        t, sd = rel @ u, rel @ np.array([-u[1], u[0]])
        d = np.abs(sd)
        # the line's own data, smeared deeper than the gap (frames levelled a few degrees apart), is no shadow
        lo, hi = own_band(lines[i], top.data_xy, g)
        clear = (sd > max(cfg.shadow_gap_m, hi + g)) | (sd < -max(cfg.shadow_gap_m, -lo + g))
        beside = (t >= 0) & (t < L[i]) & clear & (d <= cfg.shadow_m)
        n_bins = max(1, math.ceil(L[i] / bin_m))
        per_bin = np.bincount(np.minimum((t[beside] / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins)
        if L[i] <= cfg.furniture_max_length_m and len(ext_xy):
            rel = ext_xy - a
            t, d = rel @ u, np.abs(rel @ np.array([-u[1], u[0]]))
            behind = (
                (t >= 0) & (t < L[i]) & (d >= cfg.furniture_min_depth_m) & (d <= cfg.furniture_max_depth_m)
            )
            per_bin += np.bincount(
                np.minimum((t[behind] / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins
            )
        out[i] = float((per_bin > 0).mean()) < 0.5
    return out


OWN_BAND_MIN_SHARE = 0.02
"""`own_band`: an offset bin belongs to a line's data band when it holds at least this share of the line's
length in cells (and at least two cells)."""


def own_band(line: NDArray, data_xy: NDArray, grid_m: float, window_m: float = 0.3) -> tuple[float, float]:
    """(lo, hi) the signed offsets (metres, along the line's left normal) between which the line's own data
    spreads without a break: the wall cells `data_xy` (D, 2) beside the middle 80 % of its span, binned by
    offset every `grid_m`, the run of occupied bins (`OWN_BAND_MIN_SHARE`) through the one nearest the line,
    within `window_m`. A wall whose frames disagree in tilt (a corridor's end wall seen by frames levelled
    a few degrees apart) is one sloping smear decimetres deep, its upper part behind its lower part; a
    cabinet's front and the wall behind it, or a partition's two faces, have empty bins between them.
    (0, 0) when the line has no data there."""
    a, b = line[:2], line[2:]
    L = float(np.hypot(*(b - a)))
    if L <= 0 or len(data_xy) == 0:
        return 0.0, 0.0
    u = (b - a) / L
    rel = data_xy - a
    t, d = rel @ u, rel @ np.array([-u[1], u[0]])
    sel = (t >= 0.1 * L) & (t <= 0.9 * L) & (np.abs(d) <= window_m)
    k = math.ceil(window_m / grid_m)
    hist = np.bincount(np.clip(np.rint(d[sel] / grid_m).astype(np.intp) + k, 0, 2 * k), minlength=2 * k + 1)
    occupied = hist >= max(2.0, OWN_BAND_MIN_SHARE * 0.8 * L / grid_m)
    near = np.flatnonzero(occupied[k - 2 : k + 3])
    if len(near) == 0:
        return 0.0, 0.0
    start = k - 2 + int(near[np.argmin(np.abs(near - 2))])
    lo = hi = start
    while lo > 0 and occupied[lo - 1]:
        lo -= 1
    while hi < 2 * k and occupied[hi + 1]:
        hi += 1
    return (lo - k) * grid_m, (hi - k) * grid_m


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


def end_distances(walls: NDArray) -> tuple[NDArray, NDArray]:
    """The walls' ends (2M, 2: every first end, then every second) and each end's distance to every wall
    (2M, M; infinite to its own)."""
    m = len(walls)
    ends = np.concatenate([walls[:, :2], walls[:, 2:]])
    d = point_segment_distances(ends, walls)
    d[np.arange(2 * m), np.tile(np.arange(m), 2)] = np.inf
    return ends, d


def _stubs(walls: NDArray, angle_min_deg: float = 45.0) -> list[tuple[int, int]]:
    """Partition stubs of a wall model (M, 4): (wall, its joined end 0 or 1) for every wall with one free
    end whose other end stands on another wall's inside (a T, not a corner: the host wall runs on past
    the foot on both sides) at more than `angle_min_deg` to it."""
    m = len(walls)
    if m < 2:
        return []
    ends, d = end_distances(walls)
    touching = d <= 1e-6
    L = lengths(walls)
    th = angles(walls)
    out = []
    for i in range(m):
        free = [not touching[i + k * m].any() for k in (0, 1)]
        if free[0] == free[1]:
            continue
        k = 1 if free[0] else 0  # the joined end
        p = ends[i + k * m]
        for j in np.flatnonzero(touching[i + k * m]):
            t = float((p - walls[j, :2]) @ (walls[j, 2:] - walls[j, :2])) / max(L[j] ** 2, 1e-12) * L[j]
            if 0.05 < t < L[j] - 0.05 and abs(math.sin(th[i] - th[j])) > math.sin(
                math.radians(angle_min_deg)
            ):
                out.append((i, k))
                break
    return out


def _capped_stubs(walls: NDArray, cap_max_m: float, tol_m: float = 0.01) -> list[tuple[int, int, int]]:
    """Partition stubs whose second face the model holds only in part: (wall i, its end k standing on a
    wall at a T as in `_stubs`, the second face s) for every wall i whose other end meets a short wall (its
    end face, at most `cap_max_m`, across i) whose other end meets s, parallel to i (within 5 degrees), with
    a free end: s stops short of the host wall where the slice saw that face too sparsely."""
    m = len(walls)
    if m < 3:
        return []
    ends, d = end_distances(walls)
    touching = d <= tol_m
    L = lengths(walls)
    th = angles(walls)
    out = []
    for i in range(m):
        for k in (0, 1):
            p = ends[i + k * m]
            hosts = [
                j
                for j in np.flatnonzero(d[i + k * m] <= 1e-6)
                if 0.05
                < float((p - walls[j, :2]) @ (walls[j, 2:] - walls[j, :2])) / max(L[j], 1e-12)
                < L[j] - 0.05
                and abs(math.sin(th[i] - th[j])) > math.sqrt(0.5)
            ]
            if not hosts:
                continue
            for c in np.flatnonzero(touching[i + (1 - k) * m]):
                if L[c] > cap_max_m or abs(math.sin(th[i] - th[c])) <= math.sqrt(0.5):
                    continue
                # the cap's end away from i
                far = (
                    1
                    if np.hypot(*(walls[c, :2] - ends[i + (1 - k) * m]))
                    < np.hypot(*(walls[c, 2:] - ends[i + (1 - k) * m]))
                    else 0
                )
                for s in np.flatnonzero(touching[c + far * m]):
                    if s in (i, c) or abs(math.sin(th[i] - th[s])) > math.sin(math.radians(5)):
                        continue
                    free = [not touching[s + e * m].any() for e in (0, 1)]
                    if any(free):
                        out.append((i, k, int(s)))
    return out


def faces_below_slice(
    walls: NDArray,
    points: NDArray,
    slice_points: NDArray,
    floor_z_m: float,
    cfg: WallsConfig,
    grid_m: float,
    capped_only: bool = False,
) -> tuple[list[NDArray], list[dict[str, Any]]]:
    """The second faces of partition stubs, looked for in the levelled cloud under the slice.

    A stub of the wall model (`_stubs`: one free end, the other standing on a wall at a T) whose other
    face the slice does not hold, or holds too sparsely for the binarization (a face seen only from close
    range, below the camera's view of the slice, or at a grazing angle): the levelled points (N, 3) between
    `below_slice_min_z_m` above the floor and the slice's bottom, beside the stub (further than two grid
    cells, at most `thin_wall_max_m`) and along it, are binned by their offset on either side (1 cm); the
    face is the offset whose points (within 2 cm) cover the most of the stub's length (10 cm bins; ties: the
    most points), not the one with the most points: a Kinect's mixed pixels at the stub's free end lie
    between the two faces, many at one place. It is a face when its points cover at least
    `below_slice_min_share` of the stub's length and span `min_column_height_m` in height, and the slice holds
    no data there (under a fifth of the bins: "below") or holds it at under `below_slice_sparse_ratio` of the
    stub's first face's points per bin ("sparse": then at least `thin_wall_min_m` from the first face, beyond
    its noise), no wall of the model lying there already. A stub with neither takes its second face from its
    free end's own face (`_end_cap`, "end") when `end_cap_min_height_m` is on, unless that end is a door's
    jamb (`_door_beyond`). A stub whose second face the model holds in part (`_capped_stubs`: the face stops
    short of the host wall) gets the first face's points at that face's offset along the stretch the model
    lacks, where the slice holds it sparsely ("capped"; only those with `capped_only`: the second look, at
    the model the first one's faces made).

    Returns each face's points (K, 3): for a face below the slice its points (K, 2) under the slice (stood
    up as full columns by `lifted`); for a sparse, end or capped face, the stub's first face's slice points moved
    onto it (the face gets the first face's density and heights, so that neither it nor the room's walls
    outweigh the other in the projection image), with its own slice points; and what was found (for the
    metrics)."""
    faces: list[NDArray] = []
    found: list[dict[str, Any]] = []
    if cfg.below_slice_min_share <= 0 or cfg.thin_wall_max_m <= 0 or len(walls) < 2 or len(points) == 0:
        return faces, found
    z_lo = floor_z_m + cfg.below_slice_min_z_m
    z_hi = float(slice_points[:, 2].min())
    high = points[points[:, 2] >= z_lo]
    below = high[high[:, 2] < z_hi]
    if len(below) == 0:
        return faces, found
    bin_m = 0.1
    # a second face lies at least a partition's thickness from the first: nearer lie the first face's noise
    # and a Kinect's mixed pixels (711 r1: the points 4 cm off the first face covered more of the stub)
    nearest = max(2 * grid_m, cfg.thin_wall_min_m)
    for i, k in () if capped_only else _stubs(walls):
        a = walls[i, 2 * k : 2 * k + 2]
        b = walls[i, 2 * (1 - k) : 2 * (1 - k) + 2]
        L = float(np.hypot(*(b - a)))
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        rel = below[:, :2] - a
        t, d = rel @ u, rel @ n
        near = (t >= 0) & (t <= L) & (np.abs(d) >= nearest) & (np.abs(d) <= cfg.thin_wall_max_m)
        srel = slice_points[:, :2] - a
        st, sd = srel @ u, srel @ n
        s_near = (st >= 0.1 * L) & (st <= 0.9 * L)  # clear of the host wall and the stub's end
        n_bins = max(1, math.ceil(L / bin_m))
        mid = np.zeros(n_bins, dtype=bool)
        mid[int(0.1 * L / bin_m) : max(int(0.1 * L / bin_m) + 1, int(0.9 * L / bin_m))] = True

        def per_bin(tt: NDArray, n_bins: int = n_bins) -> NDArray:
            return np.bincount(np.minimum((tt / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins)

        # the stub's own (first) face in the slice: its points per bin, the reference for a sparse face
        first = (np.abs(sd) <= 0.02) & (st >= 0) & (st <= L)
        first_density = float(np.median(per_bin(st[first])[mid]))
        best = None
        for side in (1.0, -1.0):
            sel = near & (side * d > 0)
            if sel.sum() < 10:
                continue
            edges = np.arange(nearest, cfg.thin_wall_max_m + 0.01, 0.01)
            n_off = len(edges) - 1
            if n_off < 1:
                continue
            ob = np.clip(np.floor((side * d[sel] - edges[0]) / 0.01).astype(np.intp), 0, n_off - 1)
            tb = np.minimum((t[sel] / bin_m).astype(np.intp), n_bins - 1)
            occ = np.zeros((n_off + 4, n_bins), dtype=bool)
            occ[ob + 2, tb] = True
            counts = np.bincount(ob, minlength=n_off)
            # the bins of the stub's length that the points within 2 cm of each offset cover
            window = occ[:-4] | occ[1:-3] | occ[2:-2] | occ[3:-1] | occ[4:]
            covered = window.sum(axis=1)
            near_counts = np.convolve(counts, np.ones(5), mode="same")
            pk = int(np.lexsort((-near_counts, -covered))[0])
            peak = 0.5 * (edges[pk] + edges[pk + 1])
            on = sel & (np.abs(side * d - peak) <= 0.02)
            offset = side * float(np.median(side * d[on]))
            cover = float((per_bin(t[on]) > 0).mean())
            height = float(np.ptp(below[on, 2]))
            s_on = s_near & (np.abs(sd - offset) <= 0.02)
            in_slice = per_bin(st[s_on])
            seen = float((in_slice > 0).mean())  # the slice holds that face there already
            density = float(np.median(in_slice[mid]))
            ratio = density / first_density if first_density > 0 else math.inf
            if cover < cfg.below_slice_min_share or height < cfg.min_column_height_m:
                continue
            if seen < 0.2:
                kind = "below"
            elif (
                ratio < cfg.below_slice_sparse_ratio
                and abs(offset) >= cfg.thin_wall_min_m
                and not _wall_along(walls, i, a, u, n, offset, L)
            ):
                kind = "sparse"
            else:
                continue
            if best is None or cover > best[0]:
                best = (cover, offset, on, height, kind, seen, ratio)
        if (
            best is None
            and cfg.end_cap_min_height_m > 0
            and not _door_beyond(walls, i, a, u, n, L, cfg.lines.offset_tol_m)
        ):
            # no face along the stub: the end's face, as wide as the wall is thick, gives its second face
            cap = _end_cap(high, a, u, n, L, cfg, grid_m)
            if cap is not None and not _wall_along(walls, i, a, u, n, cap[0], L):
                offset, height = cap
                s_on = s_near & (np.abs(sd - offset) <= 0.02)
                in_slice = per_bin(st[s_on])
                ratio = float(np.median(in_slice[mid])) / first_density if first_density > 0 else math.inf
                if ratio < cfg.below_slice_sparse_ratio:
                    on = np.zeros(len(below), dtype=bool)
                    best = (0.0, offset, on, height, "end", float((in_slice > 0).mean()), ratio)
        if best is None:
            continue
        cover, offset, on, height, kind, seen, ratio = best
        if kind == "end":
            moved = slice_points[first].copy()
            moved[:, :2] += offset * n
            faces.append(moved)
        elif kind == "below":
            faces.append(below[on, :2])
        else:
            moved = slice_points[first].copy()
            moved[:, :2] += offset * n
            moved = moved[(st[first] >= float(t[on].min())) & (st[first] <= float(t[on].max()))]
            faces.append(moved)
        found.append(
            {
                "stub": [round(float(v), 3) for v in walls[i]],
                "offset_m": round(offset, 4),
                "cover": round(cover, 3),
                "height_span_m": round(height, 3),
                "points": int(on.sum()),  # under the slice, beside the stub ("end": none taken)
                "kind": kind,
                "slice_seen": round(seen, 3),
                "slice_density_ratio": round(ratio, 3) if math.isfinite(ratio) else None,
            }
        )
    done = {tuple(np.round(f["stub"], 3)) for f in found}
    for i, k, s_ in (
        _capped_stubs(walls, cfg.thin_wall_max_m + 0.05) if cfg.below_slice_sparse_ratio > 0 else ()
    ):
        if tuple(np.round(walls[i], 3)) in done:
            continue
        a = walls[i, 2 * k : 2 * k + 2]
        b = walls[i, 2 * (1 - k) : 2 * (1 - k) + 2]
        L = float(np.hypot(*(b - a)))
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        offset = 0.5 * float((walls[s_, :2] - a) @ n + (walls[s_, 2:] - a) @ n)
        if not cfg.thin_wall_min_m <= abs(offset) <= cfg.thin_wall_max_m:
            continue
        srel = slice_points[:, :2] - a
        st, sd = srel @ u, srel @ n
        n_bins = max(1, math.ceil(L / bin_m))
        first = (np.abs(sd) <= 0.02) & (st >= 0) & (st <= L)
        ref = _per_bin(st[first], n_bins, bin_m)
        mid = np.zeros(n_bins, dtype=bool)
        mid[int(0.1 * L / bin_m) : max(int(0.1 * L / bin_m) + 1, int(0.9 * L / bin_m))] = True
        first_density = float(np.median(ref[mid]))
        if first_density <= 0:
            continue
        held = _per_bin(st[(np.abs(sd - offset) <= 0.02) & (st >= 0) & (st <= L)], n_bins, bin_m)
        # the bins of the second face that the slice holds too sparsely get the first face's points
        sparse = held < cfg.below_slice_sparse_ratio * first_density
        # ...where the model's second face does not run already (its missing stretch, up to the host wall)
        ts = np.sort([(walls[s_, :2] - a) @ u, (walls[s_, 2:] - a) @ u])
        centres = (np.arange(n_bins) + 0.5) * bin_m
        sparse &= (centres < ts[0]) | (centres > ts[1])
        if not sparse.any():
            continue
        tb = np.minimum((st[first] / bin_m).astype(np.intp), n_bins - 1)
        pick = sparse[tb]
        moved = slice_points[first][pick].copy()
        # onto the second face's own line (its direction as modelled), each point as far from it as from the
        # first face's
        sa = walls[s_, :2]
        us = (walls[s_, 2:] - sa) / max(float(np.hypot(*(walls[s_, 2:] - sa))), 1e-12)
        q = a + np.outer(st[first][pick], u) - sa
        moved[:, :2] = sa + np.outer(q @ us, us) + np.outer(sd[first][pick], n)
        faces.append(moved)
        found.append(
            {
                "stub": [round(float(v), 3) for v in walls[i]],
                "offset_m": round(offset, 4),
                "cover": round(float((~sparse).mean()), 3),
                "kind": "capped",
                "filled_m": round(float(sparse.sum()) * bin_m, 2),
            }
        )
    return faces, found


def _per_bin(t: NDArray, n_bins: int, bin_m: float) -> NDArray:
    """Counts of the positions `t` (metres along a line, from 0) in `n_bins` bins of `bin_m`."""
    return np.bincount(np.minimum((t / bin_m).astype(np.intp), n_bins - 1), minlength=n_bins)


END_CAP_OUT_M = 0.04
"""`_end_cap`: how far past a stub's line end its end face is looked for. A Kinect's mixed pixels at the end
smear it inward and the line found stops a few centimetres short (dev clean 715 r1: 2 cm)."""


def _end_cap(
    points: NDArray, a: NDArray, u: NDArray, n: NDArray, L: float, cfg: WallsConfig, grid_m: float
) -> tuple[float, float] | None:
    """The second face of a stub (from its foot `a` along `u`, `L` long) told by its free end's own face:
    the points (N, 3) within 5 cm of the end (inward, `END_CAP_OUT_M` outward), binned by their offset
    along `n` (1 cm), occupy a run of bins from the stub's face (within 3 cm) out to the wall's thickness on
    one side (each bin at least a tenth of the fullest beyond the stub's own face), nothing stands beyond
    it for 10 cm (a corner's or a wall's run on would), the thickness lies between three grid cells and
    `thin_wall_max_m`, and the end's face spans `end_cap_min_height_m` in height. Returns (the signed offset
    of the second face: the 95th percentile of the run's points, the end's height span) or None."""
    rel = points[:, :2] - a
    t, d = rel @ u, rel @ n
    at_end = (t >= L - 0.05) & (t <= L + END_CAP_OUT_M) & (np.abs(d) <= cfg.thin_wall_max_m + 0.1)
    if at_end.sum() < 20:
        return None
    best = None
    for side in (1.0, -1.0):
        sd = side * d[at_end]
        k = math.ceil((cfg.thin_wall_max_m + 0.1) / 0.01)
        hist = np.bincount(np.clip(np.floor(sd / 0.01).astype(np.intp), -1, k) + 1, minlength=k + 2)[1:]
        # the stub's own face (its first 2 cm) does not set the scale: it holds far more points. A bin holds
        # data as the test beyond the face takes it: a 1 cm strip of an end face seen aslant holds a few
        # times fewer points than the next (836 r1: 41 between 140 and 153)
        ref = float(hist[2:].max())
        full = hist >= max(5.0, 0.1 * ref)
        if not full[:3].any():
            continue
        stop = int(np.argmax(full[:3]))
        while stop + 1 < k and full[stop + 1]:
            stop += 1
        width = (stop + 1) * 0.01
        if not max(3 * grid_m, cfg.thin_wall_min_m) <= width <= cfg.thin_wall_max_m:
            continue
        if hist[stop + 2 : stop + 11].max(initial=0) >= max(5.0, 0.1 * ref):
            continue  # data beyond the end's face: the wall does not end there
        run = (sd >= 0) & (sd < width)
        height = float(np.ptp(points[at_end][run, 2]))
        if height < cfg.end_cap_min_height_m:
            continue
        offset = side * float(np.quantile(sd[run], 0.95))
        if best is None or width < abs(best[0]):
            best = (offset, height)
    return best


def _in_stub_frame(walls: NDArray, i: int, a: NDArray, u: NDArray, n: NDArray) -> tuple[NDArray, ...]:
    """The walls of the model other than the stub i (from `a` along `u`, normal `n`) in its frame: (M,)
    which run parallel to it (within 5 degrees), their midpoints' offsets along `n`, and their ends' least and
    greatest positions along `u`."""
    p, q = walls[:, :2] - a, walls[:, 2:] - a
    dj = q - p
    lj = np.hypot(dj[:, 0], dj[:, 1])
    parallel = (lj > 0) & (np.abs(dj @ n) <= math.sin(math.radians(5)) * lj)
    parallel[i] = False
    ends = np.column_stack([p @ u, q @ u])
    return parallel, 0.5 * (p @ n + q @ n), ends.min(axis=1), ends.max(axis=1)


def _door_beyond(walls: NDArray, i: int, a: NDArray, u: NDArray, n: NDArray, L: float, tol_m: float) -> bool:
    """Does a wall of the model other than i lie in line with the stub i (from `a` along `u`, `L` long; its
    midpoint within `tol_m` of the line, parallel within 5 degrees) and start past the stub's free end within
    `DOOR_OPENING_MAX_M`? Then the end is a door's jamb in a wall of the room, its thickness the wall's, whose
    other face lies in the next room (a corridor's wall seen in pieces between doors), not a partition's."""
    parallel, offset, lo, _ = _in_stub_frame(walls, i, a, u, n)
    return bool((parallel & (np.abs(offset) <= tol_m) & (lo > L) & (lo <= L + DOOR_OPENING_MAX_M)).any())


def _wall_along(walls: NDArray, i: int, a: NDArray, u: NDArray, n: NDArray, offset: float, L: float) -> bool:
    """Does a wall of the model other than i run along the stub i's line at `offset` (within 2 cm, parallel
    within 5 degrees) over half its length `L` (from `a` along `u`)?"""
    parallel, off, lo, hi = _in_stub_frame(walls, i, a, u, n)
    along = np.minimum(hi, L) - np.maximum(lo, 0.0) >= 0.5 * L
    return bool((parallel & (np.abs(off - offset) <= 0.02) & along).any())


def lifted(faces: list[NDArray], z_lo: float, z_hi: float, step_m: float) -> NDArray:
    """The faces' points (K, 2 each), one per `step_m` cell, stood up over the slice's height band
    [z_lo, z_hi] every `step_m` (M, 3): a partition goes from floor to ceiling, so the face seen under the
    slice stands in it as the wall it is. Faces given as (K, 3) points (`faces_below_slice`'s sparse faces,
    already at the first face's density and heights) are passed on as they are."""
    if not faces:
        return np.zeros((0, 3))
    ready = [f for f in faces if f.shape[1] == 3]
    flat = [f for f in faces if f.shape[1] == 2]
    if not flat:
        return np.concatenate(ready)
    xy = np.concatenate(flat)
    _, first = np.unique(np.floor(xy / step_m).astype(np.int64), axis=0, return_index=True)
    xy = xy[np.sort(first)]
    z = np.arange(z_lo, z_hi + 1e-9, step_m)
    out = np.column_stack([np.repeat(xy, len(z), axis=0), np.tile(z, len(xy))])
    return np.concatenate([out, *ready]) if ready else out


WALKED_ROUND_ANGLE_DEG = 5.0
"""`walked_round`: how far apart in direction a thin wall's two faces may be found (a short face seen
obliquely)."""
OPEN_END_MIN_M = 2.0
"""`seen_through_gaps`: a line whose end runs on this far without meeting another line (wider than a double door
or a window) ends free in the room."""


def open_ends(
    lines: NDArray, reach_m: float, tol_m: float, back_m: float = 0.3, step_m: float = 0.05
) -> NDArray[np.bool_]:
    """(M, 2) whether each end of each line (x0 y0, then x1 y1) is open: its line, from `back_m` before that
    end (an end that overshoots a corner) to `reach_m` past it, comes within `tol_m` of no other line run on
    `reach_m` past both its ends (samples every `step_m`). A wall's end at a corner (the next wall's line
    crosses it, however short of the corner either was found) or at a door's jamb (the wall goes on past the
    door) is not open; a partition stub's free end, standing in the room, is."""
    lines = np.asarray(lines, dtype=np.float64)
    out = np.zeros((len(lines), 2), dtype=bool)
    if len(lines) < 2:
        return out
    L = lengths(lines)
    u = np.zeros((len(lines), 2))
    u[L > 0] = (lines[L > 0, 2:] - lines[L > 0, :2]) / L[L > 0, None]
    run_on = np.concatenate([lines[:, :2] - reach_m * u, lines[:, 2:] + reach_m * u], axis=1)
    for i in np.flatnonzero(L > 0):
        s = np.arange(-min(back_m, 0.5 * L[i]), reach_m + 1e-9, step_m)
        others = np.delete(run_on, i, axis=0)
        for k, (end, way) in enumerate(((lines[i, :2], -u[i]), (lines[i, 2:], u[i]))):
            out[i, k] = point_segment_distances(end + s[:, None] * way, others).min() > tol_m
    return out


def walked_round(
    lines: NDArray, thin_m: float, tol_m: float, angle_tol_deg: float = WALKED_ROUND_ANGLE_DEG
) -> NDArray[np.bool_]:
    """(M,) lines that are one face of a thin wall whose other face was seen too: a parallel line (within
    `angle_tol_deg`) more than `tol_m` and at most `thin_m` off its line, along at least half the shorter of
    the two, the two ending together (within `thin_m`) at one end at least. The capture was on both sides of
    such a line (a partition stub it walked round): whatever lies behind it may have been seen from its far
    side. A room's bounding wall shows the capture its one face only (through a door, the next room's face
    of it faces away)."""
    lines = np.asarray(lines, dtype=np.float64)
    m = len(lines)
    L = lengths(lines)
    ok = L > 0
    u = np.zeros((m, 2))
    u[ok] = (lines[ok, 2:] - lines[ok, :2]) / L[ok, None]
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    # [i, j]: line j's ends in line i's frame (from its start, along it and across it)
    rel = np.stack([lines[None, :, :2] - lines[:, None, :2], lines[None, :, 2:] - lines[:, None, :2]])
    off = np.abs(np.einsum("kijd,id->kij", rel, nrm))
    t = np.einsum("kijd,id->kij", rel, u)
    lo, hi = t.min(axis=0), t.max(axis=0)
    overlap = np.minimum(L[:, None], hi) - np.maximum(0.0, lo)
    pair = (
        np.triu(ok[:, None] & ok[None, :], k=1)
        & (np.abs(u @ u.T) >= math.cos(math.radians(angle_tol_deg)))
        & (off.max(axis=0) <= thin_m)
        & (off.min(axis=0) > tol_m)
        & (overlap >= 0.5 * np.minimum(L[:, None], L[None, :]))
        & (np.minimum(np.abs(lo), np.abs(L[:, None] - hi)) <= thin_m)
    )
    return pair.any(axis=1) | pair.any(axis=0)


def _room_behind(lines: NDArray, w: int, u: NDArray, behind: NDArray[np.bool_]) -> bool:
    """Whether a line of `behind` (M,) runs along line `w` (direction `u`) or within `OPEN_END_MIN_M` past one
    of its ends: the room goes on behind `w`, which, with an end open, is a partition stub."""
    t = np.stack([(lines[:, :2] - lines[w, :2]) @ u, (lines[:, 2:] - lines[w, :2]) @ u], axis=1)
    L = float(np.hypot(*(lines[w, 2:] - lines[w, :2])))
    by = (t.max(axis=1) >= -OPEN_END_MIN_M) & (t.min(axis=1) <= L + OPEN_END_MIN_M)
    return bool((behind & by).any())


def backs_in_doubt(
    lines: NDArray, centre: NDArray, tol_m: float, angle_min_deg: float = 45.0
) -> NDArray[np.bool_]:
    """(M,) lines whose back (the side away from the room's `centre`) may be the room's side: `centre`'s foot
    on the line's line lies beyond one of its ends, the lines meeting that end (more than `angle_min_deg` off
    it, an end within `tol_m` of its end) run to `centre`'s side and those meeting its other end to the far
    side. Such a line is a step of the room's outline that the room turns round at its near end: an alcove's
    side, whose front faces the alcove, away from `centre` (clean 888 r4). A wall at an L-room's reflex corner
    has the line at its near end running away from `centre`, and its back is known."""
    lines = np.asarray(lines, dtype=np.float64)
    L = lengths(lines)
    ang = angles(lines)
    ends = lines.reshape(-1, 2, 2)  # (M, 2 ends, xy)
    out = np.zeros(len(lines), dtype=bool)
    cos_max = math.cos(math.radians(angle_min_deg))
    for w in np.flatnonzero(L > 0):
        u = (lines[w, 2:] - lines[w, :2]) / L[w]
        t = (centre - lines[w, :2]) @ u
        if 0 <= t <= L[w]:
            continue
        front = np.array([-u[1], u[0]])
        front *= np.sign((centre - lines[w, :2]) @ front) or 1.0
        across = np.abs(np.cos(ang - ang[w])) < cos_max
        across[w] = False
        sides = []
        for e in ends[w]:
            d = np.linalg.norm(ends - e, axis=2)  # (M, 2)
            meet = across & (d.min(axis=1) <= tol_m)
            far = ends[np.flatnonzero(meet), 1 - d[meet].argmin(axis=1)]
            side = np.sign((far - e) @ front)
            sides.append(side[0] if len(side) and (side == side[0]).all() else 0.0)
        near, other = (sides[0], sides[1]) if t < 0 else (sides[1], sides[0])
        out[w] = near > 0 and other < 0
    return out


def seen_through_gaps(
    lines: NDArray,
    wall_data: NDArray[np.bool_],
    grid: Grid,
    interior: NDArray | None,
    min_depth_m: float,
    min_share: float,
    tol_m: float,
) -> NDArray[np.bool_]:
    """(M,) lines seen through a gap (a door, a window) in another line of the room: walls of the rooms
    beyond, not of this one.

    A line L is such a wall when some longer line W has L wholly on its back (the side away from the room's
    `interior`: the lines' length-weighted centre), every point of L more than `min_depth_m` behind W's
    line, and at least `min_share` of L's points lie straight behind W's data (`wall_data` within `tol_m` of
    their foot on W): the sensor, in the room, cannot have seen them through W, only obliquely through a gap
    in it. A room's own walls are never behind another of its walls' data: an alcove's or an L-room's far
    walls lie behind a wall's *line* but beyond its end or behind the gap itself (an alcove's mouth), and a
    thin wall's second face lies within `min_depth_m` (the thickest thin wall) of its first. `min_share` 0
    switches the test off.

    A line with an open end (`open_ends`) and a longer line wholly behind it, along it or within
    `OPEN_END_MIN_M` past its ends (the room goes on there: a partition stub standing free in the room), hides
    nothing: the room's walls behind it were seen round its end. Nor does an alcove's side whose back, away
    from `interior`, may be the alcove (`backs_in_doubt`, corners within half `min_depth_m`)."""
    lines = np.asarray(lines, dtype=np.float64)
    out = np.zeros(len(lines), dtype=bool)
    if min_share <= 0 or interior is None or len(lines) < 2:
        return out
    L = lengths(lines)
    ok = L > 0
    stub = open_ends(lines, OPEN_END_MIN_M, tol_m).any(axis=1)
    u = np.zeros((len(lines), 2))
    u[ok] = (lines[ok, 2:] - lines[ok, :2]) / L[ok, None]
    back = np.column_stack([u[:, 1], -u[:, 0]])
    # the normal pointing away from the room
    back[((np.asarray(interior) - lines[:, :2]) * back).sum(axis=1) > 0] *= -1
    near = _near_sampler(wall_data, grid, tol_m)
    pts, owner = sample_segments(lines, grid.size)
    # a partition the capture walked round hides nothing: what lies behind it was seen from its far side; nor
    # does an alcove's side whose back may be the alcove
    hiders = (
        ok
        & ~walked_round(lines, min_depth_m, tol_m)
        & ~backs_in_doubt(lines, np.asarray(interior), 0.5 * min_depth_m)
    )
    for w in np.flatnonzero(hiders):
        rel = pts - lines[w, :2]
        depth, t = rel @ back[w], rel @ u[w]
        # the lines wholly behind W (every sample deeper than min_depth_m), shorter than W
        deep = np.bincount(owner, depth <= min_depth_m, len(lines)) == 0
        cand = deep & (L < L[w])
        cand[w] = False
        if not cand.any() or (stub[w] and _room_behind(lines, w, u[w], deep & (L > L[w]))):
            continue
        sel = cand[owner]
        inside = (t[sel] >= 0) & (t[sel] <= L[w])
        foot = lines[w, :2] + np.outer(t[sel], u[w])
        solid = np.zeros(int(sel.sum()), dtype=bool)
        solid[inside] = near(foot[inside])
        share = np.bincount(owner[sel], solid, len(lines)) / np.maximum(
            np.bincount(owner[sel], minlength=len(lines)), 1
        )
        out |= cand & (share >= min_share)
    return out


def _bin_counts(xy: NDArray, a: NDArray, b: NDArray, tol: float, bin_m: float) -> NDArray:
    """Points of `xy` (N, 2) within `tol` of the segment a-b, counted in bins of about `bin_m` along it."""
    d = b - a
    length = float(np.hypot(*d))
    u = d / max(length, 1e-12)
    rel = xy - a
    t = rel @ u
    near = (np.abs(rel @ np.array([-u[1], u[0]])) < tol) & (t >= 0) & (t < length)
    n = max(1, round(length / bin_m))
    return np.bincount(np.minimum((t[near] / length * n).astype(np.int64), n - 1), minlength=n)


def backed_bridges(walls: NDArray, origin: NDArray, xy: NDArray, cfg: WallsConfig) -> NDArray:
    """(K, 4) spans joining two collinear observed walls across a gap longer than `lines.max_gap_m` that
    the slice points back (issue 14: a corridor wall the camera passed quickly, in a room that stays open).

    Both ends facing the gap are free (no other wall within `end_tol_m`), nothing else stands in the gap,
    and at least `lines.min_overlap` of its 10 cm bins hold `bridge_seen_ratio` times the median bin of
    the room's own observed walls (points within `support_tol_m`): the reference is the room's, so the
    sensor's density and the slice's height scale it alike. A door (no points at slice height) or an
    unseen corner (not collinear) is not bridged."""
    seen = np.flatnonzero(origin == OBSERVED)
    if len(seen) < 2 or len(xy) == 0:
        return np.zeros((0, 4))
    bin_m, tol = 0.1, cfg.support_tol_m
    obs = walls[seen]
    ref = float(np.median(np.concatenate([_bin_counts(xy, w[:2], w[2:], tol, bin_m) for w in obs])))
    if ref <= 0:
        return np.zeros((0, 4))
    lines = cfg.lines
    ends = walls.reshape(-1, 2)
    d_ends = point_segment_distances(ends, walls)  # (2M, M)
    own = np.repeat(np.arange(len(walls)), 2)
    d_ends[np.arange(len(ends)), own] = np.inf
    free = d_ends.min(axis=1) > cfg.end_tol_m
    ang = angles(walls)
    cands = []
    for ii, i in enumerate(seen):
        u = (walls[i, 2:] - walls[i, :2]) / max(float(lengths(walls[i : i + 1])[0]), 1e-12)
        nrm = np.array([-u[1], u[0]])
        for j in seen[ii + 1 :]:
            da = abs((ang[i] - ang[j] + math.pi / 2) % math.pi - math.pi / 2)
            if da > math.radians(lines.angle_tol_deg):
                continue
            if np.abs((walls[j].reshape(2, 2) - walls[i, :2]) @ nrm).max() > lines.offset_tol_m:
                continue
            ti = np.sort(walls[i].reshape(2, 2) @ u)
            tj = np.sort(walls[j].reshape(2, 2) @ u)
            lo, hi = (i, j) if ti[1] <= tj[0] else (j, i)
            tl = ti if lo == i else tj
            th = tj if lo == i else ti
            gap = th[0] - tl[1]
            if gap <= lines.max_gap_m:
                continue
            # the facing ends: lo's end furthest along u, hi's nearest
            el = 2 * lo + int(np.argmax(walls[lo].reshape(2, 2) @ u))
            eh = 2 * hi + int(np.argmin(walls[hi].reshape(2, 2) @ u))
            if not (free[el] and free[eh]):
                continue
            a, b = ends[el], ends[eh]
            n = max(2, math.ceil(gap / bin_m))
            probe = a + np.linspace(0, 1, n + 1)[1:-1, None] * (b - a)
            others = np.delete(walls, [i, j], axis=0)
            if len(others) and point_segment_distances(probe, others).min() < tol:
                continue
            counts = _bin_counts(xy, a, b, tol, bin_m)
            if (counts >= cfg.bridge_seen_ratio * ref).mean() >= lines.min_overlap:
                cands.append((gap, el, eh))
    used: set[int] = set()
    out = []
    for _, el, eh in sorted(cands):
        if el in used or eh in used:
            continue
        used |= {el, eh}
        out.append(np.concatenate([ends[el], ends[eh]]))
    return np.array(out).reshape(-1, 4)


def collinear_with(
    lines: NDArray, ang: NDArray, normal: NDArray, j: int, cos_tol: float, offset_tol_m: float
) -> NDArray[np.bool_]:
    """(M,) lines parallel to line j (within acos(cos_tol)) whose midpoints lie within offset_tol_m of its
    line: its collinear pieces, j itself among them."""
    mid = 0.5 * (lines[:, :2] + lines[:, 2:])
    par = np.abs(np.cos(ang - ang[j])) >= cos_tol
    return par & (np.abs((mid - lines[j, :2]) @ normal[j]) <= offset_tol_m)


DOOR_OPENING_MAX_M = 1.1
"""The widest door opening in a wall (a 1 m leaf and its frame): two pieces of a wall either side of a door
lie up to this far apart, further than the largest occlusion (`lines.max_gap_m`) may be."""


FURNITURE_RULES = (
    "front_along_wall",
    "front_boxed",
    "front_at_seen_end",
    "front_before_data",
    "front_alone",
    "front_in_recess",
    "front_inside",
    "front_band",
    "side",
)
"""`furniture_in_front`'s rules, in the order they are tried: a front with the wall's line along it, on the
wall's line between two sides (or a side and a corner), at the wall's seen end, with the wall's data seen
behind it, standing alone in front of the wall's unseen stretch, standing in a recess whose sides run on past
it, standing free where the room's walls run on past its line at both its ends; a line of a front's band of
data; a side."""


def furniture_in_front(
    lines: NDArray,
    interior: NDArray | None,
    cfg: WallsConfig,
    angle_tol_deg: float,
    why: dict[str, int] | None = None,
    occupied: NDArray | None = None,
    source: NDArray | None = None,
) -> NDArray[np.bool_]:
    """(M,) lines that are the faces of furniture standing against a wall, for a slice with nothing seen
    above it (a handheld scan cut at 1.3-2 m, no ceiling), where a cabinet, a shelf or a plant reaches the
    slice top like the walls and the top-reach test cannot tell them apart:
    - a front: a line at most `furniture_max_length_m` long, parallel to a line ("the wall": within twice
      the angle tolerance, or what 2 `support_tol_m` over the line's length allow a short one) and
      `furniture_min_depth_m` to `furniture_max_depth_m` in front of it on the room's side (towards
      `interior`), with the wall's line (its collinear pieces together, longer than the front: the wall
      behind the furniture is hidden in the slice, so its pieces either side may each be shorter) running
      along at least half of it, or the wall's data there (`occupied` (K, 2), the centres of the cells
      holding slice data, within `support_tol_m` of the wall's line) along at least half of its 10 cm bins
      (seen past it: a wall hides what lies behind it, a shelf lower than the cut does not; the few points
      make no line), or with both its ends joined to the wall's line by sides (a box standing on the wall
      just past where the capture saw it: the wall behind and beyond it unseen), or with one
      end where the wall's seen part ends and the other free (`at_seen_end`: the wall seen up to the box
      and not past it, or the box's side at its far end; a front longer than the wall's pieces, seen
      beside a cabinet wider than the stretch of wall the capture saw, only with that far side), or
      standing alone in front of the wall's unseen stretch between the room's corners (`isolated`);
    - a front in a recess (`in_recess`, no wall before it needed): a line that long and at least
      `furniture_min_depth_m`, in line with no other, each of whose ends has a line across it running on
      beyond it, away from the room, by furniture's depth (a cabinet filling an alcove, the alcove's sides
      seen past it and its back unseen);
    - a front inside the room (`inside`, no wall before it needed): a line that long, both ends free, in line
      with no other, with a wall of the room crossing its line past each of its ends (a cabinet's face
      before a slanted wall seen only near its corners);
    - a side: a line perpendicular to such a wall, `furniture_min_depth_m` to `furniture_max_depth_m` long,
      from within `thin_wall_end_tol_m` of the wall's line (at a front, it may reach across that line by as
      much; not at the wall's ends: a corner, unless a front ends it) into the room, in line with no other
      line (within a door's opening, `DOOR_OPENING_MAX_M`: the wall's next piece), whose inner end is free
      (within `thin_wall_end_tol_m` of no line but the wall, the fronts and the lines along it, such as the
      box's other side): a partition stub is longer than furniture is deep, and one shorter meets a wall.
    A pilaster of a furniture's size in front of a wall is dropped as well: without a ceiling nothing
    tells them apart (with one, the top-reach test keeps it). A line lying wholly within
    `thin_wall_end_tol_m` of a front is of its band of data and goes with it. `why`, when given, gets the
    number of lines each rule took (`FURNITURE_RULES`), for the metrics. `source` (M,), when given, names the
    line each line was cut from (`split_past_corners`): the pieces a reflex corner parts (a wardrobe's front
    and the alcove's side it lines up with) are not in line with each other."""
    m = len(lines)
    out = np.zeros(m, dtype=bool)
    if m < 2 or interior is None:
        return out
    decided = dict.fromkeys(FURNITURE_RULES, 0)
    d_lo, d_hi = cfg.furniture_min_depth_m, cfg.furniture_max_depth_m
    tol = cfg.support_tol_m
    L = lengths(lines)
    u = (lines[:, 2:] - lines[:, :2]) / np.maximum(L, 1e-12)[:, None]
    n = np.column_stack([-u[:, 1], u[:, 0]])
    ang = angles(lines)
    cos_tol = math.cos(math.radians(angle_tol_deg))
    # a short face of furniture, before regularization, may lie twice the tolerance off its wall's direction
    cos_loose = math.cos(math.radians(2 * angle_tol_deg))
    sin_loose = math.sin(math.radians(2 * angle_tol_deg))

    def wall_extent(j: int) -> tuple[float, float]:
        """Along line j's direction, the extent of j and its collinear pieces (offset within tol)."""
        par = np.abs(np.cos(ang - ang[j])) >= cos_tol
        off = np.abs(np.stack([(lines[:, :2] - lines[j, :2]) @ n[j], (lines[:, 2:] - lines[j, :2]) @ n[j]]))
        same = par & (off.max(axis=0) <= cfg.lines.offset_tol_m)
        t = np.concatenate([(lines[same, :2] - lines[j, :2]) @ u[j], (lines[same, 2:] - lines[j, :2]) @ u[j]])
        return float(t.min()), float(t.max())

    def depth(k: int, j: int) -> NDArray:
        """Signed offsets of line k's ends from line j, positive towards the interior."""
        side = 1.0 if float((interior - lines[j, :2]) @ n[j]) >= 0 else -1.0
        return side * np.array([(lines[k, :2] - lines[j, :2]) @ n[j], (lines[k, 2:] - lines[j, :2]) @ n[j]])

    end_tol = cfg.thin_wall_end_tol_m

    def is_side(k: int, i: int, j: int, e: int, dd: NDArray) -> bool:
        """Is line k a side joining end e of line i (standing dd in front of line j) to j's line: across j,
        from within `thin_wall_end_tol_m` of the end to within that of j's line, no longer than that?"""
        dk = depth(k, j)
        p = lines[i, 2 * e : 2 * e + 2]
        return (
            dk.min() <= end_tol
            and point_segment_distances(p[None], lines[k : k + 1])[0, 0] <= end_tol
            and L[k] <= d_hi + end_tol
            and abs(dk.max() - dd[e]) <= end_tol
        )

    def seen_behind(i: int, j: int, dd: NDArray, t: NDArray) -> bool:
        """Do the slice data lie on j's line (within `support_tol_m`) behind line i (standing dd in front
        of it, spanning t along j's line) in at least half of i's 10 cm bins? i must be at least as long as
        it stands deep (narrower, a wall's piece at a corner or a stub may look so, with the corner's data
        behind it), and the room's side clear: the interior lies beyond i by furniture's least depth (a
        centre between the two, as an L-room's may lie, tells no front from a wall)."""
        if occupied is None or len(occupied) == 0 or L[i] < dd.max():
            return False
        if abs(float((interior - lines[j, :2]) @ n[j])) < dd.max() + d_lo:
            return False
        rel = occupied - lines[j, :2]
        on = np.abs(rel @ n[j]) <= tol
        along = rel[on] @ u[j]
        lo, hi = float(t.min()), float(t.max())
        bins = max(1, math.ceil((hi - lo) / 0.1))
        hit = np.unique(np.floor((along[(along >= lo) & (along < hi)] - lo) / 0.1).astype(np.int64))
        return len(hit) >= 0.5 * bins

    def boxed(i: int, j: int, dd: NDArray) -> bool:
        """Is line i (standing dd in front of line j) a box on j's line: each of its ends joined to j's line
        by a side (a line perpendicular to j from within `thin_wall_end_tol_m` of the end to within that of
        j's line), or one end so and, beyond the other within `lines.max_gap_m`, a wall of the room running
        into the room from j's line (the corner the box stands in: the room goes on behind it there)? The
        wall behind the box and beside it is unseen in the slice; an alcove's or a step's wall beside it has
        the room's walls meeting its own line, not the line behind it."""
        t_i = (lines[i].reshape(2, 2) - lines[j, :2]) @ u[j]
        sides = 0
        for e in range(2):
            side = corner = False
            for k in np.flatnonzero(np.abs(np.cos(ang - ang[j])) <= sin_loose):
                if k in (i, j):
                    continue
                dk = depth(k, j)
                if dk.min() > end_tol:
                    continue  # k stands off j's line
                if is_side(k, i, j, e, dd):
                    side = True
                    break
                # beyond the end (outward along j), within the gap a wall may be unseen, past the box's depth
                foot = (lines[k, :2] if dk[0] <= dk[1] else lines[k, 2:]) - lines[j, :2]
                beyond = (foot @ u[j] - t_i[e]) * np.sign(t_i[e] - t_i[1 - e])
                corner |= bool(0 <= beyond <= cfg.lines.max_gap_m and dk.max() > dd[e] + end_tol)
            if side:
                sides += 1
            elif not corner:
                return False
        return sides >= 1

    across_j = np.abs(np.cos(ang[:, None] - ang[None, :])) <= sin_loose  # (M, M) k crosses j
    samples, sample_owner = sample_segments(lines, 0.5 * tol)

    def band_of(which: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """(M,) the lines lying wholly within `thin_wall_end_tol_m` of the lines `which` (M,) (those among
        them): pieces of their own band of data (a face seen from afar is a decimetre deep), not lines
        meeting their ends."""
        near = point_segment_distances(samples, lines[which]).min(axis=1) <= end_tol
        return np.bincount(sample_owner, ~near, m) == 0

    def runs_on(k: int, j: int, tk: float) -> bool:
        """Does line k, across j's line at tk along it, have another piece in line with it (another line
        across j, both ends within `lines.offset_tol_m` of tk; judged along the long line j, as a short line's
        own direction is good to a few degrees only)?"""
        other = across_j[:, j].copy()
        other[[k, j]] = False
        tt = np.abs(
            np.stack([(lines[:, :2] - lines[j, :2]) @ u[j], (lines[:, 2:] - lines[j, :2]) @ u[j]]) - tk
        )
        return bool((other & (tt.max(axis=0) <= cfg.lines.offset_tol_m)).any())

    def at_seen_end(
        i: int, j: int, dd: NDArray, t: NDArray, t0: float, t1: float, boxed_only: bool = False
    ) -> bool:
        """Is line i (standing dd in front of line j, spanning t along j's line, whose pieces span t0..t1) a
        box standing where j's seen part ends: one end at j's end (joined to j's line by a side, or its foot
        on j's line within twice `thin_wall_end_tol_m` of where j's data stop: the skeleton rounds both
        corners), the whole of i beyond that end, its other end free (within `thin_wall_end_tol_m` of no other
        line) or joined back to j's line by the box's far side, in line with no other line within a door's
        width (`lines.max_gap_m`: a piece of the same wall; an alcove's side further on is none) and at least
        as long as it stands deep? The capture saw the wall up to the box, which hid it behind, and not past
        the box's free end (a handheld capture misses a fifth of the walls). A step of the room's outline
        runs on to a corner (a wall of the room meeting i's line at its free end: not taken); the back of an
        alcove (j) beside a short stretch of the room's wall (i) has the alcove's other side at its other end,
        as deep as i stands and in line with nothing, and an alcove's side beside the room's corner has a
        wall of the room in line with the box's side: not taken. `boxed_only` (an i longer than j's pieces
        together: a cabinet wider than the stretch of wall seen beside it) wants the far side: with a free far
        end, i may be the room's wall running on past a short recess whose back is j."""
        if L[i] < dd.max():
            return False  # narrower than deep: a wall's piece at a corner and a stub may look so as well
        # in line with a piece of the same wall: one within a door's width (`lines.max_gap_m`) of it
        inline = in_line(i)
        inline[inline] = (
            point_segment_distances(lines[inline].reshape(-1, 2), lines[i : i + 1]).reshape(-1, 2).min(axis=1)
            <= cfg.lines.max_gap_m
        )
        if inline.any():
            return False
        others = ~band_of(np.arange(m) == i)
        others[i] = False
        gaps = point_segment_distances(lines[i].reshape(2, 2), lines[others]).min(axis=1)  # (2,) per end
        reach = 2 * end_tol  # each of the two ends may stop short of the box's corner by end_tol
        for e in range(2):
            o = 1 - e
            if (gaps[o] <= end_tol or boxed_only) and not any(
                is_side(k, i, j, o, dd) for k in np.flatnonzero(across_j[:, j]) if k not in (i, j)
            ):
                continue  # the other end meets a line, or is free with `boxed_only`: no side back to j's line
            # the whole of i beyond j's start (its other end before it) or beyond j's end
            before = t[o] < t[e] and t[o] <= t0 + tol
            after = t[o] > t[e] and t[o] >= t1 - tol
            if not (before or after):
                continue
            j_end = t0 if before else t1
            if abs(t[e] - j_end) > reach:
                side = t0 - reach <= t[e] <= t1 + reach and any(
                    is_side(k, i, j, e, dd) for k in np.flatnonzero(across_j[:, j]) if k not in (i, j)
                )
                if not side:
                    continue
            # the room's wall runs along the line of the box's side, deeper into the room than the box: the
            # box would stand outside the room (an alcove's side beside the room's corner)
            walled = False
            for k in np.flatnonzero(across_j[:, j]):
                if k in (i, j):
                    continue
                tk = np.array([(lines[k, :2] - lines[j, :2]) @ u[j], (lines[k, 2:] - lines[j, :2]) @ u[j]])
                walled |= bool(np.abs(tk - t[e]).max() <= end_tol and depth(k, j).max() > dd.max() + end_tol)
            if walled:
                continue
            # the room's outline steps in there: a wall of the room meets i's line at its free end (ends
            # short of the corner by up to end_tol each) and runs into the room from there
            out_dir = 1.0 if after else -1.0
            for k in np.flatnonzero(across_j[:, j]):
                if k in (i, j):
                    continue
                dk = depth(k, j)
                near = lines[k, :2] if dk[0] <= dk[1] else lines[k, 2:]
                beyond = (float((near - lines[j, :2]) @ u[j]) - t[o]) * out_dir
                if (
                    abs(dk.min() - dd.mean()) <= end_tol
                    and dk.max() > dk.min() + end_tol
                    and -end_tol <= beyond <= reach
                ):
                    return False
            far = t1 if before else t0
            # j the back of a recess: at its far end (away from i) a line runs from j's line into the
            # room as deep as i stands, and stops there (a wall of the room seen only near the corner runs
            # on, in line with its other pieces)
            for k in np.flatnonzero(across_j[:, j]):
                if k in (i, j):
                    continue
                dk = depth(k, j)
                foot = (lines[k, :2] if dk[0] <= dk[1] else lines[k, 2:]) - lines[j, :2]
                if (
                    dk.min() <= end_tol
                    and abs(dk.max() - dd.mean()) <= end_tol
                    and abs(foot @ u[j] - far) <= reach
                    and not runs_on(k, j, float(foot @ u[j]))
                ):
                    return False
            return True
        return False

    def in_line(i: int) -> NDArray[np.bool_]:
        """(M,) the lines in line with line i (collinear within `lines.offset_tol_m`), i left out, and the
        pieces of the line i was cut from at a reflex corner (the same `source`) too."""
        inline = collinear_with(lines, ang, n, i, cos_tol, cfg.lines.offset_tol_m)
        inline[i] = False
        if source is not None:
            inline &= source != source[i]
        return inline

    def room_side(i: int) -> float:
        """The side of line i (along `n[i]`, 1 or -1) the room's `interior` lies on, 0 where it lies within
        furniture's depth (and `support_tol_m`) of i's line: too close to tell a recess or the room's far side
        from a box before a wall."""
        clear = float((interior - lines[i, :2]) @ n[i])
        if abs(clear) <= d_hi + tol:
            return 0.0
        return 1.0 if clear >= 0 else -1.0

    def cos_short(i: int) -> float:
        """The cosine of how far off a wall's direction line i may be drawn: a short line's direction is good
        to about 2 `support_tol_m` over its length (at least `furniture_min_depth_m`), a longer one's to the
        usual tolerance (twice the angle tolerance)."""
        return min(cos_loose, math.cos(math.atan2(2 * tol, max(L[i], d_lo))))

    def free(i: int, shortest: float = d_lo) -> bool:
        """Is line i longer than `shortest` (`furniture_min_depth_m`), both its ends free (within
        `thin_wall_end_tol_m` of no other line)?"""
        if L[i] <= shortest:
            return False
        others = np.ones(m, dtype=bool)
        others[i] = False
        return bool(point_segment_distances(lines[i].reshape(2, 2), lines[others]).min() > end_tol)

    def isolated(i: int, j: int, t: NDArray, t0: float, t1: float) -> bool:
        """Is line i (in front of line j, spanning t along j's line, whose pieces span t0..t1) a free-standing
        front beyond where j was seen: both its ends free (within `thin_wall_end_tol_m` of no other line), in
        line with no other line, and its span on j's line within the room's corners either side of j's seen
        extent (where the nearest lines across j's line meet it), which lie further apart than it is long?
        The wall runs on unseen behind it (a handheld capture misses a fifth of the walls); a wall of the
        room so short, standing alone, would meet the room's other walls or run on in line with one of them.

        A front seen shorter than furniture is deep (a cabinet's front seen in part, however short: a
        piece of 0.15 m in degraded 331 r3) is judged against a wall parallel within what its length allows
        (`cos_short`), and not when it may be the room's wall beside an alcove whose back is j: its span on
        j's line begins within `thin_wall_end_tol_m` of j's seen end (the alcove's side, unseen, joins them),
        or a line across j's line ends on i's line and runs into the room (the room's corner stands on i's
        line), or, at one of j's ends, a line in line with no other runs from j's line as deep as i stands
        and stops there (the alcove's side)."""
        if not free(i, 0.0):
            return False
        if L[i] <= d_hi:
            # a front seen shorter than furniture is deep, unless it may be the room's wall beside an alcove
            if abs(math.cos(ang[i] - ang[j])) < cos_short(i):
                return False  # judged against a wall parallel within what its length allows
            if min(abs(float(t.min()) - t1), abs(float(t.max()) - t0)) <= end_tol:
                return False  # beginning at j's seen end: the alcove's side, unseen, would join them
            dd = depth(i, j)
            for k in np.flatnonzero(np.abs(np.cos(ang - ang[j])) <= sin_loose):
                dk = depth(k, j)
                if abs(dk.min() - dd.mean()) <= end_tol and dk.max() > dk.min() + end_tol:
                    return False  # a wall of the room ends on i's line and runs into the room: a corner
                # j the back of a recess: at one of its ends a line runs from j's line into the room as
                # deep as i stands, and stops there (a wall of the room seen only by a corner runs on)
                foot = (lines[k, :2] if dk[0] <= dk[1] else lines[k, 2:]) - lines[j, :2]
                if (
                    dk.min() <= end_tol
                    and abs(dk.max() - dd.mean()) <= end_tol
                    and min(abs(float(foot @ u[j]) - t0), abs(float(foot @ u[j]) - t1)) <= 2 * end_tol
                    and not any(
                        collinear_with(lines, ang, n, q, cos_tol, cfg.lines.offset_tol_m)[k]
                        for q in np.flatnonzero(across_j[:, j])
                        if q != k
                    )
                ):
                    return False
        inline = in_line(i)
        if inline.any():
            return False
        # where the lines across j's line meet it (beyond j's seen extent): the corners of the room, made by
        # the lines running into the room from it (a door's jamb or the next room's wall stands outside). A
        # line's direction is good to about 2 `support_tol_m` over its length, so a line ending g short of
        # j's line puts its corner there within g 2 `support_tol_m` / its length (a 0.2 m stub 4 m across
        # the room: 2 m), and the corner is taken as far out as that allows
        across = np.flatnonzero(np.abs(np.cos(ang - ang[j])) <= math.sqrt(0.5))
        dk = np.array([depth(k, j) for k in across]).reshape(-1, 2)
        inward = dk.max(axis=1) > end_tol
        across = across[inward]
        spread = np.maximum(dk[inward].min(axis=1), 0.0) * 2 * tol / L[across]
        denom = u[across] @ n[j]  # along a crossing line, the rate of moving off j's line
        s = ((lines[j, :2] - lines[across, :2]) @ n[j]) / denom
        meet = lines[across, :2] + s[:, None] * u[across]
        tm = (meet - lines[j, :2]) @ u[j]
        lo, hi = float(t.min()), float(t.max())
        after, before = tm >= t1 - tol, tm <= t0 + tol
        if not after.any() or not before.any():
            return False  # no corner on one side: nothing bounds the wall j would be a piece of
        # past j's seen ends, up to the corners, and the wall between them longer than the front
        c0, c1 = float((tm - spread)[before].max()), float((tm + spread)[after].min())
        return c0 - tol <= lo and hi <= c1 + tol and c1 - c0 > L[i] + tol

    def ends_on(i: int) -> tuple[NDArray, NDArray]:
        """Every line's two ends (2, M) along line i's direction and across it (signed, along `n[i]`), from
        i's first end."""
        rel = np.stack([lines[:, :2] - lines[i, :2], lines[:, 2:] - lines[i, :2]])  # (2, M, 2)
        return rel @ u[i], rel @ n[i]

    def in_recess(i: int) -> bool:
        """Is line i a box's front standing in a recess: at each of its ends a line across it (the nearest:
        through the end, within twice `thin_wall_end_tol_m` as `at_seen_end` allows, or beyond it, the
        front filling at least half the recess's mouth: a wardrobe in an alcove a little wider than it)
        reaches i's line and runs on beyond it, away from the room, by furniture's depth
        (`furniture_min_depth_m` to `furniture_max_depth_m` and `support_tol_m`), i in line with no other
        line but the room's wall beside the recess (beyond a side, starting within twice
        `thin_wall_end_tol_m` of it: a front a few cm behind the wall's line), the room's `interior` more
        than that on its other side, and the slice data (`occupied`) between the sides, behind i, in under
        half its 10 cm bins? The recess's sides were seen past the box (above it, or past its sides), its
        back not; a wall of the room hides what lies beyond it, and the walls meeting it end there (a wall's
        piece between two doors has the wall's other pieces in line a door's width away). A centre close to
        the line, as an L-room's may lie, tells no recess from a box's sides before a wall; an open shelf's
        front with the wall seen behind it goes onto that wall (`seen_through_fronts`)."""
        side = room_side(i)
        if not side:
            return False
        sin_side = max(sin_loose, math.sin(math.atan2(2 * tol, d_lo)))
        mid = 0.5 * (lines[i, :2] + lines[i, 2:])
        # how far each line reaches past i's line, away from the room
        along, across = ends_on(i)
        past = (-side * across).max(axis=0)
        sides, gaps = [], []
        for e in range(2):
            p = lines[i, 2 * e : 2 * e + 2]
            out_e = p - mid  # along i, away from its middle past this end
            found = []
            for k in np.flatnonzero(np.abs(np.cos(ang - ang[i])) <= sin_side):
                # k's line passes this end (within the reach, nearer it than i's middle) or lies beyond it
                gap = float((lines[k, :2] - p) @ n[k]) * (1.0 if float(out_e @ n[k]) >= 0 else -1.0)
                if k == i or not max(-2 * end_tol, -0.5 * L[i]) < gap <= max(2 * end_tol, L[i]):
                    continue
                reach = float((side * np.array([(lines[k, :2] - p) @ n[i], (lines[k, 2:] - p) @ n[i]])).max())
                if reach >= -end_tol and d_lo <= past[k] <= d_hi + tol:
                    found.append((abs(gap), gap, k))
            if not found:
                return False
            _, gap, k = min(found)  # the nearest
            sides.append(k)
            gaps.append(gap)
        # the front fills at least half the recess's mouth (a wardrobe in an alcove a little wider than it)
        if sum(max(g, 0.0) for g in gaps) > max(2 * end_tol, L[i]):
            return False
        # in line with no other line but the room's wall beside the recess, running on from its sides
        inline = in_line(i)
        if inline.any():
            at = along[:, sides].mean(axis=0)
            lo, hi = float(at.min()), float(at.max())
            t = along[:, inline]
            beside = ((t.max(axis=0) <= lo) & (lo - t.max(axis=0) <= 2 * end_tol)) | (
                (t.min(axis=0) >= hi) & (t.min(axis=0) - hi <= 2 * end_tol)
            )
            if not beside.all():
                return False
        # nothing seen behind it between the sides
        if occupied is None or len(occupied) == 0:
            return True
        rel = occupied - lines[i, :2]
        t, back = rel @ u[i], -side * (rel @ n[i])
        inside = (t > tol) & (t < L[i] - tol) & (back >= d_lo) & (back <= past[sides].max() + tol)
        bins = max(1, math.ceil(L[i] / 0.1))
        return len(np.unique(np.floor(t[inside] / 0.1))) < 0.5 * bins

    def inside(i: int) -> bool:
        """Is line i a face standing free inside the room: both its ends free (within `thin_wall_end_tol_m`
        of no other line), in line with no other line, the room's `interior` more than furniture's depth from
        its line, and past each of its ends a wall of the room (a line at least `furniture_max_depth_m` long,
        more than 45° across i) crossing i's line, running on `furniture_min_depth_m` or more on either side
        of it? The room goes on past i's line at both its ends: i bounds nothing (a cabinet's face before a
        slanted wall seen only near its corners). A wall of the room seen in its middle only has the walls
        across it ending at its line (the room's corners); an L-room's inner wall has the wing's outer wall
        running on past its line at one end only."""
        if not free(i):
            return False
        inline = in_line(i)
        if inline.any():
            return False
        side = room_side(i)
        if not side:
            return False
        # each line's ends' offsets from i's line (positive towards the room), and where it crosses that line
        off = side * ends_on(i)[1]
        crossing = (np.abs(np.cos(ang - ang[i])) <= math.sqrt(0.5)) & (L >= d_hi)
        crossing &= (off.min(axis=0) <= -d_lo) & (off.max(axis=0) >= d_lo)
        crossing[i] = False
        if not crossing.any():
            return False
        k = np.flatnonzero(crossing)
        w = off[0, k] / (off[0, k] - off[1, k])  # along k, where it meets i's line
        meet = lines[k, :2] + w[:, None] * (lines[k, 2:] - lines[k, :2])
        tm = (meet - lines[i, :2]) @ u[i]
        return bool((tm < 0).any() and (tm > L[i]).any())

    for i in np.flatnonzero(L <= cfg.furniture_max_length_m):
        # a front's wall is parallel within what its length allows (`cos_short`, as a side's is), a plant's
        # facet shorter than furniture is deep within what that gives at the least depth (27°; a faceted
        # plant shows one facet within half its turn, 18° for ten, of the wall's)
        for j in np.argsort(-L):
            if j == i or abs(math.cos(ang[i] - ang[j])) < cos_short(i):
                continue
            dd = depth(i, j)
            if not ((dd >= d_lo) & (dd <= d_hi)).all():
                continue
            t0, t1 = wall_extent(j)
            t = np.array([(lines[i, :2] - lines[j, :2]) @ u[j], (lines[i, 2:] - lines[j, :2]) @ u[j]])
            # the wall's line runs along at least half the front (a wardrobe in a corner hides the wall
            # behind it up to the corner; an alcove's mouth beside the alcove's back wall runs along none)
            overlap = min(t.max(), t1) - max(t.min(), t0)
            rule = None
            if t1 - t0 > L[i] + tol:
                if overlap >= 0.5 * L[i]:
                    rule = "front_along_wall"
                elif boxed(i, j, dd):
                    rule = "front_boxed"
                elif at_seen_end(i, j, dd, t, t0, t1):
                    rule = "front_at_seen_end"
            elif at_seen_end(i, j, dd, t, t0, t1, boxed_only=True):
                rule = "front_at_seen_end"
            if rule is None and seen_behind(i, j, dd, t):
                rule = "front_before_data"
            if rule is None and isolated(i, j, t, t0, t1):
                rule = "front_alone"
            if rule is not None:
                out[i] = True
                decided[rule] += 1
                break
        if not out[i] and L[i] >= d_lo and in_recess(i):
            out[i] = True
            decided["front_in_recess"] += 1
        if not out[i] and inside(i):
            out[i] = True
            decided["front_inside"] += 1
    if out.any():
        # the rest of a front's face: a line lying wholly within `thin_wall_end_tol_m` of a front (a cabinet's
        # front seen from afar is a band of data a decimetre deep, and gives short lines across it too)
        band = band_of(out) & ~out
        decided["front_band"] += int(band.sum())
        out |= band
    front = out.copy()
    corner_tol = math.sqrt(2.0) * end_tol
    for k in np.flatnonzero((L >= d_lo) & (L <= d_hi + tol) & ~front):
        # in line with another line, judged along either's line (a short line's own direction is good to
        # a few degrees only: 2 cm over its 0.7 m put a wall's piece a door further on 10 cm off it)
        on_theirs = np.abs(((0.5 * (lines[k, :2] + lines[k, 2:]) - lines[:, :2]) * n).sum(axis=1))
        inline = collinear_with(lines, ang, n, k, cos_tol, cfg.lines.offset_tol_m) | (
            (np.abs(np.cos(ang - ang[k])) >= cos_tol) & (on_theirs <= cfg.lines.offset_tol_m)
        )
        inline &= ~front
        inline[k] = False
        if inline.any():
            gap = point_segment_distances(lines[k].reshape(2, 2), lines[inline]).min()
            if gap <= max(cfg.lines.max_gap_m, DOOR_OPENING_MAX_M):
                continue  # a piece of a wall, in line with another (across a door, say)
        # a side is short: each of its ends is good to `support_tol_m`, so its direction to about
        # 2 support_tol_m / its length (0.4 m: 14°), looser than a long line's
        sin_side = max(sin_loose, math.sin(math.atan2(2 * tol, L[k])))
        for j in np.argsort(-L):
            if j == k or front[j] or abs(math.cos(ang[k] - ang[j])) > sin_side:
                continue
            dd = depth(k, j)
            inner = lines[k, 2:] if dd[1] > dd[0] else lines[k, :2]
            # a side that joins a front to the wall may stop short of both by as much as their ends may lie apart
            # (each end short of the box's corner by up to end_tol along its own line)
            at_front = front.any() and point_segment_distances(inner[None], lines[front]).min() <= corner_tol
            # ...and, drawn some degrees off from its few points, reach across the wall's line by as much; any
            # side may stop short of the wall's line by that much (its data near the wall go into the wall's
            # band: a sparse capture's noisy band, and a cell or two of the grid, 7 cm on degraded 251 r1)
            reach = end_tol if at_front else tol
            if not ((dd >= -reach) & (dd <= d_hi + tol)).all() or dd.min() > end_tol:
                continue
            t0, t1 = wall_extent(j)
            if t1 - t0 <= L[k]:
                continue
            tk = float((0.5 * (lines[k, :2] + lines[k, 2:]) - lines[j, :2]) @ u[j])
            if not t0 + d_lo <= tk <= t1 - d_lo and not at_front:
                continue  # at the wall's end: a corner of the room (unless a furniture front ends it)
            others = np.ones(m, dtype=bool)
            others[[k, j]] = False
            others &= ~front
            others &= ~collinear_with(lines, ang, n, j, cos_tol, cfg.lines.offset_tol_m)  # the wall too
            # a line along the side meets no end of it (one in line was judged above): the box's other side
            # beside it, a shelf's next board
            others &= np.abs(np.cos(ang - ang[k])) < cos_loose
            if others.any():
                near = point_segment_distances(inner[None], lines[others]).min() <= cfg.thin_wall_end_tol_m
                if near:
                    continue
            out[k] = True
            decided["side"] += 1
            break
    if why is not None:
        why.update(decided)
    return out


SEEN_THROUGH_MIN_SHARE = 0.5
"""`seen_through_fronts`: a front with data behind it in at least this share of the 10 cm bins where it is seen."""


def seen_through_fronts(
    lines: NDArray, candidates: NDArray, interior: NDArray | None, occupied: NDArray, cfg: WallsConfig
) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.float64]]:
    """(moved (M,), sides (M,), lines (M, 4)): the lines a capture saw through, moved onto the wall behind
    them, and their sides, for a slice with nothing seen above it (a handheld scan cut at 1.3-2 m), where an
    open shelf reaches the slice top like a wall.

    A wall hides what lies behind it. Where a line among `candidates` (M,), longer than furniture is deep
    (`furniture_max_depth_m`) and at most `furniture_max_length_m`, parallel to a longer candidate (within
    twice the angle tolerance, as a front to its wall), is seen (its 10 cm bins holding cells of `occupied`
    (K, 2), the centres of the cells with slice data, within `support_tol_m` of it), and in at least
    `SEEN_THROUGH_MIN_SHARE` of those bins the data also lie on a line parallel to it
    `furniture_min_depth_m` to `furniture_max_depth_m` behind it (away from `interior`), it is the front of
    an open shelf (its books, its boards), and the wall it stands against is that line behind: it moves
    there (the median offset of those data). Its sides, lines across it from its ends to the wall's line
    (within `thin_wall_end_tol_m`), go.

    Not moved: a line with a line across one of its ends (any line, a candidate or not) running on past
    the wall found behind it (a wall of the room: the room lies there; an L-shaped room's centre may lie in
    its other wing); a wall with a door (what lies beyond is seen where the wall itself is not); a thin
    partition seen from both sides (a stub standing in the room: a parallel line within `thin_wall_max_m`
    behind, along half of it), as the room goes on behind it."""
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    out = lines.copy()
    moved, sides = np.zeros(len(lines), dtype=bool), np.zeros(len(lines), dtype=bool)
    if interior is None or len(occupied) == 0 or len(lines) < 2:
        return moved, sides, out
    candidates = np.asarray(candidates, dtype=bool)
    tol, end_tol = cfg.support_tol_m, cfg.thin_wall_end_tol_m
    d_lo, d_hi = cfg.furniture_min_depth_m, cfg.furniture_max_depth_m
    L = lengths(lines)
    ang = angles(lines)
    step = 0.01
    # parallel within twice the angle tolerance, as a front stands to its wall (`furniture_in_front`)
    sin_loose = math.sin(math.radians(2 * cfg.lines.angle_tol_deg))
    loose = np.abs(np.sin(ang[:, None] - ang[None, :])) <= sin_loose
    # ...and across it as a side stands, good to 2 support_tol_m over its length (`furniture_in_front`)
    sin_side = np.maximum(sin_loose, np.sin(np.arctan2(2 * tol, np.maximum(L, 1e-12))))
    across = np.abs(np.cos(ang[:, None] - ang[None, :])) <= sin_side[None, :]
    for i in np.flatnonzero(candidates & (L > d_hi) & (L <= cfg.furniture_max_length_m)):
        if not (loose[i] & candidates & (L > L[i])).any():
            continue  # in no direction of the room's walls: no shelf's front
        a = lines[i, :2]
        u = (lines[i, 2:] - a) / L[i]
        n = np.array([-u[1], u[0]])
        if float((interior - a) @ n) > 0:
            n = -n  # n points away from the room
        if float((a - interior) @ n) < d_lo:
            continue  # the room's centre too near the line to tell its front from its back
        rel = occupied - a
        t, off = rel @ u, rel @ n
        inside = (t >= 0) & (t < L[i])
        bins = np.floor(t / 0.1).astype(np.int64)
        own = np.unique(bins[inside & (np.abs(off) <= tol)])
        if len(own) < 0.5 * math.ceil(L[i] / 0.1):
            continue
        # a thin partition's other face behind it: the room goes on past its end
        par = np.abs(np.sin(ang - ang[i])) <= math.sin(math.radians(cfg.lines.angle_tol_deg))
        par[i] = False
        if par.any():
            d_par = (0.5 * (lines[par, :2] + lines[par, 2:]) - a) @ n
            t_par = np.stack([(lines[par, :2] - a) @ u, (lines[par, 2:] - a) @ u])
            overlap = np.minimum(t_par.max(axis=0), L[i]) - np.maximum(t_par.min(axis=0), 0.0)
            if ((d_par > 0) & (d_par <= cfg.thin_wall_max_m) & (overlap >= 0.5 * L[i])).any():
                continue
        best, at = 0.0, 0.0
        for d in np.arange(d_lo, d_hi + 0.5 * step, step):
            behind = np.unique(bins[inside & (np.abs(off - d) <= tol)])
            share = len(np.intersect1d(behind, own, assume_unique=True)) / len(own)
            if share > best:
                best, at = share, float(d)
        if best < SEEN_THROUGH_MIN_SHARE:
            continue
        depth = float(np.median(off[inside & (np.abs(off - at) <= tol)]))
        # the lines across it at its ends (those not taken for walls too): one running on past the wall found
        # behind it is a wall of the room; a side runs from its line to the wall's
        at_ends = across[i].copy()
        at_ends[i] = False
        at_ends[at_ends] = (
            point_segment_distances(lines[i].reshape(2, 2), lines[at_ends]).min(axis=0) <= end_tol
        )
        ends = lines[at_ends].reshape(-1, 2, 2) - a
        dk = ends @ n  # (K, 2) behind the front
        if (dk.max(axis=1, initial=0.0) > depth + end_tol).any():
            continue
        out[i] += np.tile(depth * n, 2)
        moved[i] = True
        tk = ends @ u
        side = (
            (L[at_ends] <= depth + 2 * end_tol)
            & (dk.min(axis=1) >= -end_tol)
            & (dk.max(axis=1) >= depth - end_tol)
        )
        side &= np.minimum(np.abs(tk).max(axis=1), np.abs(tk - L[i]).max(axis=1)) <= end_tol
        side &= candidates[at_ends]
        sides[np.flatnonzero(at_ends)[side]] = True
    return moved, sides & ~moved, out


def run_length(s: NDArray, gap_m: float = 0.1) -> float:
    """How far (m) the sorted positions `s` run on from 0, gaps under `gap_m` bridged (those below 0 left
    out)."""
    s = s[s > 0]
    breaks = np.flatnonzero(np.diff(np.concatenate([[0.0], s])) > gap_m)
    if len(breaks):
        s = s[: breaks[0]]
    return float(s[-1]) if len(s) else 0.0


def data_run(start: NDArray, direction: NDArray, occupied: NDArray, tol_m: float) -> float:
    """How far (m) the cells of `occupied` (K, 2) within `tol_m` of the ray from `start` along the unit
    `direction` run on from it (`run_length`): where a line's data end, a Hough segment stopping a cell or
    two short of it."""
    rel = occupied - start
    return run_length(
        np.sort(rel[(np.abs(rel @ np.array([-direction[1], direction[0]])) <= tol_m)] @ direction)
    )


def recess_backs(
    lines: NDArray, candidates: NDArray, interior: NDArray | None, occupied: NDArray, cfg: WallsConfig
) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.float64]]:
    """(moved (M,), sides (M,), lines (M, 4)): the fronts of boxes standing in a recess, moved back onto
    the recess's back wall, and the boxes' sides, for a slice with nothing seen above it (a handheld scan
    cut at 1.3-2 m: a wardrobe in an alcove reaches the slice top like the walls).

    A wall hides what lies beyond it. Where a line among `candidates` (M,), `furniture_min_depth_m` to
    `furniture_max_length_m` long, in line with no other, has at one of its ends (within twice
    `thin_wall_end_tol_m` along its line) a line across it whose data (the cells of `occupied` (K, 2)
    within `support_tol_m` of its line) run on past it, away from `interior`, by `furniture_min_depth_m` to
    `furniture_max_depth_m`, and whose end on the room's side stands on (within twice `thin_wall_end_tol_m`
    of) a line parallel to it between it and `interior` (the room's wall beside the recess: the recess's
    mouth), it is a box's front, not the recess's back: the recess's side was seen past it. The back lies
    at least where the side's data end: the front moves there (the deepest of its sides'), unless the data
    lie behind it (`occupied` within `support_tol_m` of a line parallel to it between it and that depth)
    in half its 10 cm bins (an open shelf, `seen_through_fronts`). Lines across it from its ends to the
    back (the box's own sides, seen past its end) go. `furniture_in_front` drops a box seen with both
    sides of its recess; this is the box whose recess's other side the capture did not see, or whose
    recess's mouth the room's wall line bridges."""
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    out = lines.copy()
    m = len(lines)
    moved, sides = np.zeros(m, dtype=bool), np.zeros(m, dtype=bool)
    if interior is None or len(occupied) == 0 or m < 3:
        return moved, sides, out
    candidates = np.asarray(candidates, dtype=bool)
    tol, end_tol = cfg.support_tol_m, cfg.thin_wall_end_tol_m
    d_lo, d_hi = cfg.furniture_min_depth_m, cfg.furniture_max_depth_m
    L = lengths(lines)
    ang = angles(lines)
    sin_loose = math.sin(math.radians(2 * cfg.lines.angle_tol_deg))
    cos_loose = math.cos(math.radians(2 * cfg.lines.angle_tol_deg))
    sin_side = np.maximum(sin_loose, np.sin(np.arctan2(2 * tol, np.maximum(L, 1e-12))))
    cos_tol = math.cos(math.radians(cfg.lines.angle_tol_deg))
    dirs = (lines[:, 2:] - lines[:, :2]) / np.maximum(L, 1e-12)[:, None]
    normals = np.column_stack([-dirs[:, 1], dirs[:, 0]])
    for i in np.flatnonzero(candidates & (L >= d_lo) & (L <= cfg.furniture_max_length_m)):
        a = lines[i, :2]
        u = (lines[i, 2:] - a) / L[i]
        n = np.array([-u[1], u[0]])
        if float((interior - a) @ n) > 0:
            n = -n  # n points away from the room
        clear = float((a - interior) @ n)
        if clear <= d_hi + tol:
            continue  # the room's centre too near the line to tell a recess from the room's far side
        inline = collinear_with(lines, ang, normals, i, cos_tol, cfg.lines.offset_tol_m)
        inline[i] = False
        if (inline & candidates).any():
            continue
        ends = lines.reshape(-1, 2, 2) - a  # (M, 2, 2) every line's ends from i's first end
        t, off = ends @ u, ends @ n  # along i, and behind it (away from the room)
        parallel = np.abs(np.cos(ang - ang[i])) >= cos_loose  # any line: a short piece of wall too
        parallel[i] = False
        depth = 0.0
        for k in np.flatnonzero(candidates & (np.abs(np.cos(ang - ang[i])) <= sin_side)):
            if k == i:
                continue
            tk = float(t[k].mean())
            if min(abs(tk), abs(tk - L[i])) > 2 * end_tol or off[k].min() > end_tol:
                continue  # not at one of i's ends, or not reaching i's line from the room's side
            far = int(np.argmax(off[k]))
            run = data_run(lines[k, 2 * far : 2 * far + 2], n, occupied, tol)
            past = float(off[k, far]) + run
            if not d_lo <= past <= d_hi + tol:
                continue
            # its end on the room's side stands on the room's wall beside the recess
            corner = lines[k, 2 - 2 * far : 4 - 2 * far]
            mouth = parallel.copy()
            mouth[mouth] = point_segment_distances(corner[None], lines[mouth])[0] <= 2 * end_tol
            ahead = -(0.5 * (off[mouth, 0] + off[mouth, 1]))
            if ((ahead > tol) & (ahead < clear)).any():
                depth = max(depth, past)
        if depth == 0.0:
            continue
        rel = occupied - a
        tt, oo = rel @ u, rel @ n
        behind = (tt > tol) & (tt < L[i] - tol) & (oo >= d_lo) & (oo <= depth - tol)
        bins = max(1, math.ceil(L[i] / 0.1))
        if len(np.unique(np.floor(tt[behind] / 0.1))) >= 0.5 * bins:
            continue
        out[i] += np.tile(depth * n, 2)
        moved[i] = True
        # the box's own sides: across i from its ends, back to the depth it moved to
        own = candidates & (np.abs(np.cos(ang - ang[i])) <= sin_side) & (L <= depth + 2 * end_tol)
        own &= (off.min(axis=1) >= -end_tol) & (off.max(axis=1) <= depth + end_tol)
        own &= np.minimum(np.abs(t).max(axis=1), np.abs(t - L[i]).max(axis=1)) <= end_tol
        own[i] = False
        sides |= own
    return moved, sides & ~moved, out


def split_past_corners(
    lines: NDArray, interior: NDArray | None, occupied: NDArray, cfg: WallsConfig, angle_tol_deg: float
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """(lines (M', 4), src (M',)): `_split_past_corners_once` until nothing more is cut (a line cut at an
    alcove's mouth gives the corner another line needs cut), the lines' sources composed."""
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    src = np.arange(len(lines))
    for _ in range(len(lines)):
        lines, once = _split_past_corners_once(lines, interior, occupied, cfg, angle_tol_deg)
        if len(once) == len(src):
            break
        src = src[once]
    return lines, src


def _split_past_corners_once(
    lines: NDArray, interior: NDArray | None, occupied: NDArray, cfg: WallsConfig, angle_tol_deg: float
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """(lines (M', 4), src (M',)): `lines` (M, 4) with each line that runs on past a reflex corner of the
    room across a gap in its data cut there, and for every line out the index of the line it came from
    (the second pieces last), for a slice with nothing seen above it (a handheld scan cut at 1.3-2 m).

    At a reflex corner a wall of the room turns off to the far side of a line (away from `interior`): past
    that corner the line's own line runs through the room, where no wall of the room stands. Where a line
    across a line (within twice the angle tolerance, or what 2 `support_tol_m` over its length allow) has an
    end within `thin_wall_end_tol_m` of it, or crosses it (the merge may run it across an alcove's mouth too:
    the corner is where they cross), at least `furniture_min_depth_m` from either of its ends, and runs
    from there `thin_wall_end_tol_m` or more to its far side, and the line's data (the cells of
    `occupied` (K, 2) within `support_tol_m` of it) stop within `thin_wall_end_tol_m` of that corner on one
    side and resume no sooner than twice that further on, the Hough merge took two things for one wall
    across the gap: the wall to the corner, and beyond the gap a face standing in the room in line with it
    (a wardrobe's front in line with an alcove's side, 347 r4). It is cut into the two, each then judged on
    its own; the piece beyond the gap starts where its data resume."""
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    m = len(lines)
    src = np.arange(m)
    if interior is None or len(occupied) == 0 or m < 2:
        return lines, src
    tol, end_tol, d_lo = cfg.support_tol_m, cfg.thin_wall_end_tol_m, cfg.furniture_min_depth_m
    L = lengths(lines)
    ang = angles(lines)
    sin_loose = math.sin(math.radians(2 * angle_tol_deg))
    sin_side = np.maximum(sin_loose, np.sin(np.arctan2(2 * tol, np.maximum(L, 1e-12))))
    out, extra, extra_src = lines.copy(), [], []
    for i in np.flatnonzero(L >= 2 * d_lo + 2 * end_tol):
        a = lines[i, :2]
        u = (lines[i, 2:] - a) / L[i]
        n = np.array([-u[1], u[0]])
        if float((interior - a) @ n) > 0:
            n = -n  # n points away from the room
        if float((a - interior) @ n) <= end_tol:
            continue
        rel = occupied - a
        s = rel[np.abs(rel @ n) <= tol] @ u  # i's data along it
        ends = lines.reshape(-1, 2, 2) - a
        t, off = ends @ u, ends @ n
        for k in np.flatnonzero(np.abs(np.cos(ang - ang[i])) <= sin_side):
            if k == i:
                continue
            if off[k].max() < end_tol or off[k].min() > end_tol:
                continue  # k runs not to the far side, or stands off i's line
            if off[k].min() >= -end_tol:
                corner = float(t[k, int(np.argmin(off[k]))])  # k's end on i's line
            else:
                # k crosses i's line there
                corner = float(t[k, 0] + (t[k, 1] - t[k, 0]) * off[k, 0] / (off[k, 0] - off[k, 1]))
            if not d_lo <= corner <= L[i] - d_lo:
                continue
            cut = None
            for sign in (1.0, -1.0):
                q = np.sort((s - corner) * sign)
                # the data on this side run on from the corner by at most end_tol, then stop for 2 end_tol
                reach = run_length(q)
                resume = q[q > reach + 0.1]
                behind = q[(q < 0) & (q > -end_tol)]  # the wall's data up to the corner on the other side
                limit = L[i] - corner if sign > 0 else corner
                if (
                    reach <= end_tol
                    and len(behind)
                    and len(resume)
                    and float(resume[0]) - reach >= 2 * end_tol
                    and limit - float(resume[0]) >= d_lo
                ):
                    cut = (sign, float(resume[0]))
                    break
            if cut is None:
                continue
            sign, resume = cut
            at, beyond = a + corner * u, a + (corner + sign * resume) * u
            if sign > 0:
                out[i] = [*a, *at]
                extra.append([*beyond, *lines[i, 2:]])
            else:
                out[i] = [*at, *lines[i, 2:]]
                extra.append([*a, *beyond])
            extra_src.append(i)
            break
    if not extra:
        return out, src
    return np.vstack([out, np.array(extra)]), np.concatenate([src, np.array(extra_src, dtype=np.intp)])


def lone_directions(
    lines: NDArray, min_total_m: float, angle_tol_deg: float, grid_m: float
) -> NDArray[np.bool_]:
    """(M,) lines whose direction the slice shows over less than `min_total_m` in all: the lines within
    `angle_tol_deg` of it (itself among them), or within what its ends' two grid cells allow a short line
    (0.4 m at 2 cm: 5.7°), are that short together. In a slice with nothing seen above it the faceted or
    rounded face of furniture that reached the cut (a plant's pot, a chair's back) gives short lines at
    directions no wall of the room takes; a wall at its own angle is seen over more (a handheld capture
    misses a fifth of the walls, not most of one)."""
    lines = np.asarray(lines, dtype=np.float64)
    if len(lines) == 0 or min_total_m <= 0:
        return np.zeros(len(lines), dtype=bool)
    L = lengths(lines)
    ang = angles(lines)
    tol = np.maximum(math.radians(angle_tol_deg), np.arctan2(2 * grid_m, np.maximum(L, 1e-12)))
    near = np.abs(np.sin(ang[:, None] - ang[None, :])) <= np.sin(tol)[:, None]
    return (near * L[None, :]).sum(axis=1) < min_total_m
