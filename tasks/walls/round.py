"""Round things in the slice (a plant's pot, a bin, a round column): arcs of a circle a few decimetres across,
which no wall makes. Their points go before the walls are looked for: drawn as lines, a pot's facets make
stubs and false corners beside the walls it stands by (a handheld scan's low slice cuts through every pot)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.walls.config import WallsConfig

ARC_BINS = 36
"""The circle's directions, 10 degrees each, for how much of it the points cover."""
BIN_MIN_SHARE = 0.25
"""A direction counts as covered when it holds at least this share of the median covered direction's points
(and at least 3): a wall's stray points near a circle tangent to it cover none."""
MAX_CANDIDATES = 50
"""Peaks of the circle transform looked at per tile, strongest first."""
TILE_CELLS = 1024
"""The transform is made tile by tile, this many cells a side (plus the largest radius around): a plane per
radius of a whole floor's slice would take gigabytes."""
LINES = 3
"""The straight lines a round thing's points are compared with: a box's or an alcove's three faces, a circle
touches all three (against two lines, at a margin of 0.1, a shelf in a room's corner came within 0.001 of
being a round thing)."""
MIN_CIRCLE_SHARE = 0.5
"""A round thing's circle explains most of the points near it (within 3 cells, the walls it stands by left
out): where lines explain few of them either (against faces longer than the radius only), a circle through
chairs' and a table's corners explains a third to a half."""
MAX_OUTSIDE_SHARE = 0.15
"""A round thing is seen from outside, through the free space before it: in the directions its arc covers,
the points 3 to 6 cells outside its circle are at most this share of those on it (within a cell). Noise of
1.5 cells gives 0.05, of 2 cells 0.17; a wall's noisy band, which a circle threads where the wall is short or
meets another, gives 0.2 to 0.6 (the generator's plants in handheld rooms at most 0.10)."""
PAST_M = 0.5
"""`_walls_past`: how far round a round thing its neighbourhood is searched for the walls it stands by."""
PAST_MAX_POINTS = 2000
"""...searched among at most this many of the points there (every k-th)."""
PAST_BINS = 6
"""...a line whose points, outside the thing, fill at least this many 5 cm bins along it runs on past the
thing: a wall (or a long face) it stands by, not one of its own facets."""


