"""Which plan room each captured room is (thesis 7.1.1), from the first source that answers:

1. **label**: survey.yaml's `plan_room`, the label printed in the plan room (read by the plan stage);
2. **track**: the plan room holding most of the IMU track's positions during the room's capture (the
   thesis: the room that holds the track's last point);
3. **shape**: among the plan rooms nobody else claims, those of similar area, then of similar outline
   (turning function), then the best registration fit score.

Every room gets its source, or the reason it has none. Two rooms claiming one plan room: the stronger
source keeps it (label, track, shape), equal sources the better fit; the other is reported.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

SOURCES = ("label", "track", "shape")


@dataclass(frozen=True)
class PlanRoom:
    """A room of the parsed plan: free space up to the drawn walls, plan frame."""

    id: str
    label: str | None
    polygon: Polygon


@dataclass(frozen=True)
class RoomEvidence:
    """What a captured room offers for finding its plan room."""

    id: str
    plan_room: str | None = None
    """survey.yaml's label."""
    track_xy: NDArray[np.float64] | None = None
    """(K, 2) track positions (plan frame) during the capture."""
    outline: Polygon | None = None
    """The model's room polygon (its own frame) when the walls close it."""
    area_m2: float | None = None
    """The model's area (its polygon's, else its walls' convex hull's)."""


@dataclass(frozen=True)
class Correspondence:
    room: str
    plan_room: str | None
    source: str | None
    """"label" | "track" | "shape" | None (no plan room)."""
    notes: tuple[str, ...] = ()
    """Why earlier sources did not answer, conflicts, the reason for no plan room."""


def normalize_label(label: object) -> str:
    """Labels compare as upper-case text without spaces ('101', ' r 101' -> 'R101')."""
    return "".join(str(label).split()).upper()


def by_label(ev: RoomEvidence, plan_rooms: list[PlanRoom]) -> tuple[str | None, str]:
    """(plan room id, note) from the survey's label."""
    if not ev.plan_room:
        return None, "no plan_room in survey.yaml"
    want = normalize_label(ev.plan_room)
    hits = [p.id for p in plan_rooms if p.label is not None and normalize_label(p.label) == want]
    if len(hits) == 1:
        return hits[0], ""
    if len(hits) > 1:
        return None, f"plan_room {ev.plan_room!r} is printed in {len(hits)} plan rooms ({', '.join(hits)})"
    return None, f"plan_room {ev.plan_room!r} is not a label read on the plan"


def by_track(ev: RoomEvidence, plan_rooms: list[PlanRoom], min_share: float = 0.5) -> tuple[str | None, str]:
    """(plan room id, note): the plan room holding at least min_share of the track's positions during
    the capture."""
    if ev.track_xy is None or len(ev.track_xy) == 0:
        return None, "no track positions during the capture"
    xy = np.asarray(ev.track_xy, dtype=np.float64).reshape(-1, 2)
    counts = [int(shapely.contains_xy(p.polygon, xy[:, 0], xy[:, 1]).sum()) for p in plan_rooms]
    if not counts or max(counts) < min_share * len(xy):
        return None, f"the track lies in no plan room for {min_share:.0%} of the capture"
    return plan_rooms[int(np.argmax(counts))].id, ""


def turning_distance(a: Polygon, b: Polygon, samples: int = 256) -> float:
    """Distance of two outlines' turning functions (Arkin et al.): the L2 distance of the tangent angle
    as a function of the normalized arc length, minimized over the start point and the rotation; 0 for
    similar shapes (scale and position do not matter)."""
    fa, fb = _turning(a, samples), _turning(b, samples)
    best = math.inf
    s = np.linspace(0, 1, samples, endpoint=False)
    for shift in range(samples):
        g = np.roll(fb, -shift) + np.where(s >= 1 - shift / samples, 2 * math.pi, 0.0)
        diff = fa - g
        diff -= diff.mean()  # the best rotation
        best = min(best, float(np.sqrt((diff**2).mean())))
    return best


