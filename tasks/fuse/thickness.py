"""Wall thickness after registration (thesis 7.2, and beyond it).

- **both_sides** (the default): a plan wall whose two sides were captured by two placed rooms is as thick
  as the distance between the rooms' facing inner faces: measured every 10 cm where both run past it,
  the median of those. Where a room's cloud is at hand the face is the local one, where that room's
  points show it (`local_face`): a model wall is one straight line over its whole length, and where the
  real face is locally elsewhere (a niche, a few centimetres of jog, a tracked corridor whose face wanders
  along it) the line is off at the stretch the other room sees; the stations measured are those where
  both rooms' clouds show their face;
- **model_lines**: the same between the rooms' model lines (straight over each whole wall), as before the
  local faces: kept for the comparison;
- **residuals** (the thesis): one thickness per room, twice the typical distance of its shell walls to the
  plan's centrelines after registration (the thesis takes the fit residuals near a typical value); a wall
  takes the mean of the rooms on its sides;
- otherwise the plan's own `thickness_m` ("plan"), else the configured default ("default").

Every value says where it came from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tasks.lines import Segments, angle_difference, angles, as_segments, lengths, midpoints

MEASURED, PLAN, DEFAULT = "measured", "plan", "default"


@dataclass(frozen=True)
class PlacedWalls:
    """One placed room's model walls in the plan frame."""

    room: str
    walls: Segments
    """(N, 4) inner faces, plan frame."""
    inward: NDArray[np.float64]
    """(N, 2) unit normals into the room."""
    points: NDArray[np.float64] | None = None
    """(M, 2) the room's cloud at wall height (floor + 0.15 m to 0.10 m below the ceiling), plan frame: where
    its faces are locally (None: the model lines alone)."""


@dataclass(frozen=True)
class WallThickness:
    """Per plan wall (centreline): thickness and its source, and the faces that measured it."""

    thickness_m: NDArray[np.float64]
    source: NDArray[np.str_]
    """"measured" | "plan" | "default"."""
    sides: list[tuple[str | None, str | None]]
    """(room on the left of the centreline, room on the right) whose faces were found (None: none)."""