def _direction_bins(angle_deg: NDArray) -> NDArray[np.int64]:
    """The 10-degree direction (0..`ARC_BINS` - 1) of each angle about a centre (degrees)."""
    return (np.mod(angle_deg, 360.0) // (360 / ARC_BINS)).astype(np.int64)


def _arc_deg(angle_deg: NDArray, share: float = BIN_MIN_SHARE) -> float:
    """The longest run of covered 10-degree directions (circular) of points at `angle_deg` about a centre
    (`share` 0: every direction holding 3 points counts, the most any subset of the points can cover)."""
    count = np.bincount(_direction_bins(angle_deg), minlength=ARC_BINS)
    if not (count > 0).any():
        return 0.0
    covered = count >= max(3.0, share * float(np.median(count[count > 0])))
    if covered.all():
        return 360.0
    run = best = 0
    for c in np.concatenate([covered, covered]):
        run = run + 1 if c else 0
        best = max(best, run)
    return float(best * 360 / ARC_BINS)


def ransac_fit(
    pts: NDArray, model: type, samples: int, tol_m: float, seed: int
) -> tuple[Any, NDArray | None]:
    """skimage's RANSAC fit of `model` to `pts` within `tol_m`: (the model, its inliers), stopping once an
    all-inlier sample has been drawn with 99.9 % confidence (at most 200 draws), from a fixed `seed`."""
    from skimage.measure import ransac

    return ransac(
        pts,
        model,
        min_samples=samples,
        residual_threshold=tol_m,
        max_trials=200,
        stop_probability=0.999,
        rng=seed,
    )


def _lines_in_turn(pts: NDArray, tol_m: float, left: NDArray[np.bool_]) -> Iterator[tuple[Any, NDArray]]:
    """Up to `LINES` straight lines through the points `pts` (K, 2) still `left` (K,), one after the other
    (RANSAC within `tol_m`, fixed seeds): (the line, the indices of its inliers). The caller takes from `left`
    what each line explains before the next is looked for; it ends when fewer than 2 points are left."""
    from skimage.measure import LineModelND

    for seed in range(LINES):
        if left.sum() < 2:
            return
        fit, inliers = ransac_fit(pts[left], LineModelND, 2, tol_m, seed)
        if inliers is None:
            return
        yield fit, np.flatnonzero(left)[inliers]


def _lines_share(pts: NDArray, tol_m: float, min_face_m: float = 0.0) -> float:
    """Share of `pts` (K, 2) within `tol_m` of the `LINES` straight lines that explain most of them (RANSAC,
    one line after the other; fixed seeds, so the same points give the same share). A line whose points span
    less than `min_face_m` along it explains none of them: a facet of a many-sided pot, not a box's face."""
    left = np.ones(len(pts), dtype=bool)
    explained = 0
    for fit, taken in _lines_in_turn(pts, tol_m, left):
        left[taken] = False
        if float(np.ptp((pts[taken] - fit.origin) @ fit.direction)) >= min_face_m:
            explained += len(taken)
    return explained / max(len(pts), 1)


def _outside_share(offsets: NDArray, radius: float, grid_m: float) -> float:
    """Of the points at `offsets` (K, 2) from a circle's centre, in the 10-degree directions where at least 3
    lie on the circle (within `grid_m` of `radius`), the number 3 to 6 cells outside it over the number on it
    (`MAX_OUTSIDE_SHARE`)."""
    off = np.hypot(*offsets.T) - radius
    bins = _direction_bins(np.degrees(np.arctan2(offsets[:, 1], offsets[:, 0])))
    on = np.abs(off) <= grid_m
    seen = np.bincount(bins[on], minlength=ARC_BINS)[bins] >= 3
    outside = (off > 3 * grid_m) & (off <= 6 * grid_m)
    return float((outside & seen).sum() / max((on & seen).sum(), 1))


def _walls_past(
    xy: NDArray, tree: Any, centre: NDArray, radius: float, near: NDArray, grid_m: float
) -> tuple[NDArray[np.bool_], NDArray]:
    """Which of the points `near` (K, 2) lie within `grid_m` of a straight line that runs on past the circle
    (`centre`, `radius`), and (L, 2) the offsets from the centre to the foot of each such line: of the
    `LINES` lines that explain most of the slice points `xy` (N, 2; `tree` their KD-tree) within `PAST_M` of
    the circle (RANSAC, one after the other, fixed seeds), those whose points further than 3 cells from the
    circle fill `PAST_BINS` 5 cm bins along it. Those are the walls the thing stands by: a pot against a wall
    has the wall's points near it, which one line explains better than the pot's round."""
    wide = xy[np.asarray(tree.query_ball_point(centre, radius + PAST_M), dtype=np.int64)]
    # a dense scan's thousands of points there make each RANSAC draw slow, and add nothing to a wall's line
    wide = wide[:: max(1, math.ceil(len(wide) / PAST_MAX_POINTS))]
    out = np.zeros(len(near), dtype=bool)
    feet = []
    left = np.ones(len(wide), dtype=bool)
    outside = np.hypot(*(wide - centre).T) > radius + 3 * grid_m
    for _, inliers in _lines_in_turn(wide, grid_m, left):
        # the line through all its inliers (their principal direction): the sample's two points may tilt it
        # by degrees
        q = wide[inliers]
        origin = q.mean(axis=0)
        direction = np.linalg.svd(q - origin, full_matrices=False)[2][0]
        across = np.array([-direction[1], direction[0]])
        taken = np.flatnonzero(left & (np.abs((wide - origin) @ across) <= grid_m))
        left[taken] = False
        along = (wide[taken[outside[taken]]] - origin) @ direction
        if len(np.unique(np.floor(along / 0.05))) >= PAST_BINS:
            out |= np.abs((near - origin) @ across) <= grid_m
            feet.append(-float((centre - origin) @ across) * across)
    return out, np.array(feet).reshape(-1, 2)


def _walled_in(feet: NDArray, radius: float) -> bool:
    """Whether walls (the offsets (L, 2) from a circle's centre to the foot of each) cut the circle of
    `radius` so that no thing of that round stands there: one through its middle half, or two on opposite
    sides of its centre (an alcove or a corridor narrower than the thing, a pot in it and its walls making the
    circle)."""
    d = np.hypot(*feet.T) if len(feet) else np.zeros(0)
    if (d < 0.5 * radius).any():
        return True
    cut = feet[d < radius]
    return bool(len(cut) >= 2 and ((cut @ cut.T) < 0).any())


def round_objects(
    xy: NDArray, grid_m: float, cfg: WallsConfig
) -> tuple[NDArray[np.bool_], list[dict[str, Any]]]:
    """(N,) the slice points `xy` (N, 2) on round things, and those things (centre, radius, arc) for the
    metrics. A round thing is a circle of radius `round_radius_m` whose points, within a grid cell (`grid_m`,
    the data's scale) of it, cover an arc of at least `round_min_arc_deg` and which explains most
    (`MIN_CIRCLE_SHARE`) of the points near it (within 3 cells), and at least `round_margin` more of them than
    three straight lines do, each over a face at least as long as the radius: a corner's two walls or a box's
    three faces, however noisy, are explained better by lines; a many-sided pot's short facets are not a box's
    faces. Just outside its arc lies the free space it was seen through (`MAX_OUTSIDE_SHARE`). The walls it
    stands by (`_walls_past`) are left out of all these counts, and no wall may cut its circle as no thing
    standing in the room lets one (`_walled_in`). Candidates are the peaks of the circle Hough transform of the
    points' occupancy at two cells. Its points are those inside the circle or within 2 cells of it
    (`on_round_objects`)."""
    from scipy.spatial import cKDTree
    from skimage.measure import CircleModel
    from skimage.transform import hough_circle, hough_circle_peaks

    r_min, r_max = cfg.round_radius_m
    if r_max <= 0 or len(xy) < 10:
        return np.zeros(len(xy), dtype=bool), []
    cell = 2.0 * grid_m
    radii = np.arange(max(1, math.ceil(r_min / cell)), math.floor(r_max / cell) + 1)
    if len(radii) == 0:
        return np.zeros(len(xy), dtype=bool), []
    lo = xy.min(axis=0) - r_max
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    image = np.zeros(tuple(ij.max(axis=0) + 1 + int(r_max / cell)), dtype=bool)
    image[ij[:, 0], ij[:, 1]] = True
    peaks = []
    pad = int(radii[-1]) + 1
    for i0 in range(0, image.shape[0], TILE_CELLS):
        for j0 in range(0, image.shape[1], TILE_CELLS):
            # one tile and the circles' reach around it: the transform holds a plane per radius
            a0, b0 = max(0, i0 - pad), max(0, j0 - pad)
            tile = image[a0 : i0 + TILE_CELLS + pad, b0 : j0 + TILE_CELLS + pad]
            if not tile.any():
                continue
            # a covered arc fills that share of the circle's cells, less the cells a coarse circle misses
            _, col, row, rad = hough_circle_peaks(
                hough_circle(tile, radii, normalize=True),
                radii,
                min_xdistance=int(radii[0]),
                min_ydistance=int(radii[0]),
                threshold=0.75 * cfg.round_min_arc_deg / 360.0,
                total_num_peaks=MAX_CANDIDATES,
            )
            mine = (
                (row + a0 >= i0)
                & (row + a0 < i0 + TILE_CELLS)
                & (col + b0 >= j0)
                & (col + b0 < j0 + TILE_CELLS)
            )
            peaks += list(zip(row[mine] + a0, col[mine] + b0, rad[mine], strict=True))
    tree = cKDTree(xy)
    found: list[dict[str, Any]] = []
    for c0, c1, r in peaks:
        centre, radius = lo + (np.array([c0, c1]) + 0.5) * cell, float(r) * cell
        near = np.asarray(tree.query_ball_point(centre, radius + 6 * grid_m), dtype=np.int64)
        if len(near) < 10:
            continue
        p = xy[near]
        band = np.abs(np.hypot(*(p - centre).T) - radius) <= 2 * cell
        q = p[band] - centre
        if len(q) < 10 or _arc_deg(np.degrees(np.arctan2(q[:, 1], q[:, 0]))) < cfg.round_min_arc_deg:
            continue  # not even the transform's circle, two cells wide, is covered so far: a wall's tangent
        # the circle most of the band's points lie on, within a cell: a wall the round thing stands by
        # would pull a least-squares fit towards it
        fit, _ = ransac_fit(p[band], CircleModel, 3, grid_m, 0)
        if fit is None or not fit:
            continue
        centre, radius = np.asarray(fit.center, dtype=np.float64), float(fit.radius)
        if not r_min <= radius <= r_max:
            continue
        d = np.abs(np.hypot(*(p - centre).T) - radius)
        angle = np.degrees(np.arctan2(p[:, 1] - centre[1], p[:, 0] - centre[0]))
        if _arc_deg(angle[d <= grid_m], 0.0) < cfg.round_min_arc_deg:
            continue  # not even every point on the circle covers the arc (and the walls' points go below)
        # the walls it stands by are no part of it: their points count for neither the circle nor the lines
        # (nor the free space before it: the points round the fitted circle, which `near` was not taken about)
        shell = xy[np.asarray(tree.query_ball_point(centre, radius + 6 * grid_m), dtype=np.int64)]
        past, feet = _walls_past(xy, tree, centre, radius, np.concatenate([p, shell]), grid_m)
        if _walled_in(feet, radius):
            continue
        own = ~past[: len(p)]
        on = (d <= grid_m) & own
        arc = _arc_deg(angle[on])
        if arc < cfg.round_min_arc_deg:
            continue
        outside_share = _outside_share(shell[~past[len(p) :]] - centre, radius, grid_m)
        if outside_share > MAX_OUTSIDE_SHARE:
            continue  # a wall's noisy band, as much of it just outside the circle as on it
        close = (d <= 3 * grid_m) & own
        if close.sum() < 10:
            continue
        circle_share = float(on[close].mean())
        lines_share = _lines_share(p[close], grid_m, radius)
        if circle_share < MIN_CIRCLE_SHARE or circle_share - lines_share < cfg.round_margin:
            continue
        if any(np.hypot(*(centre - f["centre"])) < max(radius, f["radius_m"]) for f in found):
            continue  # the same thing found again at a neighbouring radius
        found.append(
            {
                "centre": centre,
                "radius_m": radius,
                "arc_deg": arc,
                "circle_share": round(circle_share, 3),
                "lines_share": round(lines_share, 3),
                "outside_share": round(outside_share, 3),
            }
        )
    things = [
        {**f, "centre": [round(float(v), 3) for v in f["centre"]], "radius_m": round(f["radius_m"], 3)}
        for f in found
    ]
    return on_round_objects(xy, things, grid_m), things


def on_round_objects(xy: NDArray, things: list[dict[str, Any]], grid_m: float) -> NDArray[np.bool_]:
    """(N,) the points `xy` (N, 2) inside one of the round `things` (`round_objects`) or within 2 cells
    (`grid_m`) of its circle."""
    out = np.zeros(len(xy), dtype=bool)
    for t in things:
        out |= np.hypot(xy[:, 0] - t["centre"][0], xy[:, 1] - t["centre"][1]) <= t["radius_m"] + 2 * grid_m
    return out