def _turning(poly: Polygon, samples: int) -> NDArray[np.float64]:
    ring = np.asarray(orient(poly.simplify(0.05), 1.0).exterior.coords)
    d = np.diff(ring, axis=0)
    seg_len = np.hypot(d[:, 0], d[:, 1])
    keep = seg_len > 1e-9
    d, seg_len = d[keep], seg_len[keep]
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    heading -= heading[0]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)]) / seg_len.sum()
    s = np.linspace(0, 1, samples, endpoint=False)
    return heading[np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(heading) - 1)]


def by_shape(
    ev: RoomEvidence,
    free: list[PlanRoom],
    fit_score: Callable[[str], float] | None = None,
    area_tol: float = 0.25,
    turning_tol: float = 0.15,
) -> tuple[str | None, str]:
    """(plan room id, note) by shape among the free plan rooms: area within area_tol (relative), then
    turning-function distance within turning_tol of the best, then the best fit score (when given)."""
    if ev.area_m2 is None or ev.area_m2 <= 0:
        return None, "the model has no area to compare"
    cands = [p for p in free if abs(p.polygon.area - ev.area_m2) <= area_tol * p.polygon.area]
    if not cands:
        return None, f"no free plan room has an area near the model's {ev.area_m2:.1f} m2"
    if ev.outline is not None and len(cands) > 1:
        dist = {p.id: turning_distance(ev.outline, p.polygon) for p in cands}
        lo = min(dist.values())
        cands = [p for p in cands if dist[p.id] <= lo + turning_tol]
    if fit_score is not None and len(cands) > 1:
        scores = {p.id: fit_score(p.id) for p in cands}
        return max(cands, key=lambda p: scores[p.id]).id, ""
    if len(cands) > 1:
        cands.sort(key=lambda p: abs(p.polygon.area - ev.area_m2))
    return cands[0].id, ""


def correspond_rooms(
    rooms: list[RoomEvidence],
    plan_rooms: list[PlanRoom],
    fit_score: Callable[[str, str], float] | None = None,
) -> dict[str, Correspondence]:
    """Room id -> its correspondence. `fit_score(room, plan_room)` (optional) ranks shape candidates and
    settles two claims of one source."""
    notes: dict[str, list[str]] = {r.id: [] for r in rooms}
    claims: dict[str, tuple[str, str]] = {}  # room -> (plan room, source)
    for ev in rooms:
        for source in ("label", "track"):
            pid, note = (by_label if source == "label" else by_track)(ev, plan_rooms)
            if pid is not None:
                claims[ev.id] = (pid, source)
                break
            notes[ev.id].append(f"{source}: {note}")
    _settle(claims, notes, fit_score)
    for ev in rooms:
        if ev.id in claims:
            continue
        taken = {pid for pid, _ in claims.values()}
        free = [p for p in plan_rooms if p.id not in taken]
        score = (lambda pid, rid=ev.id: fit_score(rid, pid)) if fit_score else None
        pid, note = by_shape(ev, free, score)
        if pid is not None:
            claims[ev.id] = (pid, "shape")
        else:
            notes[ev.id].append(f"shape: {note}")
    out = {}
    for ev in rooms:
        pid, source = claims.get(ev.id, (None, None))
        out[ev.id] = Correspondence(ev.id, pid, source, tuple(notes[ev.id]))
    return out


def _settle(
    claims: dict[str, tuple[str, str]],
    notes: dict[str, list[str]],
    fit_score: Callable[[str, str], float] | None,
) -> None:
    """Two rooms claiming one plan room: the stronger source keeps it, then the better fit; the other loses
    its claim (and goes on to shape matching) with a note."""
    by_plan: dict[str, list[str]] = {}
    for rid, (pid, _) in claims.items():
        by_plan.setdefault(pid, []).append(rid)
    for pid, rids in by_plan.items():
        if len(rids) < 2:
            continue

        def rank(rid: str, pid: str = pid) -> tuple[int, float]:
            score = fit_score(rid, pid) if fit_score else 0.0
            return (-SOURCES.index(claims[rid][1]), score)

        keep = max(rids, key=rank)
        for rid in rids:
            if rid != keep:
                notes[rid].append(
                    f"{claims[rid][1]}: plan room {pid} is also claimed by room {keep} "
                    f"({claims[keep][1]}), which keeps it"
                )
                del claims[rid]
