"""Wall thickness after registration (thesis 7.2, and beyond it).

- **both_sides** (the default): a plan wall whose two sides were captured by two placed rooms is as thick
  as the distance between the rooms' facing inner faces (measured on their overlap);
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


@dataclass(frozen=True)
class WallThickness:
    """Per plan wall (centreline): thickness and its source, and the faces that measured it."""

    thickness_m: NDArray[np.float64]
    source: NDArray[np.str_]
    """"measured" | "plan" | "default"."""
    sides: list[tuple[str | None, str | None]]
    """(room on the left of the centreline, room on the right) whose faces were found (None: none)."""


def face_offsets(
    centreline: NDArray,
    placed: list[PlacedWalls],
    reach_m: float,
    angle_tol_deg: float = 3.0,
    min_overlap_m: float = 0.3,
) -> dict[int, list[tuple[str, float, float]]]:
    """Faces lying along one centreline, by side (+1: left of x0y0 -> x1y1, -1: right): (room, mean
    offset from the centreline (m, signed), overlap length along it (m)). A face counts when it is
    parallel, within reach_m, overlaps the centreline and looks away from it (into its room)."""
    a, b = centreline[:2], centreline[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    out: dict[int, list[tuple[str, float, float]]] = {1: [], -1: []}
    for room in placed:
        w = as_segments(room.walls)
        if len(w) == 0:
            continue
        par = np.abs(angle_difference(angles(w), math.atan2(u[1], u[0]))) <= math.radians(angle_tol_deg)
        off0, off1 = (w[:, :2] - a) @ n, (w[:, 2:] - a) @ n
        off = 0.5 * (off0 + off1)
        s0, s1 = (w[:, :2] - a) @ u, (w[:, 2:] - a) @ u
        overlap = np.minimum(np.maximum(s0, s1), length) - np.maximum(np.minimum(s0, s1), 0.0)
        looks_away = np.sign(room.inward @ n) == np.sign(off)
        ok = par & (np.abs(off) <= reach_m) & (overlap >= min_overlap_m) & looks_away
        for k in np.flatnonzero(ok):
            out[int(np.sign(off[k]))].append((room.room, float(off[k]), float(overlap[k])))
    return out


def both_sides_thickness(
    centrelines: Segments,
    plan_thickness_m: NDArray,
    placed: list[PlacedWalls],
    valid_range_m: tuple[float, float],
    default_m: float,
) -> WallThickness:
    """Per plan wall: the distance between the two captured rooms' facing faces where both sides were seen
    by different rooms (the longest-overlapping face of each side), else the plan's value, else the default."""
    centrelines = as_segments(centrelines)
    thick = np.zeros(len(centrelines))
    source = np.empty(len(centrelines), dtype=object)
    sides: list[tuple[str | None, str | None]] = []
    lo, hi = valid_range_m
    for i, c in enumerate(centrelines):
        plan_t = float(plan_thickness_m[i]) if i < len(plan_thickness_m) else float("nan")
        reach = (plan_t if math.isfinite(plan_t) and plan_t > 0 else hi) / 2 + 0.15
        faces = face_offsets(c, placed, reach)
        left = max(faces[1], key=lambda f: f[2], default=None)
        right = max(faces[-1], key=lambda f: f[2], default=None)
        sides.append((left[0] if left else None, right[0] if right else None))
        if left and right and left[0] != right[0] and lo <= left[1] - right[1] <= hi:
            thick[i], source[i] = left[1] - right[1], MEASURED
        elif math.isfinite(plan_t) and plan_t > 0:
            thick[i], source[i] = plan_t, PLAN
        else:
            thick[i], source[i] = default_m, DEFAULT
    return WallThickness(thick, source.astype(str), sides)


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
) -> WallThickness:
    """Per plan wall: the mean of the residual thickness of the placed rooms with a face along it (the
    thesis' method), else the plan's value, else the default."""
    centrelines = as_segments(centrelines)
    per_room = {p.room: room_thickness_from_residuals(p.walls, centrelines, valid_range_m) for p in placed}
    both = both_sides_thickness(centrelines, plan_thickness_m, placed, valid_range_m, default_m)
    thick, source = both.thickness_m.copy(), both.source.astype(object)
    for i, (left, right) in enumerate(both.sides):
        vals = [per_room[r] for r in (left, right) if r is not None and per_room.get(r) is not None]
        if vals:
            thick[i], source[i] = float(np.mean(vals)), MEASURED
        elif source[i] == MEASURED:
            source[i] = PLAN if math.isfinite(plan_thickness_m[i]) and plan_thickness_m[i] > 0 else DEFAULT
            thick[i] = plan_thickness_m[i] if source[i] == PLAN else default_m
    return WallThickness(thick, source.astype(str), both.sides)
