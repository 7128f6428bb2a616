"""From Hough segments to the room's walls for one α (thesis 5.2.4.2-5.2.5): merge, the top-reach test,
regularize, refine, connect, the room polygon and the walls that belong to it; and the choice of α among
the candidates' models."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.connect import EXTENDED, OBSERVED, Connected, connect_detailed
from tasks.lines import (
    STEP_MIN_CELLS,
    LinesConfig,
    MergedLines,
    angle_difference,
    angles,
    fit_line,
    lengths,
    line_intersection,
    merge_segments,
    overlapping_parallels,
    point_segment_distances,
    regularize,
    room_polygons,
    rotate_segments,
)
from tasks.walls.beyond import across_beyond_the_room, beyond_the_room
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import (
    TopCells,
    backed_bridges,
    end_distances,
    extend_to_data,
    furniture_in_front,
    lone_directions,
    recess_backs,
    refine_frames,
    refine_offsets,
    seen_through_fronts,
    seen_through_gaps,
    split_faces,
    split_past_corners,
    support_sampler,
    thin_wall_faces,
    top_reach_shares,
    two_faces,
    unshadowed_lines,
)
from tasks.walls.image import Coarse, Grid, Projection, binarize, hough_segments, skeleton, sparse_cells


@dataclass(frozen=True)
class Candidate:
    """The model one α gives (steps 2-7): what the choice of α compares."""

    alpha: float | None
    walls: NDArray
    origin: NDArray
    counts: dict[str, int]
    binary: NDArray
    polygon: Any
    """The room, when the walls enclose one (a partition stub may still dangle in it)."""
    grid_m: float = 0.0
    """The grid the model was made on."""

    @property
    def closed(self) -> bool:
        return self.polygon is not None


SIN_ACROSS = math.sin(math.radians(45.0))
"""Two walls whose directions lie more than 45° apart (the sine of the angle between them above this) are
across each other; closer, they are along each other."""


def with_corners(cand: Candidate, xy: NDArray, cfg: WallsConfig) -> Candidate:
    """An open candidate closed at the corners its data pin (`close_at_corners`, with the slice points
    `xy` (N, 2)), or the candidate itself when that does not close it: what `model_for` with `corners`
    gives, without making the model again."""
    if cand.closed or len(cand.walls) == 0:
        return cand
    closed = close_at_corners(cand.walls, cand.origin, xy, cfg, cand.grid_m)
    if closed is None:
        return cand
    walls, origin, polygon, corner_m, how = closed
    counts = {**cand.counts, "bridged_gap_m": round(corner_m, 3), "corners_closed": how, "walls": len(walls)}
    return replace(cand, walls=walls, origin=origin, polygon=polygon, counts=counts)


def close_at_corners(
    walls: NDArray, origin: NDArray, xy: NDArray, cfg: WallsConfig, grid_m: float
) -> tuple[NDArray, NDArray, Any, float, str] | None:
    """An open room's walls (M, 4) with the collinear gaps the slice points `xy` (N, 2) back
    (`evidence.backed_bridges`) and the corners one wall's data pin (`pinned_corners`), or, when that does
    not close it and `close_unseen_spans` is on, the unseen spans closed as well (`pinned_corners` with
    `across_unseen`): (walls, origin, room, longest extension, what closed it: "pinned" or "across unseen
    spans") when that closes the room, else None."""
    backed = backed_bridges(walls, origin, xy, cfg) if len(walls) else np.zeros((0, 4))
    if len(backed):
        walls = np.concatenate([walls, backed])
        origin = np.concatenate([origin, np.full(len(backed), EXTENDED, dtype=origin.dtype)])
    closed = pinned_corners(
        walls, origin, cfg.lines.extend_m, grid_m, cfg.lines.offset_tol_m, thin_m=cfg.thin_wall_max_m
    )
    if closed is not None:
        return (*closed, "pinned")
    if cfg.close_unseen_spans:
        # nothing pins the corners: an unseen span (a corner both walls point at, a collinear gap) is closed
        # where nothing the capture saw stands against it (`pinned_corners` with `across_unseen`)
        def across(w: NDArray, o: NDArray) -> tuple[NDArray, NDArray, Any, float] | None:
            return pinned_corners(
                w,
                o,
                cfg.lines.extend_m,
                grid_m,
                cfg.lines.offset_tol_m,
                True,
                points=xy,
                thin_m=cfg.thin_wall_max_m,
                angle_tol_deg=cfg.lines.angle_tol_deg,
            )

        box = _box_fronts(walls, origin, grid_m, cfg.lines.offset_tol_m, xy)
        if box.any():
            # a furniture box against a wall whose line beyond it the capture did not see: the room is closed
            # without the box (the wall runs on behind it) where that closes it
            closed = across(walls[~box], origin[~box])
            if closed is not None and _held(closed, walls, origin, xy, cfg.lines):
                return (*closed, "across unseen spans")
        closed = across(walls, origin)
        for aside_of in (
            lambda: _jambs(walls, grid_m, cfg.thin_wall_max_m),
            lambda: _box_sides(walls, grid_m, cfg.lines.offset_tol_m, cfg.thin_wall_max_m, xy),
        ):
            aside = aside_of() if closed is None else np.zeros(0, dtype=bool)
            if not aside.any():
                continue
            # a door's jamb standing free on a wall's line stops no wall run on along that line (the wall goes
            # on past the door), nor does a furniture box's side at a wall's end (the wall runs on behind the
            # box): the room is closed without them, which are then its walls again
            closed = across(walls[~aside], origin[~aside])
            if closed is not None:
                polygon, w, o, _ = _room_polygon(
                    np.concatenate([closed[0], walls[aside]]),
                    np.concatenate([closed[1], origin[aside]]),
                    grid_m,
                )
                closed = None if polygon is None else (w, o, polygon, closed[3])
        if closed is not None and _held(closed, walls, origin, xy, cfg.lines):
            return (*closed, "across unseen spans")
    return None


def _held(closed: tuple, walls: NDArray, origin: NDArray, xy: NDArray, lcfg: LinesConfig) -> bool:
    """Does the room `closed` across unseen spans ((walls, origin, room, longest extension)) hold the slice
    points `xy` (N, 2) (`_points_held`), and run along no line of a wall it leaves outside (of the walls
    (M, 4) and their `origin` before closing: `_along_a_line_outside`)?"""
    if _points_held(closed[2], xy, UNSEEN_HELD_BUFFER_M) < UNSEEN_HELD_MIN_SHARE:
        return False
    return not _along_a_line_outside(closed[0], closed[1], closed[2], walls, origin, lcfg)


def _along_a_line_outside(
    walls: NDArray, origin: NDArray, polygon: Any, seen: NDArray, seen_origin: NDArray, lcfg: LinesConfig
) -> bool:
    """Does a wall the closing added (`EXTENDED`, of `walls` (M, 4) bounding `polygon`) run along the line of
    an observed wall of `seen` (K, 4) that lies wholly outside the room (none of it within
    `UNSEEN_HELD_BUFFER_M`), and along no observed wall of the room? The room was then closed along the line
    of a wall it does not hold, nothing it saw pinning that side: the next room's wall seen through a door
    (degraded 127 hall: a partition 0.7 m behind the corridor's wall, whose seen part the highest alpha lost,
    run on across the corridor as its end wall). A wall of the room run on across an unseen span, or one
    added where an observed wall of the room ends within `lcfg.max_gap_m` of its ends (its corner seen up
    to), may have the building's wall in line beyond the room's corner (degraded 104 hall: its end wall in
    line with the building's, seen past the corridor's corner through a door). In line: parallel within
    `lcfg.angle_tol_deg`, the middle within `lcfg.offset_tol_m` of the added wall's line."""
    added = walls[origin == EXTENDED]
    observed = seen[seen_origin == OBSERVED]
    if len(added) == 0 or len(observed) == 0:
        return False
    outside = _lines_away_from(observed, polygon, UNSEEN_HELD_BUFFER_M)
    if not outside.any():
        return False
    u = (added[:, 2:] - added[:, :2]) / np.maximum(lengths(added), 1e-12)[:, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    sin_tol = math.sin(math.radians(lcfg.angle_tol_deg))

    def along(lines: NDArray) -> NDArray[np.bool_]:
        """(len(lines), len(added)) which lines lie in line with which added walls."""
        parallel = np.abs(np.sin(angles(lines)[:, None] - angles(added)[None, :])) <= sin_tol
        mid = 0.5 * (lines[:, None, :2] + lines[:, None, 2:]) - added[None, :, :2]
        return parallel & (np.abs((mid * normal[None]).sum(axis=2)) <= lcfg.offset_tol_m)

    kept = walls[origin == OBSERVED]
    # held by the room: in line with one of its observed walls, or reaching one within a gap at an end (its
    # corner seen up to)
    ends = np.concatenate([added[:, :2], added[:, 2:]])
    gap = point_segment_distances(ends, kept).min(axis=1, initial=np.inf)
    near = gap.reshape(2, -1).min(axis=0) <= lcfg.max_gap_m
    held = along(kept).any(axis=0) | near
    return bool((along(observed[outside]) & ~held[None, :]).any())


def _end_distances(walls: NDArray) -> tuple[NDArray, NDArray]:
    """The walls' (M, 4) ends (2M, 2), end k of wall i at row i + k M, and their distances (2M, M) to the
    walls, each to its own wall infinite."""
    n = len(walls)
    ends = np.concatenate([walls[:, :2], walls[:, 2:]])
    d = point_segment_distances(ends, walls)
    d[np.arange(2 * n), np.tile(np.arange(n), 2)] = np.inf
    return ends, d


def _geometry(walls: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """The walls' (M, 4) lengths, ends (2M, 2) and their distances (2M, M) to the walls (`_end_distances`),
    angles and unit normals (M, 2)."""
    th = angles(walls)
    return lengths(walls), *_end_distances(walls), th, np.column_stack([-np.sin(th), np.cos(th)])


def _jambs(walls: NDArray, tol_m: float, max_m: float) -> NDArray[np.bool_]:
    """(M,) the walls (M, 4) that are a door's jamb: no longer than `max_m` (a wall's thickness), joined to no
    other wall (both ends more than `tol_m` from every other), across (more than 45°) the line of another
    wall that they reach (within `tol_m`) without touching that wall: they stand in a gap in its line."""
    n = len(walls)
    out = np.zeros(n, dtype=bool)
    if n < 3 or max_m <= 0:
        return out
    L = lengths(walls)
    _, d = _end_distances(walls)
    th = angles(walls)
    for k in np.flatnonzero((L <= max_m) & (np.minimum(d[:n], d[n:]).min(axis=1) > tol_m)):
        for j in range(n):
            if j == k or abs(math.sin(th[k] - th[j])) < SIN_ACROSS:
                continue
            hit = line_intersection(walls[k], walls[j])
            if hit is None:
                continue
            m_k, m_j = tol_m / max(L[k], 1e-12), tol_m / max(L[j], 1e-12)
            if -m_k <= hit[1] <= 1 + m_k and not -m_j <= hit[2] <= 1 + m_j:
                out[k] = True
                break
    return out


def _box_sides(
    walls: NDArray, tol_m: float, offset_m: float, thin_m: float, points: NDArray
) -> NDArray[np.bool_]:
    """(M,) the walls (M, 4) that are a furniture box's side at a wall's end: shorter than
    `UNSEEN_RUN_FREE_SPAN_M`, nothing else on their line (within `offset_m`), one end joined (within
    `tol_m`) only to the end of one longer wall across (more than 45°), whose line (its pieces in line
    followed) starts at a corner with a wall across at least `UNSEEN_RUN_FREE_SPAN_M` long, the other end
    free, and the box's front there: at least `BOX_FRONT_MIN_POINTS` of the slice `points` (N, 2) on the
    line through the free end along the wall (within `BEHIND_BAND_M`), from `BEHIND_BAND_M` to `BOX_FRONT_M`
    beyond the side's line and reaching deeper than `thin_m` (a door's jamb, a wall's noise band do not).
    A wardrobe standing in a corner whose walls the capture saw only beside it: the wall seen up to the box
    ends at the box's side, and that L is no corner of the room (a room's wall seen only near its corner
    has nothing of the room beyond it; degraded 300 r3 and 110 r3 stayed open)."""
    n = len(walls)
    out = np.zeros(n, dtype=bool)
    if n < 4 or len(points) == 0:
        return out
    L, ends, d, th, nrm = _geometry(walls)
    for k in np.flatnonzero(L < UNSEEN_RUN_FREE_SPAN_M):
        near = d[[k, k + n]] <= tol_m  # (2, M): the walls each end of k touches
        if near.any(axis=0).sum() != 1 or near.any(axis=1).all():
            continue
        e = k + n * int(near[1].any())  # the joined end; the free one is e's other row
        j = int(np.flatnonzero(near.any(axis=0))[0])
        far_end = walls[j, 2:] if np.hypot(*(walls[j, :2] - ends[e])) <= tol_m else walls[j, :2]
        if (
            abs(math.sin(th[k] - th[j])) < SIN_ACROSS
            or L[j] <= L[k]
            or np.hypot(*(far_end - ends[e])) < L[j] - tol_m
        ):
            continue  # not across, not longer, or not joined at the wall's end
        run = (ends[e] - far_end) / max(L[j], 1e-12)  # the way the wall runs into the joint
        # the wall's line, followed through its pieces in line, ends at a corner with a wall across at least
        # `UNSEEN_RUN_FREE_SPAN_M` long: a wall of the room, not a box's front (its other side)
        pieces = ends.reshape(2, n, 2)[:, _in_line(walls, nrm, j, offset_m)].reshape(-1, 2)
        start = pieces[int(np.argmin(pieces @ run))]
        corner = (point_segment_distances(start[None], walls)[0] <= tol_m) & (L >= UNSEEN_RUN_FREE_SPAN_M)
        if (
            not (corner & (np.abs(np.sin(th - th[j])) >= SIN_ACROSS)).any()
            or _in_line(walls, nrm, k, offset_m).sum() > 1
        ):
            continue
        # its front: points on the line through its free end along the wall, from beyond the side's line on
        # (`BEHIND_BAND_M`) and deeper than a wall is thick (`thin_m`: no door's jamb, no wall's noise)
        rel = points - ends[(e + n) % (2 * n)]
        along, across = rel @ run, np.abs(rel @ np.array([-run[1], run[0]]))
        front = (along >= BEHIND_BAND_M) & (along <= BOX_FRONT_M) & (across <= BEHIND_BAND_M)
        out[k] = int(front.sum()) >= BOX_FRONT_MIN_POINTS and float(along[front].max()) >= thin_m
    return out


def _box_fronts(
    walls: NDArray, origin: NDArray, tol_m: float, offset_m: float, points: NDArray
) -> NDArray[np.bool_]:
    """(M,) the walls (M, 4) that are a furniture box's side and front against a wall the capture saw up to
    the box only. The side: observed, shorter than `UNSEEN_RUN_FREE_SPAN_M`, alone on its line (within
    `offset_m`), joined (within `tol_m`) at one end to the end of a wall across it at least
    `UNSEEN_RUN_FREE_SPAN_M` long and at the other to the end of the front, and leading from the wall's
    line into the room (where most of the slice `points` (N, 2) are). The front: across the side, no longer
    than `BOX_FRONT_MAX_M`, alone on its line, running on the way the wall runs into the side, its other end
    free. The wall is no alcove's back: its other end is not joined to a short wall leading into the room as
    well, then to one along the wall (the alcove's other side and the room's wall beyond it). Nothing the
    capture saw tells such a box from a step in the room's wall but that the wall runs on behind a box
    (degraded 253 r4, 272 r4: a wardrobe's side and front closed as a step, the front run on to the next
    wall)."""
    n = len(walls)
    out = np.zeros(n, dtype=bool)
    if n < 4 or len(points) == 0:
        return out
    L, ends, d, th, nrm = _geometry(walls)
    joined = d <= tol_m  # (2M, M): the walls each end touches
    centre = np.median(points, axis=0)

    def end_at(w: int, p: NDArray) -> int:
        """The row in `ends` of wall w's end at p (within `tol_m`), or -1."""
        near = [r for r in (w, w + n) if np.hypot(*(ends[r] - p)) <= tol_m]
        return near[0] if near else -1

    def alcove_back(j: int, far: int, inward: NDArray, k: int) -> bool:
        """Does wall j's end row `far` lead to a short wall across j (not k) going `inward`, and that to a
        wall along j?"""
        for s in np.flatnonzero(joined[far]):
            s_end = end_at(s, ends[far])
            if (
                s == k
                or s_end < 0
                or L[s] >= UNSEEN_RUN_FREE_SPAN_M
                or abs(math.sin(th[s] - th[j])) < SIN_ACROSS
            ):
                continue
            other = (s_end + n) % (2 * n)
            if float((ends[other] - ends[far]) @ inward) <= 0:
                continue
            nxt = np.setdiff1d(np.flatnonzero(joined[other]), [j])
            if (np.abs(np.sin(th[nxt] - th[j])) < SIN_ACROSS).any():
                return True
        return False

    for k in np.flatnonzero((L < UNSEEN_RUN_FREE_SPAN_M) & (origin == OBSERVED)):
        touch = joined[[k, k + n]]
        if not (touch.sum(axis=1) == 1).all() or touch.any(axis=0).sum() != 2:
            continue
        if _in_line(walls, nrm, k, offset_m).sum() > 1:
            continue
        for e in (k, k + n):  # the side's end at the wall, its other end at the front
            e2 = (e + n) % (2 * n)
            j, f = int(np.flatnonzero(joined[e])[0]), int(np.flatnonzero(joined[e2])[0])
            at_j, at_f = end_at(j, ends[e]), end_at(f, ends[e2])
            if (
                at_j < 0
                or at_f < 0
                or L[j] < UNSEEN_RUN_FREE_SPAN_M
                or L[f] > BOX_FRONT_MAX_M
                or min(abs(math.sin(th[k] - th[j])), abs(math.sin(th[k] - th[f]))) < SIN_ACROSS
                or joined[(at_f + n) % (2 * n)].any()
                or _in_line(walls, nrm, f, offset_m).sum() > 1
            ):
                continue
            far_j = (at_j + n) % (2 * n)
            run = (ends[at_j] - ends[far_j]) / max(L[j], 1e-12)  # the way the wall runs into the side
            across = np.array([-run[1], run[0]])
            inward = across * np.sign(float((ends[e2] - ends[e]) @ across))
            if (
                float((ends[(at_f + n) % (2 * n)] - ends[e2]) @ run) > 0
                and float((centre - ends[e]) @ inward) > 0
                and not alcove_back(j, far_j, inward, k)
            ):
                out[[k, f]] = True
    return out


BOX_FRONT_MAX_M = 1.2
"""`_box_fronts`: the longest front of a furniture box against a wall (a wardrobe or shelf one or two doors
wide)."""


def _in_line(walls: NDArray, nrm: NDArray, k: int, offset_m: float) -> NDArray[np.bool_]:
    """(M,) the walls (M, 4), unit normals `nrm`, on wall k's line (within 45° of its direction, both ends
    within `offset_m` of it), k among them."""
    off = np.abs((walls.reshape(-1, 2, 2) - walls[k, :2]) @ nrm[k]).max(axis=1)
    return (off <= offset_m) & (np.abs(nrm[:, 0] * nrm[k, 1] - nrm[:, 1] * nrm[k, 0]) < SIN_ACROSS)


BOX_FRONT_M = 0.4
"""`_box_sides`: how far beyond a box's side its front is looked for."""
BOX_FRONT_MIN_POINTS = 10
"""`_box_sides`: the fewest slice points that show the box's front."""


def model_for(
    proj: Projection,
    cfg: WallsConfig,
    alpha: float | None,
    xy: NDArray | None = None,
    coarse: Coarse | None = None,
    corners: NDArray | None = None,
) -> Candidate:
    """Steps 2-7 for one α; the slice points `xy` (N, 2), when given, refine the wall offsets; the `coarse`
    projection, when given, adds the sparsely seen walls (`image.sparse_cells`); with `corners` (the slice
    points (N, 2) again), a room that stays open gets the collinear gaps they back
    (`evidence.backed_bridges`) and the corners its data pin (`pinned_corners`; its bridged gap is the
    longest extension), kept when that closes it."""
    grid = proj.grid
    # the tall cells go through the image steps; the top-reach test is made on the lines (`_topology`)
    binary = binarize(proj.counts, proj.tall, cfg, alpha)
    skel = skeleton(binary, cfg)
    hough = hough_segments(skel, grid, cfg)
    low_share = support_sampler(proj.low, grid, cfg.support_tol_m)
    top = TopCells(binary & proj.top, grid, binary)
    found = _topology(hough, cfg.lines, cfg, grid, binary, top, proj, low_share, xy)
    sparse_px = 0
    if found.polygon is None and coarse is not None and len(found.walls):
        # an open room: the sparsely seen stretches that continue one of its walls' lines join the image
        extra = sparse_cells(binary, coarse, cfg, alpha) & _along_lines(
            found.walls, grid, binary.shape, max(cfg.lines.offset_tol_m, coarse.factor * grid.size)
        )
        sparse_px = int(extra.sum())
        if sparse_px:
            binary = binary | extra
            skel = skeleton(binary, cfg)
            hough = hough_segments(skel, grid, cfg)
            top = TopCells(binary & proj.top, grid, binary)
            found = _topology(hough, cfg.lines, cfg, grid, binary, top, proj, low_share, xy)
    bridged = corners_closed = None
    held_refused: list[float] = []
    unheld_refused: list[float] = []
    # the usual reach's walls, for the corners: the wider reaches' joins across the room were refused
    last = found if found.polygon is None else None
    for gap in cfg.bridge_gaps_m if found.polygon is None else ():
        # the unseen span may be a corner as well as a stretch of one wall: ends reach as far
        lines = replace(cfg.lines, max_gap_m=gap, extend_m=max(cfg.lines.extend_m, gap))
        wider = _topology(hough, lines, cfg, grid, binary, top, proj, low_share, xy)
        # a wall made only by extension (a perpendicular join) longer than the usual reach needs data:
        # without it the wider reach would cut off a poorly seen part of the room (behind a partition).
        # Longer by more than the lines' own tolerance: the join's length is the distance between two
        # fitted lines (an alcove as deep as the reach)
        made = wider.origin != OBSERVED
        long_made = made & (lengths(wider.walls) > cfg.lines.extend_m + cfg.lines.offset_tol_m)
        if (
            wider.polygon is not None
            and not (wider.share(wider.walls[long_made]) < cfg.lines.min_overlap).any()
        ):
            # ...and the room it closes must hold most of the walls seen (not a box in a corner)
            if _held_share(found.walls, found.origin, wider.polygon, cfg.lines.offset_tol_m) < HELD_MIN_SHARE:
                held_refused.append(gap)
                continue
            # without a ceiling (a handheld scan) it must also hold the data seen, as a room closed across
            # unseen spans must: most of the slice's occupied cells lie in the room (a closet the wider
            # joins made in a corner leaves the room's other walls' data outside)
            if proj.open_top and _points_held(wider.polygon, _occupied(proj), UNSEEN_HELD_BUFFER_M) < (
                UNSEEN_HELD_MIN_SHARE
            ):
                unheld_refused.append(gap)
                continue
            found, bridged = wider, gap
            break
    if corners is not None and found.polygon is None and last is not None:
        # no reach closed it, nor the coarser grid: the collinear gaps the slice points back are bridged
        # and a corner that one wall's data pin is closed along the other wall's line, however far that
        # was unseen (`pinned_corners`)
        closed = close_at_corners(last.walls, last.origin, corners, cfg, grid.size)
        if closed is not None:
            walls, origin, polygon, corner_m, corners_closed = closed
            found = replace(last, walls=walls, origin=origin, polygon=polygon)
            bridged = round(corner_m, 3)
    stats = {
        "binary_px": int(found.binary.sum()),
        "skeleton_px": int(skel.sum()),
        "hough_segments": len(hough),
        "orientation_clusters": len(found.merged.orientation_deg),
        "orientation_criterion": found.merged.orientation_criterion,
        "regularization_refused": found.refused,
        "lines_joined_after_regularization": found.joined,
        "frame_fit_turn_max_deg": found.frame_turn_deg,
        "merged_lines": len(found.merged.segments),
        "lines_below_top": found.below_top,
        "lines_furniture_no_ceiling": found.furniture,
        "walls_beyond_room_no_ceiling": found.beyond,
        "furniture_rules_no_ceiling": found.furniture_rules,
        "removed_extensions": len(found.conn.removed),
        "walls_outside_room": found.outside,
        "walls_seen_through_gaps": found.through,
        "walls_hung_from_ceiling": int(found.hung.sum()),
        "walls_stray": found.stray,
        "corner_jogs": found.jogs,
        "bridged_gap_m": bridged,
        "bridged_refused_outside_m": held_refused,
        "bridged_refused_data_outside_m": unheld_refused,
        "corners_closed": corners_closed,
        "sparse_px": sparse_px,
        "walls": len(found.walls),
    }
    return Candidate(alpha, found.walls, found.origin, stats, found.binary, found.polygon, grid.size)


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
    through: int = 0
    """Lines seen through a gap in another wall of the room (`evidence.seen_through_gaps`), dropped."""
    refused: int = 0
    """Lines whose regularization was refused (it would move them beyond their data's noise)."""
    stray: int = 0
    """Walls dropped because no orientation cluster and too little data supported them (`stray_walls`), or
    as a streak leaving a wall at a narrow angle (`acute_stubs`)."""
    furniture: int = 0
    """Lines dropped as furniture in front of a wall in a slice without a ceiling (`furniture_in_front`)."""
    beyond: int = 0
    """Lines dropped as seen beyond the room in a slice without a ceiling (`beyond_the_room`)."""
    furniture_rules: dict[str, int] = field(default_factory=dict)
    """How many lines each of `furniture_in_front`'s rules took (before the top-reach test's own drops)."""
    frame_turn_deg: float = 0.0
    """The largest turn the fit of the frames to the points made (`evidence.refine_frames`), degrees."""
    jogs: int = 0
    """Jogs at a corner's tip dropped, their two walls run on to the corner (`corner_jogs`)."""
    joined: int = 0
    """Lines merged into another after the regularization (`join_overlapping`)."""


def _along_lines(walls: NDArray, grid: Grid, shape: tuple[int, ...], tol_m: float) -> NDArray:
    """(H, W) the cells within `tol_m` of the lines through `walls` (M, 4), across the whole image: where a
    sparsely seen stretch continues one of the walls found."""
    band = np.zeros(shape[:2], dtype=np.uint8)
    reach = grid.size * (shape[0] + shape[1])
    d = walls[:, 2:] - walls[:, :2]
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    ends = np.concatenate([walls[:, :2] - reach * d, walls[:, 2:] + reach * d], axis=1)
    px = grid.to_pixels(ends.reshape(-1, 2)).reshape(-1, 4)
    thick = 2 * math.ceil(tol_m / grid.size) + 1
    for s in px:
        a, b = (round(s[0]), round(s[1])), (round(s[2]), round(s[3]))
        ok, a, b = cv2.clipLine((0, 0, shape[1], shape[0]), a, b)
        if ok:
            cv2.line(band, a, b, 1, thick)
    return band.astype(bool)


def _free_ends(lines: NDArray, tol_m: float) -> NDArray[np.bool_]:
    """(2M,) whether end k of line i (row i + k M) lies further than `tol_m` from every other line."""
    if len(lines) == 0:
        return np.zeros(0, dtype=bool)
    return end_distances(lines)[1].min(axis=1, initial=np.inf) > tol_m


def _wall_data(binary: NDArray, top: NDArray, lines: NDArray, grid: Grid, tol_m: float) -> NDArray:
    """The binary cells that are wall data: those near the slice top, and the others within `tol_m` of
    a kept line (the part of a wall seen below the top). A cabinet's cells, away from every kept line,
    do not back an extension."""
    near = np.zeros(binary.shape, dtype=np.uint8)
    px = grid.to_pixels(lines.reshape(-1, 2)).reshape(-1, 4) if len(lines) else np.zeros((0, 4))
    thick = 2 * math.ceil(tol_m / grid.size) + 1
    for s in px:
        cv2.line(near, (round(s[0]), round(s[1])), (round(s[2]), round(s[3])), 1, thick)
    return binary & (top | near.astype(bool))


LOW_REACH_MAX_SHARE = 0.2
"""`split_below_top`: the pieces of a line's one side reach the top over at most this share of their length
(a piece of a cabinet's front may graze the wall's top-reaching data at its end)."""


def stop_at_steps(before: NDArray, after: NDArray, chain: NDArray) -> NDArray:
    """`after` (M, 4), the lines `before` (M, 4) extended along their data, with no line of a chain merging
    split at a step (the same `chain` (M,)) run on past where its neighbour across the step begins: the two
    sides of a jog of a few cm lie in each other's band of data, and each would run on over the other (the
    room's outline would then double back along the wall)."""
    out = np.array(after, dtype=np.float64, copy=True)
    for c in np.unique(chain):
        idx = np.flatnonzero(chain == c)
        if len(idx) < 2:
            continue
        d = before[idx[0], 2:] - before[idx[0], :2]
        u = d / max(float(np.hypot(*d)), 1e-12)
        tb = np.stack([before[idx, :2] @ u, before[idx, 2:] @ u], axis=1)  # (K, 2)
        lo_b, hi_b, mid = tb.min(axis=1), tb.max(axis=1), tb.mean(axis=1)
        for a, i in enumerate(idx):
            ends = np.array([out[i, :2] @ u, out[i, 2:] @ u])
            later, earlier = mid > mid[a], mid < mid[a]
            hi = max(hi_b[a], lo_b[later].min()) if later.any() else np.inf
            lo = min(lo_b[a], hi_b[earlier].max()) if earlier.any() else -np.inf
            for e in range(2):
                t = float(np.clip(ends[e], lo, hi))
                out[i, 2 * e : 2 * e + 2] += (t - ends[e]) * u
    return out


def split_below_top(
    hough: NDArray, merged: MergedLines, top: TopCells, cfg: WallsConfig, angle_tol_deg: float, quantum: float
) -> MergedLines:
    """`merged` with each line whose pieces at one end stop below the slice top, a step in front of the
    rest, cut there into two lines of one chain (a step `tasks.connect` may join).

    The merge takes parallel pieces within `offset_tol_m` of each other as one wall unless the data show
    a step between them (`tasks.lines._step_cut`); a cabinet standing in an alcove, its front a few cm in
    front of the alcove's mouth and seen askew, passes as clutter of the wall beside it and carries the
    wall across the mouth, which then hides the alcove's back wall as a wall seen through a gap. The
    Hough pieces themselves tell them apart: the wall's reach the slice top, the cabinet's stop below it.
    A line is cut between its pieces (in order along it) where those on one side (at least
    `lines.min_length_m` of line) lie more than `STEP_MIN_CELLS` grid cells (their weighted mean offset)
    from the others, the two sides overlap along the line by no more than that step and `STEP_MIN_CELLS`
    cells, one side's pieces reach the top (`min_top_share` of a piece on top-reaching data) over at least
    half their length, the other's over at most `LOW_REACH_MAX_SHARE`, and no piece below the top lies
    between the cut and the reaching side's first piece that reaches it (a wall's end seen askew below the
    top, its mean on the wall's line, is not cut where its first half leaves the line). Of several such
    cuts, the one that leaves the most length on its own side (reaching the top or not). The line fitted to
    the reaching side must lie no more askew of the pieces' orientation cluster than the line through all
    of them. The top-reach test then judges each line on its own."""
    if cfg.top_reach_m is None or len(merged.segments) == 0:
        return merged
    hough = np.asarray(hough, dtype=np.float64)
    labels = merged.labels.copy()
    reach = top_reach_shares(hough, top, cfg.top_share_tol_m, angle_tol_deg) >= cfg.min_top_share
    hl = lengths(hough)
    segments, chain = list(merged.segments), list(merged.chain)
    for j in range(len(merged.segments)):
        members = np.flatnonzero(labels == j)
        if len(members) < 2 or reach[members].all() or not reach[members].any():
            continue
        # along the pieces' orientation cluster: the line fitted through a wall and a front askew is askew
        phi = math.radians(
            float(merged.orientation_deg[np.bincount(merged.orientation_labels[members]).argmax()])
        )
        u = np.array([math.cos(phi), math.sin(phi)])
        ta, tb = hough[members, :2] @ u, hough[members, 2:] @ u
        t0, t1 = np.minimum(ta, tb), np.maximum(ta, tb)
        order = np.argsort(t0, kind="stable")
        members, t0, t1 = members[order], t0[order], t1[order]
        off = 0.5 * (hough[members, :2] + hough[members, 2:]) @ np.array([-u[1], u[0]])
        w, hit = hl[members], reach[members]
        up = w * hit
        # the cut that best parts the pieces reaching the top from those that do not (the most length on
        # its own side), where the two sides step apart and do not overlap along the line
        best, best_score, low_first = None, -np.inf, True
        for k in range(1, len(members)):
            a, b = slice(0, k), slice(k, None)
            step = abs(float(np.average(off[a], weights=w[a]) - np.average(off[b], weights=w[b])))
            if (
                step <= STEP_MIN_CELLS * quantum
                or float(t1[a].max() - t0[k]) > step + STEP_MIN_CELLS * quantum
            ):
                continue  # no step, or the two sides overlap along the line: pieces of one wall
            ra, rb = up[a].sum() / w[a].sum(), up[b].sum() / w[b].sum()
            if min(ra, rb) > LOW_REACH_MAX_SHARE or max(ra, rb) < 0.5:
                continue
            if ra < rb:
                ragged = (t0[b][~hit[b]] < t0[b][hit[b]].min()).any()
            else:
                ragged = (t1[a][~hit[a]] > t1[a][hit[a]].max()).any()
            if ragged:
                continue  # pieces below the top run on past the cut: the cut is not where the top changes
            score = (w[a] - up[a]).sum() + up[b].sum() if ra < rb else up[a].sum() + (w[b] - up[b]).sum()
            if score > best_score:
                best, best_score, low_first = k, score, ra < rb
        if best is None:
            continue
        low, high = (members[:best], members[best:]) if low_first else (members[best:], members[:best])
        front = fit_line(hough[low], np.ones(len(low)))[0]
        wall = fit_line(hough[high], np.ones(len(high)))[0]
        if float(lengths(front[None])[0]) < cfg.lines.min_length_m:
            continue
        # the wall left must lie straighter along its cluster than the line through both (a front seen askew
        # tilts that line); a cut that leaves it more askew is of pieces of one wall's ragged data
        askew = np.abs(np.sin(angles(np.array([wall, merged.segments[j]])) - phi))
        if askew[0] > askew[1]:
            continue
        segments[j] = wall
        labels[low] = len(segments)
        segments.append(front)
        chain.append(chain[j])
    if len(segments) == len(merged.segments):
        return merged
    return replace(merged, segments=np.array(segments), labels=labels, chain=np.array(chain, dtype=np.intp))


def _topology(
    hough: NDArray,
    lcfg: LinesConfig,
    cfg: WallsConfig,
    grid: Grid,
    binary: NDArray,
    top: TopCells,
    proj: Projection,
    low_share,
    xy: NDArray | None,
) -> _Topology:
    """Steps 5-7 on the Hough segments: merge, the top-reach test, regularize, refine (when `xy` is
    given), connect, then keep the room's walls."""
    merged = merge_segments(hough, lcfg, quantum=grid.size)
    merged = split_below_top(hough, merged, top, cfg, lcfg.angle_tol_deg, grid.size)
    lines, chain = merged.segments, merged.chain
    noise = np.maximum(
        line_noise(hough, merged.labels, lines, grid.size), band_noise(lines, top.data_xy, lcfg.offset_tol_m)
    )
    below_top = furniture_lines = beyond_lines = 0
    why: dict[str, int] = {}
    if cfg.top_reach_m is not None and len(lines):
        reach = top_reach_shares(lines, top, cfg.top_share_tol_m, lcfg.angle_tol_deg)
        keep = reach >= cfg.min_top_share
        keep = keep | thin_wall_faces(lines, keep, top, cfg, lcfg.angle_tol_deg)
        keep |= unshadowed_lines(lines, keep, top, cfg)
        if proj.open_top and cfg.furniture_max_length_m > 0:
            # nothing seen above the slice: furniture reached its top too
            occupied = _occupied(proj)
            # a line run on past a reflex corner of the room, across a gap in its data, is two things
            lines, src = split_past_corners(lines, _centre(lines[keep]), occupied, cfg, lcfg.angle_tol_deg)
            why["split_past_corner"] = len(src) - len(keep)
            noise, keep, chain = noise[src], keep[src], _split_chains(chain, src, len(keep))
            furniture = furniture_in_front(
                lines, _centre(lines[keep]), cfg, lcfg.angle_tol_deg, why=why, occupied=occupied, source=src
            )
            # and a direction the slice shows over only a few decimetres is a rounded or faceted furniture face
            furniture |= lone_directions(lines, cfg.furniture_lone_direction_m, lcfg.angle_tol_deg, grid.size)
            furniture[~keep] = False
            furniture_lines = int(furniture.sum())
            keep &= ~furniture
            # an open shelf's front, seen through: the wall behind it
            moved, sides, lines = seen_through_fronts(lines, keep, _centre(lines[keep]), occupied, cfg)
            keep &= ~sides
            why["seen_through"] = int(moved.sum())
            furniture_lines += int(sides.sum())
            # a box's front in a recess whose side was seen past it: the recess's back
            moved, sides, lines = recess_backs(lines, keep, _centre(lines[keep]), occupied, cfg)
            keep &= ~sides
            why["recess_back"] = int(moved.sum())
            furniture_lines += int(sides.sum())
        below_top = int((~keep).sum()) - furniture_lines
        lines, noise, chain = lines[keep], noise[keep], chain[keep]
    wall_data = _wall_data(binary, proj.top, lines, grid, cfg.support_tol_m)
    share = support_sampler(wall_data, grid, cfg.support_tol_m)
    reg, rotation, refused = regularize_within_noise(lines, noise, lcfg)
    before = len(reg)
    reg, rotation, refused, chain = join_overlapping(reg, rotation, refused, chain, lcfg, grid.size)
    joined = before - len(reg)
    turn = np.zeros(len(reg))
    if xy is None:
        refined = reg
    else:
        turn = refine_frames(
            reg, refused, xy, proj.cell, grid, cfg.refine_band_m, math.radians(lcfg.angle_tol_deg)
        )
        reg, rotation = rotate_segments(reg, turn), rotation + turn
        refined = refine_offsets(reg, xy, proj.cell, grid, cfg.refine_band_m)
        # a thin partition one binarization took as one wall: its two faces
        faces = two_faces(reg, xy, proj.cell, grid, cfg.refine_band_m, cfg.thin_wall_min_m)
        refined, src = split_faces(reg, refined, faces, lcfg.angle_tol_deg, grid.size)
        rotation = rotation[src]
        chain = _split_chains(chain, src, len(np.unique(src)))  # the second faces come last
    unextended = refined
    refined = extend_to_data(refined, wall_data, grid, cfg.end_tol_m, cfg.end_gap_m, lcfg.extend_m)
    if not proj.open_top:
        # a free end (no other line within `lines.max_gap_m`) runs on through its wall's data however sparse
        # (a Kinect's far stretch, fewer points per cell than the binarization's share): any wall-like cell.
        # Without a ceiling furniture reaches the top like the walls, and a cabinet in line with a wall
        # would carry its end on; an end at a corner has its wall's end already
        free = _free_ends(refined, lcfg.max_gap_m).reshape(2, -1).T  # (M, 2): per line, its two ends
        some = free.any(axis=1)
        if some.any():
            sparse = _wall_data(binary | proj.wall_like, proj.top, lines, grid, cfg.support_tol_m)
            further = extend_to_data(refined[some], sparse, grid, cfg.end_tol_m, cfg.end_gap_m, lcfg.extend_m)
            refined[some] = np.where(np.repeat(free[some], 2, axis=1), further, refined[some])
    refined = stop_at_steps(unextended, refined, chain)
    # walls of the next rooms, seen through a door in one of this room's walls, go before they shape its corners
    through = seen_through_gaps(
        refined,
        wall_data,
        grid,
        _centre(refined),
        cfg.thin_wall_max_m,
        cfg.through_gap_share,
        cfg.support_tol_m,
    )
    if proj.open_top:
        # nothing seen above the slice (a handheld scan): the wall in front of a door may be barely seen
        centre = _centre(refined, cfg.thin_wall_max_m)
        cut, across = across_beyond_the_room(refined, centre, cfg, lcfg.angle_tol_deg)
        beyond = beyond_the_room(refined, centre, cfg, lcfg.angle_tol_deg, across)
        if beyond.any():
            # a line across held only by a line beyond the room (the next room's corner seen through a door)
            cut, more = across_beyond_the_room(cut, centre, cfg, lcfg.angle_tol_deg, across | beyond)
            across |= more
        refined = cut
        beyond |= across & ~through
        through |= beyond
        beyond_lines = int(beyond.sum())
    if through.any():
        refined, rotation, chain = refined[~through], rotation[~through], chain[~through]
    centres = 0.5 * (refined[:, :2] + refined[:, 2:])

    def support_fn(pieces: NDArray, parent: NDArray) -> NDArray:
        # undo the regularization rotation about the parent wall's centre before looking at the data
        rot = np.where(parent >= 0, -rotation[np.maximum(parent, 0)], 0.0)
        c = np.where(
            parent[:, None] >= 0, centres[np.maximum(parent, 0)], 0.5 * (pieces[:, :2] + pieces[:, 2:])
        )
        return share(rotate_segments(pieces, rot, c))

    # the room's interior, for the joins across unseen walls: the walls' length-weighted centre
    interior = _centre(refined)
    conn = connect_detailed(refined, lcfg, support_fn, interior, step_chain=chain)
    conn = place_steps(conn, refined, proj.counts, grid, lcfg.offset_tol_m, interior)
    walls, origin = _drop_short_stubs(conn.segments, conn.origin, cfg.min_wall_length_m)
    polygon, walls, origin, outside = _room_polygon(walls, origin, grid.size)
    away = _lines_away_from(refined, polygon, grid.size)
    if away.any() and not away.all():
        # a line wholly outside the room (a wall seen through a door) is no wall of it, and must not shape
        # its corners either (its extension trims the room's wall it meets): connect again without it
        def support_kept(pieces: NDArray, parent: NDArray) -> NDArray:
            return support_fn(pieces, np.where(parent >= 0, kept[np.maximum(parent, 0)], -1))

        kept = np.flatnonzero(~away)
        again = connect_detailed(refined[kept], lcfg, support_kept, interior, step_chain=chain[kept])
        again = place_steps(again, refined[kept], proj.counts, grid, lcfg.offset_tol_m, interior)
        w2, o2 = _drop_short_stubs(again.segments, again.origin, cfg.min_wall_length_m)
        p2, w2, o2, out2 = _room_polygon(w2, o2, grid.size)
        if p2 is not None:
            conn, polygon, walls, origin, outside = again, p2, w2, o2, out2 + int(away.sum())
    hung = _hung_from_ceiling(walls, polygon, low_share)
    if hung.any():
        walls, origin = walls[~hung], origin[~hung]
        polygon, walls, origin, _ = _room_polygon(walls, origin, grid.size)
    stray = stray_walls(walls, merged.orientation_deg, share, lcfg) | acute_stubs(walls, lcfg)
    stray |= dangling_extensions(walls, origin, lcfg.offset_tol_m)
    if stray.any():
        walls, origin = walls[~stray], origin[~stray]
        polygon, walls, origin, _ = _room_polygon(walls, origin, grid.size)
    jogs, cornered = corner_jogs(walls, lcfg.offset_tol_m)
    n_jogs = 0
    if jogs.any():
        p2, w2, o2, _ = _room_polygon(cornered[~jogs], origin[~jogs], grid.size)
        if p2 is not None or polygon is None:
            polygon, walls, origin, n_jogs = p2, w2, o2, int(jogs.sum())
    return _Topology(
        merged,
        conn,
        walls,
        origin,
        polygon,
        outside,
        hung,
        below_top,
        wall_data,
        share,
        int(through.sum()) - beyond_lines,
        int(refused.sum()),
        int(stray.sum()),
        furniture_lines,
        beyond_lines,
        why,
        round(math.degrees(float(np.abs(turn).max(initial=0.0))), 4),
        n_jogs,
        joined,
    )


UNSEEN_RUN_RATIO = 2.0
"""`pinned_corners` with `across_unseen`: a wall runs on to an unseen corner for at most this many times the
length its line is seen over (a wall seen over 1.5 m for 3 m, not a 0.5 m furniture face across the room)."""
UNSEEN_RUN_FREE_SPAN_M = 1.0
"""...unless its line is seen over at least this length: then as far as the corner. A wall seen over 1.2 m
runs 3.8 m to its unseen corner; the furniture faces and plant facets that ran on wrongly were shorter
(0.4-0.8 m). On the dev degraded rooms this closed 36 more of 252 rooms, with as many rooms meeting the
targets (2 gained, 2 lost) and 2 more TLS rooms; 4 times the seen length for every wall closed more, but
3 fewer Kinect rooms met them."""


UNSEEN_OVERSHOOT_M = 0.1
"""`pinned_corners` with `across_unseen`: a free end may lie this far past the corner its wall makes with
another (the corner back along the wall): a wall seen obliquely near its unseen corner scatters its points
along its line, in a far Kinect's depth noise (degraded 263 r3: 10 cm)."""


DISTINCT_DIRECTION_DEG = 10.0
"""`pinned_corners` with `across_unseen`: a wall whose direction lies this far from every long observed wall's
and its perpendicular is a wall of its own direction, run on from a seen corner like one that has it."""


BOUNDING_MAX_SHARE = 0.01
"""`pinned_corners` with `across_unseen`: a wall whose line has at most this share of the slice points beyond
it (more than `BEHIND_BAND_M` off it, on its side away from the room) bounds everything the capture saw, and
runs on to a corner however short its seen piece: the far wall of a room seen only over a few dm (a TLS
station's sparse rings) where a furniture front would have the wall's own points, or the room's wing, behind
it. A window's reveal or a few stray points stay below it; a door onto the next room does not."""


def _bounding(
    walls: NDArray, nrm: NDArray, centre: NDArray | None, points: NDArray | None
) -> NDArray[np.bool_]:
    """(M,) which walls (M, 4), unit normals `nrm` (M, 2), have at most `BOUNDING_MAX_SHARE` of the slice
    `points` (N, 2) more than `BEHIND_BAND_M` beyond their lines, on the side away from the room's
    `centre`. A point beyond the line of a wall across (more than 45°) at least `UNSEEN_RUN_FREE_SPAN_M` long
    as well lies off the room's corner: what a door in that wall shows of the next room, it says nothing of
    where this wall ends."""
    if centre is None or points is None or len(points) == 0:
        return np.zeros(len(walls), dtype=bool)
    inward = np.sign(np.einsum("ij,ij->i", centre - walls[:, :2], nrm))
    off = (points @ nrm.T - np.einsum("ij,ij->i", walls[:, :2], nrm)) * inward  # (N, M), + towards the room
    beyond = off < -BEHIND_BAND_M
    across = np.abs(nrm[:, 0, None] * nrm[None, :, 1] - nrm[:, 1, None] * nrm[None, :, 0]) >= SIN_ACROSS
    across &= (lengths(walls) >= UNSEEN_RUN_FREE_SPAN_M)[None, :]  # (M, M): k, and a long wall across k
    off_corner = beyond.astype(np.int64) @ across.T.astype(np.int64) > 0  # (N, M): beyond a wall across k
    return (beyond & ~off_corner).sum(axis=0) <= BOUNDING_MAX_SHARE * len(points)


def _unseen_run_limit(span_m: float, ratio: float = UNSEEN_RUN_RATIO) -> float:
    """How far (m) a wall whose line is seen over `span_m` may run on across an unseen span: `ratio` times
    that, without limit from `UNSEEN_RUN_FREE_SPAN_M` on."""
    return math.inf if span_m >= UNSEEN_RUN_FREE_SPAN_M else ratio * span_m


UNSEEN_HELD_MIN_SHARE = 0.9
"""`close_at_corners`: a room closed across unseen spans must hold at least this share of the slice points
(within `UNSEEN_HELD_BUFFER_M` of it) and those outside that hang together with them (`_points_held`): the
points outside it are what doors show of the next rooms, not a wing of the room its walls were dropped from
(seen through a gap) and a piece across the room cut off. A wall seen through a door, apart from all the room
holds, counts for neither. At 0.85 of all the slice points, a trapezoid room and 25 of the 78 dev and held-out
hallways stayed open for the next room's far wall seen through their doors. Measured on the degraded dev and
held-out rooms: 37 more closed, 3 more Kinect rooms met the targets and 5 fewer (a wing whose points lay
apart cut off); at 0.85 rather than 0.9 of these points, a TLS room cut off a wing too."""
UNSEEN_HELD_BUFFER_M = 0.1


def _split_chains(chain: NDArray, src: NDArray, n_first: int) -> NDArray:
    """The step chains (`stop_at_steps`) of lines cut from lines of `chain`: each line out, `src` naming the
    line it came from, keeps that line's chain, and the second pieces (from index `n_first` on, the last)
    get chains of their own."""
    second = np.arange(len(src)) >= n_first
    return np.where(second, chain.max(initial=-1) + 1 + np.cumsum(second) - 1, chain[src])


def _occupied(proj: Projection) -> NDArray:
    """(K, 2) the centres (m) of the projection's cells holding slice data."""
    rows, cols = np.nonzero(proj.counts > 0)
    return proj.grid.to_metres(np.column_stack([cols, rows]))


def _within(polygon: Any, xy: NDArray, buffer_m: float) -> NDArray[np.bool_]:
    """(N,) which points `xy` (N, 2) lie within `buffer_m` of the room `polygon` (grown with mitred corners)."""
    import shapely

    grown = polygon.buffer(buffer_m, join_style="mitre")
    return shapely.contains_xy(grown, xy[:, 0], xy[:, 1])


def _points_held(polygon: Any, xy: NDArray, buffer_m: float) -> float:
    """Share of the points `xy` (N, 2) within `buffer_m` of the room `polygon` (1 without points), of those
    and the points outside that hang together with them (8-connected cells `buffer_m` a side): a wall seen
    through a door across the next room, apart from everything the room holds, is none of its wings."""
    if len(xy) == 0:
        return 1.0
    from scipy import ndimage

    held = _within(polygon, xy, buffer_m)
    if held.all() or not held.any():
        return float(held.mean())
    ij = np.floor((xy - xy.min(axis=0)) / buffer_m).astype(np.int64)
    cells = np.zeros(tuple(ij.max(axis=0) + 1), dtype=bool)
    cells[ij[:, 0], ij[:, 1]] = True
    label, _ = ndimage.label(cells, structure=np.ones((3, 3), dtype=bool))
    of = label[ij[:, 0], ij[:, 1]]
    joined = np.isin(of, np.unique(of[held]))
    return float(held.sum() / joined.sum())


def pinned_corners(
    walls: NDArray,
    origin: NDArray,
    reach_m: float,
    tol_m: float,
    offset_m: float = 0.05,
    across_unseen: bool = False,
    points: NDArray | None = None,
    thin_m: float = 0.0,
    rounds: int = 2,
    angle_tol_deg: float = 3.0,
) -> tuple[NDArray, NDArray, Any, float] | None:
    """An open room's unseen corners closed where the data pin them (None when that does not close it).

    Two free wall ends (no other wall within `tol_m`) whose walls cross at more than 45° make a corner
    where the lines meet, beyond both ends, when one end lies within `reach_m` of it (that wall's data
    run up to the other wall's line: the corner is seen to be there) and the other wall runs there over
    no more than the length its line is seen over (with its pieces in line, within `offset_m`: a wall
    seen over 5 m may run on unseen for 3, not a 1 m stub for 4).
    The longer extension follows an observed wall's line through a stretch the capture missed (a corridor's
    end passed without looking at it); a corner whose both walls stop short of it by more than `reach_m`
    is not invented. Two pieces of one wall (parallel, lines within `offset_m`) whose free ends face each
    other within `reach_m` are joined (a step where their lines are apart). Pairs are taken shortest first, each end once, and no extension may cross another
    wall. Returns (walls with the extensions, origin, room polygon, longest extension) when the room then
    closes.

    `across_unseen` (a handheld scan's spans seen at no height, 0.5 m and more short of each corner) also
    closes a corner that neither end is within `reach_m` of, when each wall runs on unseen for no more than
    `UNSEEN_RUN_RATIO` times the length its line is seen over, or as far as the corner when that length is
    `UNSEEN_RUN_FREE_SPAN_M` or more (`_unseen_run_limit`) or when its other end is a seen corner of the room
    (joined to a wall across that ends there too, whose line is seen over `UNSEEN_RUN_FREE_SPAN_M` or more: a
    wall the capture saw only at its corner, no furniture face) and an observed wall that long runs in its
    direction or across it (within `angle_tol_deg`: a short piece's own direction may be degrees off), or
    when, in such a direction, its line has nothing the capture saw beyond it (`_bounding`: the far wall of
    a sparse scan seen over a few dm), no
    other wall lies inside the parallelogram
    the corner and the two free ends span (an L-room's notch, the room's own walls across it) and nothing
    lies behind either added piece (`_nothing_behind`: a partition stub's face run across the room has the
    room's far walls behind it); joins two pieces of one wall across a gap of any length when each lies on
    the other's line (within `offset_m`) and nothing lies behind the join (an alcove's back wall behind
    its mouth); and runs a free end along its line to a wall (its end within `tol_m`) as far as the line
    is seen over (any distance when that is `UNSEEN_RUN_FREE_SPAN_M` or more) when nothing lies behind
    the piece and that wall, met at its end, does not run on away from the room (an alcove's side: the room
    goes on past the line there). With the slice `points` (N, 2), "nothing" includes them, close behind (a
    furniture front run on, the wall seen just behind it). What was seen stays: the added pieces still may
    not cross a wall. A free end up to `UNSEEN_OVERSHOOT_M` past the corner makes it too.

    A wall's end where a thin partition (two faces within `thin_m`, `_at_a_stub`) stands on its line counts
    as free too: the wall runs on past the partition (the pocket behind a partition stub whose wall the
    capture never saw). `thin_m` 0 leaves such ends joined.

    Across unseen spans, when the corners closed leave the room open, it is looked at again with them, up to
    `rounds` times in all: a wall run on to one corner is then one seen from a corner of the room (its pieces
    in line followed to the corner), and may run on to the next."""
    n = len(walls)
    if n < 3:
        return None
    L, ends, d, th, nrm = _geometry(walls)  # end k of wall i at row i + k n
    crossing = np.abs(np.sin(th[:, None] - th[None, :])) >= SIN_ACROSS  # (M, M) at > 45°
    free = np.union1d(
        np.flatnonzero(d.min(axis=1) > tol_m), _at_a_stub(walls, ends, d, crossing, nrm, tol_m, thin_m)
    )
    centre = _centre(walls)

    def seen_over(k: int) -> float:
        """The length wall k's line is seen over: the extent of k and the walls in line with it."""
        inline = _in_line(walls, nrm, k, offset_m)
        u = np.array([math.cos(th[k]), math.sin(th[k])])
        t = np.concatenate([(walls[inline, :2] - walls[k, :2]) @ u, (walls[inline, 2:] - walls[k, :2]) @ u])
        return float(t.max() - t.min())

    span = np.array([seen_over(k) for k in range(n)])
    # the walls whose direction an observed wall of `UNSEEN_RUN_FREE_SPAN_M` or more has too, or its
    # perpendicular (within `angle_tol_deg`): a short piece's own direction may be degrees off, which a long
    # run would carry metres across the room (short pieces in line far apart span a long line, but their
    # directions are short pieces', and a piece run on along one in an earlier round has its direction)
    sin_tol = math.sin(math.radians(angle_tol_deg))
    turn = th[:, None] - th[None, (L >= UNSEEN_RUN_FREE_SPAN_M) & (origin == OBSERVED)]
    confirmed = ((np.abs(np.sin(turn)) <= sin_tol) | (np.abs(np.cos(turn)) <= sin_tol)).any(axis=1)
    # ...or one no such wall has within `DISTINCT_DIRECTION_DEG`, nor its perpendicular: a wall of its own
    # direction (a trapezoid room's slanted wall seen near its corner), no axis-aligned wall's piece degrees
    # off
    sin_own = math.sin(math.radians(DISTINCT_DIRECTION_DEG))
    own_way = ((np.abs(np.sin(turn)) > sin_own) & (np.abs(np.cos(turn)) > sin_own)).all(axis=1)
    confirmed |= own_way & (turn.shape[1] > 0)
    # the ends of those walls at a seen corner of the room: joined to a wall across that ends there too
    # (within `tol_m`) and whose line is seen over `UNSEEN_RUN_FREE_SPAN_M` or more (a step's few cm, a box's
    # side, are no wall of the room), directly or through the pieces run on from the end along its line (a
    # corner closed in an earlier round)
    meets = np.hypot(*(ends[:, None, :] - ends[None, :, :]).transpose(2, 0, 1)) <= tol_m  # (2M, 2M) ends
    ends_at = meets[:, :n] | meets[:, n:]  # (2M, M): a wall with an end at this end
    at_corner = np.zeros(2 * n, dtype=bool)
    for e0 in np.flatnonzero(d.min(axis=1) <= tol_m):
        e, seen = int(e0), {int(e0) % n}
        while True:
            k = e % n
            joined = (d[e] <= tol_m) & ends_at[e]
            if (joined & crossing[k] & (span >= UNSEEN_RUN_FREE_SPAN_M)).any():
                at_corner[e0] = bool(confirmed[e0 % n])
                break
            # a piece in line starting at this end (run on in an earlier round): on to its other end
            on = [int(j) for j in np.flatnonzero(joined & ~crossing[k]) if int(j) not in seen]
            if not on:
                break
            j = on[0]
            seen.add(j)
            e = j + n * int(meets[e, j])  # its other end

    overshoot_m = UNSEEN_OVERSHOOT_M if across_unseen else 0.0
    # the walls with nothing the capture saw beyond their lines, in a direction a long wall confirms
    bounding = confirmed & _bounding(walls, nrm, centre, points) if across_unseen else np.zeros(n, dtype=bool)
    cands = []
    for x, y in itertools.combinations(free, 2):
        i, j = x % n, y % n
        if i == j:
            continue
        if not crossing[i, j]:
            # two pieces of one wall facing each other across a short gap (a door's jamb took the corner
            # connect would have joined them at): joined, by a step where their lines are apart
            p, q = ends[x], ends[y]
            u = (p - ends[(x + n) % (2 * n)]) / max(L[i], 1e-12)  # out of wall i's free end
            gap = float((q - p) @ u)
            off = float((q - p) @ np.array([-u[1], u[0]]))
            v = (q - ends[(y + n) % (2 * n)]) / max(L[j], 1e-12)
            if 0 < gap and abs(off) <= offset_m and float((p - q) @ v) > 0:
                if gap <= reach_m or (
                    across_unseen
                    and abs(float((p - q) @ np.array([-v[1], v[0]]))) <= offset_m
                    and _nothing_behind(walls, p, q, centre, (i, j), tol_m, points)
                ):
                    cands.append((gap, gap, x, y, p + off * np.array([-u[1], u[0]]), j))
            continue
        hit = line_intersection(walls[i], walls[j])
        if hit is None:
            continue
        corner = hit[0]
        ext = []
        for e, w in ((x, i), (y, j)):
            p, q = ends[e], ends[(e + n) % (2 * n)]  # the free end and the wall's other end
            if float((corner - p) @ (p - q)) < -(tol_m + overshoot_m) * max(L[w], 1e-12):
                break  # the corner lies back along the wall, not beyond its free end
            ext.append(float(np.hypot(*(corner - p))))
        if len(ext) < 2:
            continue
        far = int(np.argmax(ext))
        pinned = min(ext) <= reach_m and ext[far] <= span[(i, j)[far]]
        if not pinned and not (
            across_unseen
            and (ext[0] <= _unseen_run_limit(span[i]) or at_corner[(x + n) % (2 * n)] or bounding[i])
            and (ext[1] <= _unseen_run_limit(span[j]) or at_corner[(y + n) % (2 * n)] or bounding[j])
            and _open_corner(walls, ends[x], ends[y], corner, (i, j), tol_m, points, centre)
        ):
            continue
        cands.append((sum(ext), max(ext), x, y, corner, j))
    for x in free:
        # a free end whose line meets another wall within the reach (the extension connect removed for want
        # of data: a door's opening beside its jamb)
        i = x % n
        p = ends[x]
        u = (p - ends[(x + n) % (2 * n)]) / max(L[i], 1e-12)
        best = None
        # across unseen spans, as far as the wall's line is seen over (any distance when that is
        # `UNSEEN_RUN_FREE_SPAN_M` or more), when no wall lies behind the piece
        limit = max(reach_m, _unseen_run_limit(span[i], 1.0)) if across_unseen else reach_m
        for j in range(n):
            if j == i or not crossing[i, j]:
                continue
            hit = line_intersection(np.array([*p, *(p + u)]), walls[j])
            # (across unseen spans the line may meet the wall's end within the tolerance, a cell off it)
            m = tol_m / max(L[j], 1e-12) if across_unseen else 1e-9
            if hit is None or not (tol_m < hit[1] <= limit) or not (-m <= hit[2] <= 1 + m):
                continue
            if best is None or hit[1] < best[0]:
                # the corner on the wall (its end when the line passes a cell beyond it)
                k = 2 * int(hit[2] > 1.0)
                at = hit[0] if not across_unseen or 0.0 <= hit[2] <= 1.0 else walls[j, k : k + 2]
                # met at its end (within `offset_m`), a wall that runs on away from the room (its other end
                # beyond the line, on the far side from the room's centre) says the room goes on past the
                # line there: an alcove's side, its mouth unseen
                far = walls[j, 2:4] if hit[2] < 0.5 else walls[j, 0:2]
                across = np.array([-u[1], u[0]])
                inward = math.copysign(1.0, float((centre - p) @ across))
                at_end = min(hit[2], 1.0 - hit[2]) * L[j] <= offset_m
                away = at_end and float((far - p) @ across) * inward < -tol_m
                best = (hit[1], at, j, away)
        if best is not None and (
            best[0] <= reach_m
            or (not best[3] and _nothing_behind(walls, p, best[1], centre, (i, best[2]), tol_m, points))
        ):
            cands.append((best[0], best[0], x, x, best[1], best[2]))
    if not cands:
        return None
    used: set[int] = set()
    added, longest = [], 0.0
    for _, far_m, x, y, corner, target in sorted(cands, key=lambda c: c[0]):
        if x in used or y in used:
            continue
        pieces = np.array(
            [[*ends[e], *corner] for e in {x, y} if np.hypot(*(corner - ends[e])) > 1e-9]
        ).reshape(-1, 4)
        others = np.delete(walls, sorted({x % n, y % n, target}), axis=0)
        if len(pieces) and len(others) and _crosses(pieces, others, tol_m):
            continue
        used |= {x, y}
        added.extend(pieces.tolist())
        longest = max(longest, far_m)
    if not added:
        return None
    out = np.concatenate([walls, np.array(added)])
    out_origin = np.concatenate([origin, np.full(len(added), EXTENDED, dtype=origin.dtype)])
    polygon, closed, closed_origin, _ = _room_polygon(out, out_origin, tol_m)
    if polygon is None:
        if across_unseen and rounds > 1:
            # the corners closed make walls seen from a corner of the room that were not before: once more
            again = pinned_corners(
                out, out_origin, reach_m, tol_m, offset_m, True, points, thin_m, rounds - 1, angle_tol_deg
            )
            if again is not None:
                return (*again[:3], max(longest, again[3]))
        return None
    return closed, closed_origin, polygon, longest


def _at_a_stub(
    walls: NDArray, ends: NDArray, d: NDArray, across: NDArray, nrm: NDArray, tol_m: float, thin_m: float
) -> NDArray[np.int64]:
    """Rows of the walls' `ends` (2M, 2) (end k of wall i at row i + k M; `d` (2M, M) their distances to the
    walls, `across` (M, M) the pairs more than 45° apart, `nrm` their unit normals) where a thin partition stands on the wall's
    line: the end is joined to a line across the wall (more than 45°) that has a parallel line within `thin_m`
    on the same side of the wall, the two overlapping along their direction and ending together (within
    `thin_m`) away from the wall: the partition's two faces and its free end. The wall is no corner there."""
    n = len(walls)
    if thin_m <= 0 or n < 3:
        return np.zeros(0, dtype=np.int64)

    def on_its_line(k: int) -> bool:
        """Does another wall lie on wall k's line (within two `tol_m`)?"""
        for m in np.flatnonzero(~across[k]):
            off = np.abs((walls[m].reshape(2, 2) - walls[k, :2]) @ nrm[k])
            if m != k and off.max() <= 2 * tol_m:
                return True
        return False

    def second_face(a: int, k: int, p: NDArray) -> bool:
        ends_a = walls[a].reshape(2, 2)
        near = int(np.argmin(np.hypot(*(ends_a - p).T)))
        if np.hypot(*(ends_a[near] - p)) > tol_m:
            return False  # the line does not end at the wall's end: it passes it
        u = (ends_a[1 - near] - ends_a[near]) / max(
            float(np.hypot(*(ends_a[1 - near] - ends_a[near]))), 1e-12
        )
        far = float((ends_a[1 - near] - p) @ u)
        # a partition's end cap joins its two faces and no other wall lies on its line: the cap is no wall
        # the partition stands on (the piece of the room's wall between a partition's faces, at its root, is)
        near_start = np.hypot(*(walls[k, :2] - p)) <= np.hypot(*(walls[k, 2:] - p))
        other = walls[k, 2:] if near_start else walls[k, :2]
        cap = not on_its_line(k)
        for b in np.flatnonzero(~across[a]):
            if b in (a, k) or (cap and point_segment_distances(other[None], walls[b : b + 1])[0, 0] <= tol_m):
                continue
            off = np.abs((walls[b].reshape(2, 2) - ends_a[0]) @ nrm[a])
            t = (walls[b].reshape(2, 2) - p) @ u
            if (
                off.max() <= thin_m
                and off.min() > tol_m
                and t.min() > -tol_m
                and abs(t.max() - far) <= thin_m
            ):
                return True
        return False

    out = [
        int(e)
        for e in np.flatnonzero(d.min(axis=1) <= tol_m)
        if any(second_face(a, e % n, ends[e]) for a in np.flatnonzero((d[e] <= tol_m) & across[e % n]))
    ]
    return np.asarray(out, dtype=np.int64)


def _samples(walls: NDArray, skip: tuple[int, ...], step_m: float = 0.05) -> NDArray:
    """(S, 2) points every `step_m` along the walls (M, 4) other than those indexed by `skip`."""
    out = [np.zeros((0, 2))]
    for k, w in enumerate(walls):
        if k in skip:
            continue
        n = max(2, math.ceil(float(np.hypot(*(w[2:] - w[:2]))) / step_m) + 1)
        out.append(w[:2] + np.linspace(0.0, 1.0, n)[:, None] * (w[2:] - w[:2]))
    return np.concatenate(out)


BEHIND_DEPTH_M = 0.75
"""`_nothing_behind`: the slice points up to this far behind a piece added across an unseen span (the
deepest furniture, `furniture_max_depth_m`) count against it: the piece runs on a furniture front, with the
wall behind it. Deeper points may be the next room seen through a door."""
BEHIND_BAND_M = 0.1
"""...beyond this band about the piece's line (its own wall's noise)..."""
BEHIND_MAX_SHARE = 0.3
"""...when they stand behind at least this share of its 10 cm bins (a few stray points do not)."""


def _nothing_behind(
    walls: NDArray,
    p: NDArray,
    q: NDArray,
    inside: NDArray | None,
    skip: tuple[int, ...],
    tol_m: float,
    points: NDArray | None = None,
) -> bool:
    """Does nothing stand behind the piece p -> q (on its side away from `inside`, a point of the room,
    within its span)? No wall other than `skip`, more than `tol_m` off its line at any depth, and, with
    the slice `points` (N, 2), none of them up to `BEHIND_DEPTH_M` behind it beyond `BEHIND_BAND_M` over
    `BEHIND_MAX_SHARE` or more of its 10 cm bins. A wall piece across an unseen span is the room's
    boundary: what the capture saw of the room lies on one side of it only."""
    if inside is None:
        return False
    d = q - p
    L = float(np.hypot(*d))
    if L <= 2 * tol_m:
        return True
    u = d / L
    nrm = np.array([-u[1], u[0]])
    if float((inside - p) @ nrm) < 0:
        nrm = -nrm
    rel = _samples(walls, skip) - p
    t, o = rel @ u, rel @ nrm
    if ((t > tol_m) & (t < L - tol_m) & (o < -tol_m)).any():
        return False
    if points is None or len(points) == 0 or L <= 2 * BEHIND_BAND_M:
        return True
    rel = points - p
    t, o = rel @ u, rel @ nrm
    sel = (t > BEHIND_BAND_M) & (t < L - BEHIND_BAND_M) & (o < -BEHIND_BAND_M) & (o > -BEHIND_DEPTH_M)
    return not _held_bins(t[sel], L)


def _open_corner(
    walls: NDArray,
    a: NDArray,
    b: NDArray,
    corner: NDArray,
    pair: tuple[int, int],
    tol_m: float,
    points: NDArray | None = None,
    centre: NDArray | None = None,
) -> bool:
    """May the free ends `a` and `b` of the walls `pair` be run on to the `corner` their lines meet at,
    across a span nothing was seen on? No other wall lies inside the parallelogram the corner and the two
    ends span (more than `tol_m` inside it), and nothing behind either added piece (`_nothing_behind`, the
    room's side being towards the other wall). At a reflex corner (an L-room's inner corner: the room's
    `centre` lies on the far side of both walls' lines from the other wall) the room's side is away from the
    other wall, no other wall lies in the part cut off (the parallelogram the corner and the walls' far ends
    span) and the slice `points` do not run on past either far end into it (`_runs_on_past`: that end is a
    partition's T on the room's wall, not a corner)."""
    ea, eb = a - corner, b - corner
    if abs(float(np.linalg.det(np.column_stack([ea, eb])))) <= 1e-12:
        return False
    rel = _samples(walls, pair) - corner
    if _inside_parallelogram(rel, ea, eb, tol_m):
        return False
    # the room's side of each added piece: towards the other wall (its end away from the corner: the free
    # end may lie a few cm past the corner) at a convex corner; at a reflex one (an L-room's inner corner: the
    # room's centre lies on the far side of both lines) away from it
    far_a, far_b = (max(walls[k].reshape(2, 2), key=lambda e: float(np.hypot(*(e - corner)))) for k in pair)
    inside_a, inside_b = far_b, far_a
    if centre is not None:
        na, nb = np.array([-ea[1], ea[0]]), np.array([-eb[1], eb[0]])
        if (
            float((centre - corner) @ na) * float((far_b - corner) @ na) < 0
            and float((centre - corner) @ nb) * float((far_a - corner) @ nb) < 0
        ):
            # and the walls cut off are the room's own: no other wall inside the parallelogram the corner and
            # the two walls' far ends span (a partition's face run on to a door's jamb would cut off the
            # room's part beyond it, the partition's other face with it)
            if _inside_parallelogram(rel, far_a - corner, far_b - corner, tol_m):
                return False
            # each wall's far end is a corner of the room, the wall across it stopping there: one whose data
            # run on past it into the part cut off makes that end a T (a partition standing on the room's wall)
            if points is not None and (
                _runs_on_past(far_a, far_b - corner, points) or _runs_on_past(far_b, far_a - corner, points)
            ):
                return False
            inside_a, inside_b = 2 * corner - far_b, 2 * corner - far_a
    return _nothing_behind(walls, a, corner, inside_a, pair, tol_m, points) and _nothing_behind(
        walls, b, corner, inside_b, pair, tol_m, points
    )


def _inside_parallelogram(rel: NDArray, ea: NDArray, eb: NDArray, tol_m: float) -> bool:
    """Does any of the points `rel` (S, 2, relative to a corner) lie more than `tol_m` inside the
    parallelogram the corner and the two edge vectors `ea`, `eb` (not parallel) span?"""
    st = np.linalg.solve(np.column_stack([ea, eb]), rel.T).T  # each point as corner + s ea + t eb
    margin = tol_m / np.maximum(np.hypot(*np.stack([ea, eb]).T), 1e-12)
    return bool(((st > margin).all(axis=1) & (st < 1 - margin).all(axis=1)).any())


def _held_bins(t: NDArray, length_m: float) -> bool:
    """Do the positions `t` (m, along a stretch `length_m` long from 0) fill `BEHIND_MAX_SHARE` or more of
    its 10 cm bins?"""
    bins = np.unique(np.floor(t / 0.1).astype(np.int64))
    return len(bins) >= BEHIND_MAX_SHARE * math.ceil(length_m / 0.1)


def _runs_on_past(end: NDArray, direction: NDArray, points: NDArray) -> bool:
    """Do the slice `points` (N, 2) run on from a wall's `end` in `direction` (a wall across it carrying on
    past it there): within `BEHIND_BAND_M` of that line, `BEHIND_BAND_M` to `BEHIND_DEPTH_M` from the end,
    over `BEHIND_MAX_SHARE` or more of its 10 cm bins?"""
    u = direction / max(float(np.hypot(*direction)), 1e-12)
    rel = points - end
    t, o = rel @ u, rel @ np.array([-u[1], u[0]])
    sel = (t > BEHIND_BAND_M) & (t < BEHIND_DEPTH_M) & (np.abs(o) <= BEHIND_BAND_M)
    return _held_bins(t[sel], BEHIND_DEPTH_M - BEHIND_BAND_M)


def _crosses(pieces: NDArray, walls: NDArray, tol_m: float) -> bool:
    """Does any of `pieces` (P, 4) come within `tol_m` of one of `walls` (M, 4) away from its own ends?"""
    import shapely

    d = pieces[:, 2:] - pieces[:, :2]
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    cut = np.minimum(2 * tol_m, 0.5 * L)[:, None] * d / L[:, None]
    inner = np.concatenate([pieces[:, :2] + cut, pieces[:, 2:] - cut], axis=1)
    a = shapely.linestrings(inner.reshape(-1, 2, 2))
    b = shapely.linestrings(walls.reshape(-1, 2, 2))
    return bool((shapely.distance(a[:, None], b[None, :]) <= tol_m).any())


def stray_walls(walls: NDArray, orientation_deg: NDArray, share, lcfg: LinesConfig) -> NDArray[np.bool_]:
    """(M,) walls that no orientation cluster supports (their direction lies further than `angle_tol_deg`
    from every cluster's mean, `orientation_deg`) and whose data back less than `min_overlap` of their
    length (`share`): a wall that only the joins made (a perpendicular join across an unseen stretch
    between walls of other directions), which neither the data's directions nor its own points show.
    A step (shorter than `offset_tol_m`) is exempt: its few cm carry no direction to measure."""
    out = np.zeros(len(walls), dtype=bool)
    if len(walls) == 0 or len(orientation_deg) == 0:
        return out
    long = lengths(walls) >= lcfg.offset_tol_m
    off = np.abs(angle_difference(angles(walls)[:, None], np.radians(orientation_deg)[None, :])).min(axis=1)
    out = long & (off > math.radians(lcfg.angle_tol_deg))
    if out.any():
        out[out] = share(walls[out]) < lcfg.min_overlap
    return out


ACUTE_STUB_MAX_DEG = 30.0
"""`acute_stubs`: a dangling wall leaving a straight wall at less than this angle is no wall."""


def acute_stubs(walls: NDArray, lcfg: LinesConfig) -> NDArray[np.bool_]:
    """(M,) dangling walls (one end free: no other wall within `offset_tol_m`) whose other end lies on a
    straight wall longer than they are (within `offset_tol_m`; its pieces in line as close), which runs on
    past it both ways as far, and which leave that wall at more than `angle_tol_deg` but less than
    `ACUTE_STUB_MAX_DEG`. A partition meets a wall near square, and a wall a few degrees off its neighbour
    meets it at a corner, the end of both; a narrow fan of points out of the middle of a wall is the
    sensor's streak along its rays where it saw the wall at a grazing angle."""
    n = len(walls)
    out = np.zeros(n, dtype=bool)
    if n < 2:
        return out
    L = lengths(walls)
    th = angles(walls)
    ends, d = end_distances(walls)  # end k of wall i at row i + k n
    arm = lcfg.offset_tol_m
    free = d.min(axis=1) > arm
    lo, hi = math.sin(math.radians(lcfg.angle_tol_deg)), math.sin(math.radians(ACUTE_STUB_MAX_DEG))
    for i in np.flatnonzero(free[:n] != free[n:]):
        p = ends[i + n] if free[i] else ends[i]
        for j in np.flatnonzero(d[i + (n if free[i] else 0)] <= arm):
            if not lo < abs(math.sin(th[i] - th[j])) < hi:
                continue
            u = (walls[j, 2:] - walls[j, :2]) / max(L[j], 1e-12)
            nrm = np.array([-u[1], u[0]])
            inline = (np.abs(np.sin(th - th[j])) < lo) & (
                np.abs(np.stack([(walls[:, :2] - p) @ nrm, (walls[:, 2:] - p) @ nrm])).max(axis=0) <= arm
            )
            t = np.stack([(walls[inline, :2] - p) @ u, (walls[inline, 2:] - p) @ u])
            if t.min() < -arm and t.max() > arm and t.max() - t.min() > L[i]:
                out[i] = True
                break
    return out


CORNER_JOG_MAX_M = 0.25
"""`corner_jogs`: the longest piece taken for a jog at a corner."""


def corner_jogs(walls: NDArray, tol_m: float) -> tuple[NDArray[np.bool_], NDArray]:
    """A short piece (up to `CORNER_JOG_MAX_M`) joining, end to end (within `tol_m`), two walls that cross
    at more than 45° while it runs along neither (within 10°), where their lines meet within
    `CORNER_JOG_MAX_M` of both joined ends: a jog that the noisy, sparsely seen tip of a corner (an acute
    corner's, a Kinect's far one) left between walls that do not quite reach it, not a wall. Returns ((M,)
    the jogs, the walls with the two walls of each run on to their lines' corner). A step between parallel
    walls has no corner to meet at and stays; the model keeps the jog when the room does not close without
    it."""
    walls = np.asarray(walls, dtype=np.float64)
    n = len(walls)
    jogs = np.zeros(n, dtype=bool)
    out = walls.copy()
    if n < 3:
        return jogs, out
    L = lengths(walls)
    th = angles(walls)
    ends = walls.reshape(n, 2, 2)
    used: set[int] = set()
    for k in np.flatnonzero(L <= CORNER_JOG_MAX_M):
        joined = []
        for p in ends[k]:
            d = np.hypot(*(ends - p).transpose(2, 0, 1))  # (M, 2) each wall end's distance to p
            d[k] = np.inf
            a, e = np.unravel_index(int(np.argmin(d)), d.shape)
            joined.append((int(a), int(e)) if d[a, e] <= tol_m else None)
        if None in joined or joined[0][0] == joined[1][0]:
            continue
        (a, ea), (b, eb) = joined
        if {a, b, k} & used or abs(math.sin(th[a] - th[b])) < SIN_ACROSS:
            continue
        if min(abs(math.sin(th[k] - th[a])), abs(math.sin(th[k] - th[b]))) < math.sin(math.radians(10.0)):
            continue  # in line with one of them: a piece of that wall
        hit = line_intersection(walls[a], walls[b])
        if hit is None:
            continue
        corner = hit[0]
        if max(np.hypot(*(corner - ends[a, ea])), np.hypot(*(corner - ends[b, eb]))) > CORNER_JOG_MAX_M:
            continue
        out[a, 2 * ea : 2 * ea + 2] = corner
        out[b, 2 * eb : 2 * eb + 2] = corner
        jogs[k] = True
        used |= {a, b, k}
    return jogs, out


def dangling_extensions(walls: NDArray, origin: NDArray, tol_m: float) -> NDArray[np.bool_]:
    """(M,) walls the connection added for want of data (`EXTENDED`) that join nothing at one end (no
    other wall within `tol_m`). An extension runs to where it meets another wall; one left dangling, its
    wall cut back or dropped after the join (an alcove's mouth, a step placed from a line that ran across
    it), invents a wall where nothing was seen."""
    n = len(walls)
    if n < 2:
        return np.zeros(n, dtype=bool)
    free = end_distances(walls)[1].min(axis=1) > tol_m
    return (origin == EXTENDED) & (free[:n] | free[n:])


STEP_MAX_TOLS = 2.0
"""`place_steps` moves joins up to this many times `lines.offset_tol_m` long: the jogs where two rooms' walls
of different thickness meet (5-7 cm), whose refined lines may lie a little further apart than the tolerance
that chained them."""


def place_steps(
    conn: Connected,
    lines: NDArray,
    counts: NDArray,
    grid: Grid,
    offset_tol_m: float,
    interior: NDArray | None = None,
) -> Connected:
    """Each step of the connected walls (a perpendicular join shorter than `STEP_MAX_TOLS` times
    `offset_tol_m` between the ends of two parallel walls running on to either side, a jog of a few cm)
    moved along them to where the data changes from one wall to the other. Connect places a join at a
    wall's end, and where neither wall was found across an unseen or sparsely seen stretch (a Hough line
    needs dense cells) that end can lie a metre from the step.

    Between the two walls' observed ends (`lines`, connect's input, by `conn.parent`), widened by the
    step, every grid column along the walls counts the occupied voxels (`counts`) nearer each wall's line
    than half the step; the step goes to the cut that leaves most of the first wall's data on its side
    and most of the second's on the other (the greatest sum of count differences). Where several cuts
    tie (a stretch with data on neither line), the step goes to the tie's end at the data of the wall
    nearer the room's `interior`: the step hides the farther wall from the room, never the nearer one,
    whose data run up to the corner (without `interior`, to the middle of the tie). Returns `conn` with the
    walls moved."""
    walls, parent = conn.segments.copy(), conn.parent
    L = lengths(walls)
    cand = np.flatnonzero((parent < 0) & (L > 0) & (L < STEP_MAX_TOLS * offset_tol_m))
    if len(cand) == 0:
        return conn
    g = grid.size
    moved = False
    for s in cand:
        ends = []
        for p in (walls[s, :2], walls[s, 2:]):
            d = point_segment_distances(p[None], walls)[0]
            d[s] = np.inf
            touching = np.flatnonzero(d <= 1e-9)
            if len(touching) != 1 or parent[touching[0]] < 0:
                break
            w = int(touching[0])
            at = [float(np.hypot(*(walls[w, 2 * k : 2 * k + 2] - p))) for k in (0, 1)]
            if min(at) > 1e-9:
                break  # the step stands on the wall's middle (a T), not at its end
            ends.append((w, int(np.argmin(at))))
        if len(ends) != 2:
            continue
        (a, ea), (b, eb) = ends
        qa, qb = walls[s, :2].copy(), walls[s, 2:].copy()
        far_a = walls[a, 2:] if ea == 0 else walls[a, :2]
        u = qa - far_a
        if np.hypot(*u) <= 0:
            continue
        u = u / np.hypot(*u)  # along the walls, from the first wall towards the second
        step = qb - qa
        h = float(np.hypot(*step))
        if abs(float(step @ u)) > 1e-6 * max(h, 1e-12) + 1e-9 or h <= 0:
            continue  # not perpendicular to the walls
        nrm = step / h
        far_b = walls[b, 2:] if eb == 0 else walls[b, :2]
        t_far_a, t_far_b = float((far_a - qa) @ u), float((far_b - qb) @ u)
        if t_far_b <= 0:
            continue  # both walls run back from the join: a thin partition's end cap, no step
        obs_a = float(max((lines[parent[a], :2] - qa) @ u, (lines[parent[a], 2:] - qa) @ u))
        obs_b = float(min((lines[parent[b], :2] - qb) @ u, (lines[parent[b], 2:] - qb) @ u))
        lo = max(min(obs_a, obs_b) - h, t_far_a + g)
        hi = min(max(obs_a, obs_b) + h, t_far_b - g)
        if hi - lo < 2 * g:
            continue
        # the grid cells around the window, their weights (voxels) and place (t along, o across from qa)
        corners = np.array([qa + t * u + o * nrm for t in (lo, hi) for o in (-h, 2 * h)])
        px = grid.to_pixels(corners)
        c0, r0 = np.floor(px.min(axis=0)).astype(int) - 1
        c1, r1 = np.ceil(px.max(axis=0)).astype(int) + 2
        c0, r0 = max(c0, 0), max(r0, 0)
        c1, r1 = min(c1, counts.shape[1]), min(r1, counts.shape[0])
        if c1 <= c0 or r1 <= r0:
            continue
        rows, cols = np.mgrid[r0:r1, c0:c1]
        wgt = counts[r0:r1, c0:c1].ravel()
        xy = grid.to_metres(np.column_stack([cols.ravel(), rows.ravel()]))[wgt > 0]
        wgt = wgt[wgt > 0]
        t, o = (xy - qa) @ u, (xy - qa) @ nrm
        inside = (t >= lo) & (t < hi)
        bins = np.floor((t[inside] - lo) / g).astype(int)
        n_bins = math.ceil((hi - lo) / g)
        diff = np.bincount(bins, wgt[inside] * (np.abs(o[inside]) < 0.5 * h), n_bins) - np.bincount(
            bins, wgt[inside] * (np.abs(o[inside] - h) < 0.5 * h), n_bins
        )
        gain = np.concatenate([[0.0], np.cumsum(diff)])  # the first wall's data left of each cut, net
        best = np.flatnonzero(gain >= gain.max() - 1e-9)
        if interior is None:
            cut = 0.5 * (best.min() + best.max())
        else:
            # the step hides the farther wall from the room, not the nearer one: the nearer wall's data run
            # up to the corner, and the stretch with data on neither line is the farther wall's, unseen
            b_nearer = abs(float((interior - qb) @ nrm)) < abs(float((interior - qa) @ nrm))
            cut = float(best.max() if b_nearer else best.min())
        t_step = lo + cut * g
        if abs(t_step) <= 1e-9:
            continue
        na, nb = qa + t_step * u, qb + t_step * u
        walls[a, 2 * ea : 2 * ea + 2], walls[b, 2 * eb : 2 * eb + 2] = na, nb
        walls[s] = [*na, *nb]
        moved = True
    return replace(conn, segments=walls) if moved else conn


REFUSE_NOISE_SIGMAS = 3.0
"""A regularization may move a line's ends by at most this many standard deviations of its data about it."""


def regularize_within_noise(
    lines: NDArray, noise: NDArray, lcfg: LinesConfig
) -> tuple[NDArray, NDArray, NDArray[np.bool_]]:
    """`regularize` with every rotation that would move a line's ends by more than `REFUSE_NOISE_SIGMAS`
    times its data's noise (`noise` (M,), metres) refused: the data say that wall runs at its own angle (a
    wall a few degrees off its neighbours' direction). A refused line keeps its angle and is left out of
    its cluster's mean, which the others are regularized to again (until none more is refused): a wall held
    at its own angle must not still pull its neighbour off its own. Returns (lines (M, 4), rotation (M,)
    radians) as `regularize`, and the refused lines."""
    n = len(lines)
    reg, rotation = lines.copy(), np.zeros(n)
    refused = np.zeros(n, dtype=bool)
    half = 0.5 * lengths(lines)
    for _ in range(n + 1):
        free = ~refused
        reg[free], rotation[free] = regularize(lines[free], lcfg)
        more = free & (np.abs(rotation) * half > REFUSE_NOISE_SIGMAS * noise)
        if not more.any():
            break
        refused |= more
        reg[more], rotation[more] = lines[more], 0.0
    return reg, rotation, refused


def join_overlapping(
    lines: NDArray, rotation: NDArray, refused: NDArray, chain: NDArray, lcfg: LinesConfig, quantum: float
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The regularized `lines` (M, 4) that are one wall's pieces (`lines.overlapping_parallels`: parallel,
    overlapping, within `offset_tol_m`) merged into one line each, in the place of the group's first: along
    the longest's direction, at their length-weighted mean offset, over all their spans, with the longest's
    rotation and chain. Lines left at their own angle (`refused`) are kept as they are. On clean 854 r4 an
    alcove's back wall 1.2 m long, a Kinect band of +-10 cm at 4 m, gave skeleton lines 3.5 degrees off the
    room's frame beside level ones, two clusters then: turned level, two of them 4.4 cm apart both stayed,
    and the wall was drawn as two with a step. Returns (lines, rotation, refused, chain) of the lines kept."""
    free = np.flatnonzero(~refused)
    group = np.full(len(lines), -1, dtype=np.intp)
    group[free] = overlapping_parallels(lines[free], lcfg.offset_tol_m, quantum)
    if len(np.unique(group[free])) == len(free):
        return lines, rotation, refused, chain
    L = lengths(lines)
    out, rotation, chain = lines.copy(), rotation.copy(), chain.copy()
    keep = []
    for i in range(len(lines)):
        members = np.flatnonzero(group == group[i]) if group[i] >= 0 else np.array([i])
        if members[0] != i:
            continue
        keep.append(i)
        if len(members) == 1:
            continue
        longest = members[np.argmax(L[members])]
        # (a fit through parallel lines of unequal spans would tilt the line)
        u = (lines[longest, 2:] - lines[longest, :2]) / L[longest]
        nrm = np.array([-u[1], u[0]])
        ends = lines[members].reshape(-1, 2)
        t = ends @ u
        off = float(np.repeat(L[members], 2) @ (ends @ nrm)) / (2 * L[members].sum())
        out[i] = np.concatenate([off * nrm + t.min() * u, off * nrm + t.max() * u])
        rotation[i], chain[i] = rotation[longest], chain[longest]
    k = np.array(keep, dtype=np.intp)
    return out[k], rotation[k], refused[k], chain[k]


def line_noise(hough: NDArray, labels: NDArray, lines: NDArray, floor_m: float) -> NDArray[np.float64]:
    """(M,) the noise of each merged line's data: the RMS distance of its member Hough segments' ends from
    the line (`labels` maps Hough segment -> line, -1 for none), at least `floor_m` (the grid: a skeleton
    is only good to a pixel)."""
    out = np.full(len(lines), float(floor_m))
    if len(lines) == 0 or len(hough) == 0:
        return out
    d = lines[:, 2:] - lines[:, :2]
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    nrm = np.column_stack([-d[:, 1], d[:, 0]]) / L[:, None]
    ok = labels >= 0
    j = labels[ok]
    off = [((hough[ok][:, k : k + 2] - lines[j, :2]) * nrm[j]).sum(axis=1) for k in (0, 2)]
    sq = np.bincount(j, off[0] ** 2 + off[1] ** 2, len(lines))
    n = np.bincount(j, minlength=len(lines)) * 2
    rms = np.sqrt(sq / np.maximum(n, 1))
    return np.maximum(out, rms)


def band_noise(lines: NDArray, cells_xy: NDArray, band_m: float) -> NDArray[np.float64]:
    """(M,) the RMS distance from each line (M, 4) of the wall cells (`cells_xy` (K, 2), their centres) within
    `band_m` of it along its length (0 with fewer than 3): the spread of its data across it. A line found from
    one Hough segment shows none in `line_noise` (that segment's ends lie on it), however wide the band of
    points it was drawn through: a Kinect's far wall spreads over ±5 cm, and a 0.4 m piece of it took a 14°
    skeleton segment (clean 107 r4)."""
    out = np.zeros(len(lines))
    for i, (a, b) in enumerate(np.asarray(lines, dtype=np.float64).reshape(-1, 2, 2)):
        length = float(np.hypot(*(b - a)))
        if length <= 0:
            continue
        u = (b - a) / length
        rel = cells_xy - a
        t, d = rel @ u, rel @ np.array([-u[1], u[0]])
        d = d[(t >= 0) & (t <= length) & (np.abs(d) <= band_m)]
        if len(d) >= 3:
            out[i] = float(np.sqrt(np.mean(d**2)))
    return out


def _centre(lines: NDArray, band_m: float = 0.0) -> NDArray | None:
    """The lines' length-weighted centre (None without length): where the room's interior is taken to be.
    With `band_m`, lines lying wholly within `band_m` of each other (both ways) share their weight: one band
    of data drawn as several lines (a far wall seen through a door, its points smeared a decimetre or two by
    the distance) counts once, and does not pull the centre out to the room's wall in front of it."""
    weight = lengths(lines)
    if len(lines) == 0 or weight.sum() <= 0:
        return None
    if band_m > 0:
        reach = point_segment_distances(lines.reshape(-1, 2), lines).reshape(-1, 2, len(lines)).max(axis=1)
        weight = weight / ((reach <= band_m) & (reach.T <= band_m)).sum(axis=1)
    return (0.5 * (lines[:, :2] + lines[:, 2:]) * weight[:, None]).sum(axis=0) / weight.sum()


HELD_MIN_SHARE = 0.5
"""A room closed only by the wider reaches (`bridge_gaps_m`) must hold at least this share of the observed wall
length the usual reach found (on or inside its outline, `_held_share`): a box that the wider joins made of a
corner's walls and furniture across the room, leaving most of the walls seen outside it, is not the room
(`bridged_refused_outside_m` in the metrics lists the reaches refused so)."""


def _held_share(walls: NDArray, origin: NDArray, polygon: Any, tol_m: float) -> float:
    """Share of the observed walls' length (`walls` (M, 4), `origin`) within `tol_m` of the room `polygon`
    (on or inside its outline); 1 without observed walls."""
    seen = walls[origin == OBSERVED]
    total = float(lengths(seen).sum())
    if total <= 0:
        return 1.0
    import shapely

    lines = shapely.linestrings(seen.reshape(-1, 2, 2))
    held = shapely.length(shapely.intersection(lines, polygon.buffer(tol_m, join_style="mitre"))).sum()
    return float(held) / total


def _lines_away_from(lines: NDArray, polygon: Any, tol_m: float) -> NDArray[np.bool_]:
    """(M,) lines farther than `tol_m` from the room (None: none is)."""
    if polygon is None or len(lines) == 0:
        return np.zeros(len(lines), dtype=bool)
    import shapely

    return shapely.distance(polygon, shapely.linestrings(lines.reshape(-1, 2, 2))) > tol_m


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
    _, d = _end_distances(walls)
    n = len(walls)
    free = d.min(axis=1) > 1e-6 if n > 1 else np.ones(2 * n, dtype=bool)
    drop = short & (free[:n] | free[n:])
    return walls[~drop], origin[~drop]


def _room_polygon(walls: NDArray, origin: NDArray, tol_m: float) -> tuple[Any, NDArray, NDArray, int]:
    """The room: the largest face the walls enclose, provided the walls on or inside its outline hold most
    of the wall length (else it is a column or a cupboard, not the room: None). With a room, the walls are
    clipped to its outline (a wall seen through a door, or a wall line running on past the room's
    corner, is not one of its inner faces), and a join no longer than `tol_m` goes, the ends of the walls it
    joined moved to its middle (they still meet). Returns (room, walls, origin, walls dropped)."""
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
    out, out_origin, joins = [], [], []
    for wall, geom, o, length in zip(walls, inner, origin, L, strict=True):
        for part in shapely.get_parts(geom):
            # a wall cut in two (its span behind a partition stub lies outside the room) gives two walls
            if part.geom_type != "LineString" or part.length <= tol_m:
                if part.geom_type == "LineString" and abs(part.length - length) <= 1e-9:
                    joins.append(wall)  # a whole wall within the tolerance (a step's join of a few mm)
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
    ends = kept.reshape(-1, 2)  # a view: end k of wall i at row 2 i + k
    for j in joins:
        # ...but the walls it joined still meet: their ends at it go to its middle
        at = (np.hypot(*(ends - j[:2]).T) <= 1e-9) | (np.hypot(*(ends - j[2:]).T) <= 1e-9)
        ends[at] = 0.5 * (j[:2] + j[2:])
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


CLOSED_MIN_LENGTH_SHARE = 0.5
"""`choose_alpha`: a closed candidate counts as closed only with at least this share of the candidates'
median wall length."""


CLOSED_MIN_POINTS_SHARE = 0.5
"""`choose_alpha`: a closed candidate counts as closed only when it holds at least this share of the slice
points (within `UNSEEN_HELD_BUFFER_M` of it): the capture stood in the room, and the walls of the next rooms
seen through its doors are a small part of what it saw."""


def choose_alpha(
    cands: list[Candidate], tol_m: float, wall_max_m: float = 0.0, xy: NDArray | None = None
) -> tuple[int, str]:
    """Index of the chosen candidate and the reason (see the module docstring). Models closed as they
    are rank before models closed only by bridging wider gaps, which rank before unclosed ones. A room
    whose mean width (2 area / perimeter) is no more than `wall_max_m` (the thickest thin wall) is not
    a room but the two faces of one wall or a cabinet, nor one that holds under `CLOSED_MIN_POINTS_SHARE` of
    the slice points `xy` (N, 2), when given."""
    n = len(cands)
    # a closed model holding under half the wall length the candidates typically find is a piece of
    # furniture or a closet the walls of a poorly seen room happen to enclose, not the room; an open one, the
    # few lines the highest α leave (alike at neighbouring α, where the rooms' fuller models each differ)
    length = np.array([float(lengths(c.walls).sum()) for c in cands])
    typical = float(np.median(length)) if n else 0.0
    room_sized = (length >= CLOSED_MIN_LENGTH_SHARE * typical) & np.array(
        [c.polygon is None or 2 * c.polygon.area / max(c.polygon.length, 1e-9) > wall_max_m for c in cands],
        dtype=bool,
    )
    if xy is not None and len(xy):
        # ...and a closed one holding under half the slice points is a cabinet against a wall of a room whose
        # other walls the capture saw apart from it, however long its walls run
        for k, c in enumerate(cands):
            if c.polygon is not None and room_sized[k]:
                room_sized[k] = _within(c.polygon, xy, UNSEEN_HELD_BUFFER_M).mean() >= CLOSED_MIN_POINTS_SHARE
    tiers = (
        (
            "closed",
            lambda c: c.closed and c.counts.get("bridged_gap_m") is None and room_sized[cands.index(c)],
        ),
        ("closed (after bridging wider gaps)", lambda c: c.closed and room_sized[cands.index(c)]),
        (
            "unclosed (no candidate gave a closed, room-sized wall graph)",
            lambda c: room_sized[cands.index(c)],
        ),
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
