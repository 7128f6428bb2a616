"""Walls a handheld capture saw only part of the way up (issue 14).

Without a ceiling, the slice is the highest band under the top of the data. A handheld scan sees each wall
up to its own height (1.2-2.7 m in the issue's real rooms), so a wall whose data stop lower than the slice's
top is missing from the slice, or reaches into it without reaching its top. The top-reach test then takes it
for furniture. `low_topped_walls` finds such walls' columns in the levelled cloud and drapes their top
band into the slice. Each column is moved up by its own shortfall, at its own density, so it stands in the
slice as a wall seen up to the slice's top.

The column's top tells a wall from furniture. Under the top there must be a wall's filled column: data
from the bottom of the column up, on most heights. At the top, the data that the same height holds
nearby must lie along a line: the wall's free upper edge, where the capture's view stopped. Furniture
lower than the wall behind it ends in a top surface instead: a cabinet's or a shelf's board, seen from
above or from below, whose data at that height spread as deep as the piece.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.measure import LineModelND

from tasks.walls.config import WallsConfig
from tasks.walls.model import point_spacing
from tasks.walls.round import ransac_fit, round_objects

LOW_TOP_EDGE_RADIUS_M = 0.3
"""A column's top is judged by the data at its height within this distance in plan view: more than a piece
of furniture's top surface is deep is not needed, and a wall's edge runs straight over it."""
LOW_TOP_EDGE_MAX_SPREAD_M = 0.05
"""...whose spread across their main direction (standard deviation) is at most this for a wall's free edge
(its noise; a 35-45 cm deep cabinet or shelf top spreads 10-13 cm)."""
LOW_TOP_FILLED_SHARE = 0.5
"""A wall's column holds data on at least this share of its heights (one layer per point spacing): a table
or a chair seen through holds its top and little under it."""
LOW_TOP_MIN_LENGTH_M = 0.5
"""Draped columns come in runs holding a straight stretch at least this long: a wall's, not a post's nor a
plant's rim."""