def face_profile(
    centreline: NDArray,
    placed: list[PlacedWalls],
    reach_m: float,
    step_m: float = 0.10,
    angle_tol_deg: float = 3.0,
) -> dict[int, tuple[NDArray[np.float64], NDArray[np.object_]]]:
    """Along one centreline, every step_m, the offset of the face on each side (+1: left of x0y0 -> x1y1,
    -1: right) where a placed room's face runs past that point: (offsets (K,), NaN where none; the room
    of each, None where none). A face counts when it is parallel, within reach_m, looks away from the
    centreline (into its room); the nearest one wins where two cover a point."""
    a, b = centreline[:2], centreline[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    s = np.arange(step_m / 2, length, step_m)
    out = {}
    for side in (1, -1):
        offset = np.full(len(s), np.nan)
        owner = np.full(len(s), None, dtype=object)
        for room in placed:
            w = as_segments(room.walls)
            if len(w) == 0:
                continue
            par = np.abs(angle_difference(angles(w), math.atan2(u[1], u[0]))) <= math.radians(angle_tol_deg)
            off0, off1 = (w[:, :2] - a) @ n, (w[:, 2:] - a) @ n
            s0, s1 = (w[:, :2] - a) @ u, (w[:, 2:] - a) @ u
            looks_away = np.sign(room.inward @ n) == side
            for k in np.flatnonzero(par & looks_away):
                if abs(s1[k] - s0[k]) < 1e-9:
                    continue
                t = (s - s0[k]) / (s1[k] - s0[k])
                at = off0[k] + t * (off1[k] - off0[k])  # the face's offset where it passes each point
                ok = (t >= 0) & (t <= 1) & (np.sign(at) == side) & (np.abs(at) <= reach_m)
                better = ok & ~(np.abs(offset) <= np.abs(at))  # NaN compares False: first face wins
                offset[better], owner[better] = at[better], room.room
        out[side] = (offset, owner)
    return out


def local_face(
    centreline: NDArray,
    offsets: NDArray,
    owners: NDArray[np.object_],
    side: int,
    placed: list[PlacedWalls],
    step_m: float = 0.10,
    band_m: float = 0.08,
    min_points: int = 10,
) -> NDArray[np.float64]:
    """(K,) at each station of `face_profile` along one centreline, the offset of the face on `side` where
    its room's cloud shows it: that room's points within step_m along the wall of the station and within
    band_m of its model face (the model's line is straight over the whole wall; the face it stands for
    may lie a few centimetres off it here), where they gather (`face_offset`). NaN where the station has
    no face, the room no cloud or fewer than min_points points there (a stretch its capture never saw)."""
    a, b = centreline[:2], centreline[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    s = np.arange(step_m / 2, length, step_m)
    out = np.full(len(s), np.nan)
    by_room = {p.room: p for p in placed}
    for rid in {o for o in owners if o is not None}:
        pts = by_room[rid].points
        if pts is None or len(pts) == 0:
            continue
        mine = np.flatnonzero(owners == rid)
        lo = float(np.nanmin(offsets[mine])) - band_m
        hi = float(np.nanmax(offsets[mine])) + band_m
        ps, po = (pts - a) @ u, (pts - a) @ n
        near = (po >= lo) & (po <= hi) & (ps >= -step_m) & (ps <= length + step_m) & (np.sign(po) == side)
        ps, po = ps[near], po[near]
        order = np.argsort(ps, kind="stable")
        ps, po = ps[order], po[order]
        for k in mine:
            i0, i1 = np.searchsorted(ps, [s[k] - step_m, s[k] + step_m])
            off = po[i0:i1]
            off = off[np.abs(off - offsets[k]) <= band_m]
            if len(off) < min_points:
                continue
            out[k] = face_offset(off)
    return out


def face_offset(offsets: NDArray, floor_m: float = 0.015, iterations: int = 3) -> float:
    """The face the offsets (one wall's points across it) gather on: starting from all of them, the
    median of the points within a window of the current estimate, the window three robust standard
    deviations (1.4826 MAD) of the points in it and no narrower than floor_m, repeated: a crisp face
    keeps a narrow window (and leaves a jog's other face or a door's jamb out), a noisy far-range depth
    face a wide one (its median, not the densest bin of its noise)."""
    off = np.asarray(offsets, dtype=np.float64)
    if len(off) == 0:
        return float("nan")
    centre, width = float(np.median(off)), float(np.ptp(off))
    for _ in range(iterations):
        inside = off[np.abs(off - centre) <= width + 1e-12]
        if len(inside) == 0:
            break
        centre = float(np.median(inside))
        mad = float(np.median(np.abs(inside - centre)))
        width = max(floor_m, 3.0 * 1.4826 * mad)
    return centre


def both_sides_thickness(
    centrelines: Segments,
    plan_thickness_m: NDArray,
    placed: list[PlacedWalls],
    valid_range_m: tuple[float, float],
    default_m: float,
    step_m: float = 0.10,
    min_overlap_m: float = 0.3,
    local: bool = True,
) -> WallThickness:
    """Per plan wall: where two different captured rooms' faces run past it on either side (over at least
    min_overlap_m), the median over that stretch of the distance between them, measured at the same
    points (a long corridor face against two rooms' short ones, a face that stops halfway: each point
    pairs the faces that are there); else the plan's value, else the default. Each face is taken where
    its room's cloud shows it (`local_face`) when both rooms have clouds and their local faces overlap
    over min_overlap_m; else the model's lines."""
    centrelines = as_segments(centrelines)
    thick = np.zeros(len(centrelines))
    source = np.empty(len(centrelines), dtype=object)
    sides: list[tuple[str | None, str | None]] = []
    lo, hi = valid_range_m
    for i, c in enumerate(centrelines):
        plan_t = float(plan_thickness_m[i]) if i < len(plan_thickness_m) else float("nan")
        reach = (plan_t if math.isfinite(plan_t) and plan_t > 0 else hi) / 2 + 0.15
        prof = face_profile(c, placed, reach, step_m)
        (left, left_room), (right, right_room) = prof[1], prof[-1]
        t = left - right
        both = np.isfinite(t) & (left_room != right_room) & (t >= lo) & (t <= hi)
        if local:
            at = local_face(c, left, left_room, 1, placed, step_m) - local_face(
                c, right, right_room, -1, placed, step_m
            )
            seen = both & np.isfinite(at) & (at >= lo) & (at <= hi)
            if seen.sum() * step_m >= min_overlap_m:
                t, both = at, seen
        sides.append((_most(left_room), _most(right_room)))
        if both.sum() * step_m >= min_overlap_m:
            thick[i], source[i] = float(np.median(t[both])), MEASURED
        elif math.isfinite(plan_t) and plan_t > 0:
            thick[i], source[i] = plan_t, PLAN
        else:
            thick[i], source[i] = default_m, DEFAULT
    return WallThickness(thick, source.astype(str), sides)


def _most(owners: NDArray[np.object_]) -> str | None:
    """The room that covers most of the points (None: none)."""
    named = [o for o in owners if o is not None]
    return max(set(named), key=named.count) if named else None


def room_thickness_from_residuals(
    walls: Segments, centrelines: Segments, valid_range_m: tuple[float, float], angle_tol_deg: float = 3.0
) -> float | None:
    """The thesis' figure (7.2): one thickness for a placed room, twice the median distance of its walls to
    the nearest parallel plan centreline, among distances within the valid half-thickness range (the
    plan's lines are centrelines here, so a residual is half a wall). None when no wall qualifies."""
    walls, centrelines = as_segments(walls), as_segments(centrelines)
    if len(walls) == 0 or len(centrelines) == 0:
        return None
    lo, hi = valid_range_m
    mid = midpoints(walls)
    par = np.abs(angle_difference(angles(walls)[:, None], angles(centrelines)[None, :])) <= math.radians(
        angle_tol_deg
    )
    a, u = centrelines[:, :2], centrelines[:, 2:] - centrelines[:, :2]
    u = u / np.maximum(lengths(centrelines), 1e-12)[:, None]
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    dist = np.abs(((mid[:, None, :] - a[None]) * nrm[None]).sum(-1))
    t = ((mid[:, None, :] - a[None]) * u[None]).sum(-1)
    inside = (t >= 0) & (t <= lengths(centrelines)[None, :])
    cand = np.where(par & inside & (dist >= lo / 2) & (dist <= hi / 2), dist, np.inf)
    best = cand.min(axis=1)
    ok = np.isfinite(best)
    if not ok.any():
        return None
    return float(
        2.0 * np.average(best[ok], weights=lengths(walls)[ok]) if ok.sum() < 3 else 2.0 * np.median(best[ok])
    )


def residual_thickness(
    centrelines: Segments,
    plan_thickness_m: NDArray,
    placed: list[PlacedWalls],
    valid_range_m: tuple[float, float],
    default_m: float,
    lines: WallThickness | None = None,
) -> WallThickness:
    """Per plan wall: the mean of the residual thickness of the placed rooms with a face along it (the
    thesis' method), else the plan's value, else the default. `lines`: the same walls'
    `both_sides_thickness(..., local=False)` when already at hand (which rooms are on each side)."""
    centrelines = as_segments(centrelines)
    per_room = {p.room: room_thickness_from_residuals(p.walls, centrelines, valid_range_m) for p in placed}
    both = (
        lines
        if lines is not None
        else both_sides_thickness(
            centrelines, plan_thickness_m, placed, valid_range_m, default_m, local=False
        )
    )
    thick, source = both.thickness_m.copy(), both.source.astype(object)
    for i, (left, right) in enumerate(both.sides):
        vals = [per_room[r] for r in (left, right) if r is not None and per_room.get(r) is not None]
        if vals:
            thick[i], source[i] = float(np.mean(vals)), MEASURED
        elif source[i] == MEASURED:
            source[i] = PLAN if math.isfinite(plan_thickness_m[i]) and plan_thickness_m[i] > 0 else DEFAULT
            thick[i] = plan_thickness_m[i] if source[i] == PLAN else default_m
    return WallThickness(thick, source.astype(str), both.sides)