def low_topped_walls(
    levelled: NDArray,
    slice_points: NDArray,
    floor_z_m: float,
    ceiling_z_m: float,
    cfg: WallsConfig,
    spacing_m: float | None = None,
    ceiling_captured: bool | None = None,
) -> tuple[NDArray, dict[str, Any]]:
    """The slice (N, 3) with the columns of walls seen only up to under its top draped into it, and what was
    found (for the metrics).

    Looked for only without a ceiling (`ceiling_captured` False, preprocess's verdict; when not given, the
    slice's top within `top_clear_m` of `ceiling_z_m`, which is then the top of the data: a slice capped at
    `slice_max_m` under walls seen higher says nothing) and with `low_top_min_m` above 0. The levelled cloud
    (L, 3) is binned in columns of twice the point spacing `spacing_m` (by default the slice's,
    `model.point_spacing`), from `below_slice_min_z_m` above the floor to the slice's top.
    A column is a low-topped wall's when:
    - its top lies at least `low_top_min_m` above the floor, and more than `top_reach_m` under the slice's
      top (or the top-reach test would take it already);
    - it spans at least half the slice's height (the band draped), with data on `LOW_TOP_FILLED_SHARE` of its
      layers;
    - the data at its top's height nearby (`LOW_TOP_EDGE_RADIUS_M`) spread across their direction by at most
      `LOW_TOP_EDGE_MAX_SPREAD_M`: an edge, not a top surface;
    - it lies in a run of such columns whose top band holds a straight stretch (points within
      `support_tol_m` of one line) at least `LOW_TOP_MIN_LENGTH_M` long, not on a round thing
      (`round.round_objects`: a plant's open rim is an edge too).

    Such a column's slice points go, and its points from the slice's height under its top up to its top
    are moved up by the difference between the tops."""
    found: dict[str, Any] = {"low_top_columns": 0}
    if cfg.low_top_min_m <= 0 or cfg.top_reach_m is None or len(slice_points) == 0:
        return slice_points, found
    z_slice = slice_points[:, 2]
    z_lo, z_hi = float(z_slice.min()), float(z_slice.max())
    if ceiling_captured is None:
        ceiling_captured = ceiling_z_m - float(np.quantile(z_slice, 0.999)) >= cfg.top_clear_m
    if ceiling_captured:
        return slice_points, found  # a ceiling above the slice: the walls reach it
    lowest, highest = floor_z_m + cfg.low_top_min_m, z_hi - cfg.top_reach_m
    if lowest >= highest:
        return slice_points, found
    z = levelled[:, 2]
    pts = levelled[(z >= floor_z_m + cfg.below_slice_min_z_m) & (z <= z_hi)]
    if len(pts) == 0:
        return slice_points, found
    if spacing_m is None:
        spacing_m = point_spacing(slice_points)
    cell_m = 2.0 * spacing_m
    band = z_hi - z_lo

    ij = np.floor(pts[:, :2] / cell_m).astype(np.int64)
    origin = ij.min(axis=0)
    ij -= origin
    shape = tuple(int(v) + 1 for v in ij.max(axis=0))
    flat = np.ravel_multi_index((ij[:, 0], ij[:, 1]), shape)
    order = np.lexsort((pts[:, 2], flat))
    key, zs = flat[order], pts[order, 2]
    starts = np.flatnonzero(np.concatenate([[True], key[1:] != key[:-1]]))
    ends = np.concatenate([starts[1:], [len(key)]])
    cells = key[starts]
    bottom, top = zs[starts], zs[ends - 1]
    # the layers (one point spacing thick) each column holds data on
    layer = np.floor(zs / spacing_m).astype(np.int64)
    new_layer = np.concatenate([[True], (key[1:] != key[:-1]) | (layer[1:] != layer[:-1])])
    filled = np.add.reduceat(new_layer.astype(np.int64), starts)
    span = top - bottom
    cand = (
        (top >= lowest)
        & (top < highest)
        & (span >= 0.5 * band)
        & (filled >= LOW_TOP_FILLED_SHARE * (span / spacing_m + 1))
    )
    if not cand.any():
        return slice_points, found
    # the data at each candidate's top height nearby: an edge or a surface (heights scaled so that a ball
    # of the radius holds a layer of a point spacing either side of the top)
    squash = LOW_TOP_EDGE_RADIUS_M / spacing_m
    tree = cKDTree(np.column_stack([pts[:, :2], pts[:, 2] * squash]))
    idx = np.flatnonzero(cand)
    centres = (np.column_stack(np.unravel_index(cells[idx], shape)) + origin + 0.5) * cell_m
    near = tree.query_ball_point(
        np.column_stack([centres, top[idx] * squash]), LOW_TOP_EDGE_RADIUS_M, workers=1
    )
    for k, hits in zip(idx, near, strict=True):
        xy = pts[hits, :2]
        if len(xy) >= 3:
            spread = math.sqrt(max(float(np.linalg.eigvalsh(np.cov(xy.T))[0]), 0.0))
            if spread > LOW_TOP_EDGE_MAX_SPREAD_M:
                cand[k] = False
    found["low_top_surfaces"] = int(len(idx) - cand[idx].sum())
    # runs of such columns holding a straight stretch of wall (a plant's rim seen in part is curved): the
    # points of their top band within `support_tol_m` of one line over `LOW_TOP_MIN_LENGTH_M`
    mask = np.zeros(shape, dtype=bool)
    mask.flat[cells[cand]] = True
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    run = labels.ravel()[cells]  # each column's run (0: none)
    col = np.searchsorted(cells, flat)  # every point's column
    in_band = pts[:, 2] >= top[col] - band
    straight = np.zeros(n + 1, dtype=bool)
    for k in range(1, n + 1):
        xy = pts[in_band & (run[col] == k), :2]
        xy = xy[:: max(1, len(xy) // 2000)]
        if len(xy) < 2:
            continue
        line, inliers = ransac_fit(xy, LineModelND, 2, cfg.support_tol_m, 0)
        if inliers is not None and inliers.sum() >= 2:
            t = (xy[inliers] - line.origin) @ line.direction
            straight[k] = float(t.max() - t.min()) >= LOW_TOP_MIN_LENGTH_M
    chosen = straight[run] & cand
    if not chosen.any():
        return slice_points, found
    moved = chosen[col] & in_band
    # a round thing's columns (a plant's open rim is an edge too) are no wall's
    on_round, things = round_objects(
        pts[moved, :2], max(cfg.grid_size_m, cfg.grid_spacing_ratio * spacing_m), cfg
    )
    if things:
        chosen[np.unique(col[np.flatnonzero(moved)[on_round]])] = False
        found["low_top_round_things"] = len(things)
        if not chosen.any():
            return slice_points, found
        moved = chosen[col] & in_band
    up = pts[moved].copy()
    up[:, 2] += z_hi - top[col[moved]]
    # the slice's own points in those columns go (their wall's stretch under the top, or nothing)
    draped = np.zeros(shape[0] * shape[1], dtype=bool)
    draped[cells[chosen]] = True
    s_ij = np.floor(slice_points[:, :2] / cell_m).astype(np.int64) - origin
    inside = np.all((s_ij >= 0) & (s_ij < np.array(shape)), axis=1)
    gone = np.zeros(len(slice_points), dtype=bool)
    gone[inside] = draped[np.ravel_multi_index((s_ij[inside, 0], s_ij[inside, 1]), shape)]
    tops = top[chosen] - floor_z_m
    found.update(
        low_top_columns=int(chosen.sum()),
        low_top_runs=len(np.unique(run[chosen])),
        low_top_heights_m=[round(float(tops.min()), 3), round(float(np.median(tops)), 3)],
        low_top_slice_points_replaced=int(gone.sum()),
    )
    return np.concatenate([slice_points[~gone], up]), found
