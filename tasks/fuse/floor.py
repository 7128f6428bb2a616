"""The fused floor: every placed room's walls in the plan frame with the gaps filled from the plan, the
plan's walls with their fused thickness and the rooms on either side, doors, and floor.geojson."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import shapely
import shapely.geometry
from numpy.typing import NDArray
from shapely.geometry import Polygon

from tasks.fuse.config import FuseConfig
from tasks.fuse.correspond import PlanRoom
from tasks.fuse.gaps import GAP_FILLED, GapFill, fill_gaps, shell_polygon
from tasks.fuse.openings import SpanState, span_state, wall_columns
from tasks.fuse.place import Placed, RoomInput, RoomModel, place_rooms
from tasks.fuse.thickness import PlacedWalls, WallThickness, both_sides_thickness, residual_thickness
from tasks.lines import Segments, as_segments, lengths, share_along, true_runs


@dataclass(frozen=True)
class FusedRoom:
    """One room after fusion."""

    placed: Placed
    walls: Segments
    """(N, 4) plan frame when placed (own frame otherwise), gap-filled walls appended."""
    origin: NDArray[np.str_]
    support: NDArray[np.float64]
    height_m: float
    inward: NDArray[np.float64]
    doors: Segments
    """(D, 4) doors seen in the model, same frame as the walls."""
    gaps: GapFill | None
    closed_plan_doors: tuple[int, ...] = ()
    """Indices of the plan's doors this room's capture shows closed (and no other room saw open)."""
    plan_doors: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    """(P, 4) the plan's doors (what closed_plan_doors indexes)."""
    doors_contradicted: Segments = field(default_factory=lambda: np.zeros((0, 4)))
    """(C, 4) doors seen in the model that another room's capture shows closed (dropped from doors)."""

    @property
    def in_plan(self) -> bool:
        return self.placed.placement is not None


@dataclass(frozen=True)
class FusedFloor:
    rooms: dict[str, FusedRoom]
    models: dict[str, RoomModel]
    thickness: WallThickness
    thickness_residuals: WallThickness
    """The thesis' per-room residual thickness, kept for the comparison."""
    thickness_lines: WallThickness
    centrelines: Segments
    plan_doors: Segments
    plan_rooms: list[PlanRoom]
    metrics: dict[str, Any] = field(default_factory=dict)
    evidence: WallEvidence | None = None
    """Where crisp captures show the plan's walls standing or open (tasks.fuse.floor.wall_evidence)."""


def fuse_floor(
    rooms: list[RoomInput],
    plan_rooms: list[PlanRoom],
    centrelines: Segments,
    plan_thickness_m: NDArray,
    plan_doors: Segments,
    track: NDArray | None,
    cfg: FuseConfig,
) -> FusedFloor:
    """Place every room, measure wall thickness, fill the gaps (see the package's modules)."""
    centrelines = as_segments(centrelines)
    placed, models = place_rooms(rooms, plan_rooms, centrelines, plan_doors, track, cfg)
    by_id = {r.id: r for r in rooms}
    on_plan = []
    for rid, p in placed.items():
        if p.placement is not None:
            m = models[rid]
            on_plan.append(
                PlacedWalls(
                    rid,
                    p.placement.segments(by_id[rid].walls),
                    m.inward @ p.placement.rotation.T,
                    _wall_band(by_id[rid], p.placement),
                )
            )
    args = (
        centrelines,
        np.asarray(plan_thickness_m),
        on_plan,
        cfg.thickness_range_m,
        cfg.default_thickness_m,
    )
    both, lines = both_sides_thickness(*args), both_sides_thickness(*args, local=False)
    resid = residual_thickness(*args, lines=lines)
    thickness = {"both_sides": both, "model_lines": lines, "residuals": resid}[cfg.thickness_method]
    plan_by_id = {p.id: p for p in plan_rooms}
    fused = {}
    for rid, p in placed.items():
        fused[rid] = _fuse_room(
            by_id[rid], p, models.get(rid), plan_by_id, centrelines, thickness, plan_doors, cfg
        )
    fused = cross_check_doors(fused, by_id, models, cfg)
    evidence = wall_evidence(fused, by_id, models, centrelines, thickness.thickness_m, cfg)
    return FusedFloor(
        fused, models, thickness, resid, lines, centrelines, as_segments(plan_doors), plan_rooms, {}, evidence
    )


def _wall_band(room: RoomInput, placement) -> NDArray[np.float64] | None:
    """(M, 2) the room's cloud from 0.15 m above its floor to 0.10 m below its ceiling, in the plan frame
    (where its walls' faces show, clear of the floor and ceiling): None without a cloud."""
    if room.points is None:
        return None
    z = room.points[:, 2]
    band = room.points[(z >= room.floor_z + 0.15) & (z <= room.ceiling_z - 0.10), :2]
    return placement.points(band)


@dataclass(frozen=True)
class WallEvidence:
    """What the crisp captures show along the plan's walls: plan wall index -> stretches (metres along its
    centreline, from its first end)."""

    standing: dict[int, list[tuple[float, float]]]
    """The wall's face seen (not empty by the door finder's measure), nothing seen through it or beside."""
    seen_through: dict[int, list[tuple[float, float]]]
    """The wall's face empty and points seen beyond it (0.1-1.5 m behind): an opening there."""


def wall_evidence(
    fused: dict[str, FusedRoom],
    rooms: dict[str, RoomInput],
    models: dict[str, RoomModel],
    centrelines: Segments,
    thickness_m: NDArray,
    cfg: FuseConfig,
    empty_share: float = 0.2,
    min_run_m: float = 0.10,
) -> WallEvidence:
    """Where the captures show each plan wall standing or open, whatever their wall models made of it:
    along the plan wall's face on each placed room's side (its points' face found within 15 cm,
    tasks.fuse.openings.wall_columns), in 5 cm columns counted over each column and its neighbours as
    the door finder counts them. A column is open where its face is empty (at most empty_share of the
    face's typical column; all of it when no face shows at all) and two points or more lie beyond it, or
    it lies in a door-wide empty run seen through as the door finder reads a door (`door_runs`): a
    removed wall, a door. It stands where its face shows, neither it nor a neighbour was seen through,
    and the capture is crisp (crisp_face_m: a smeared capture fills openings with the wall beside them):
    a wall the model missed still stands. A stretch never looked at is neither, and a room testifies only
    along the stretch its polygon lies beside. Runs shorter than min_run_m are left out."""
    standing: dict[int, list[tuple[float, float]]] = {}
    through: dict[int, list[tuple[float, float]]] = {}
    centrelines = as_segments(centrelines)
    placed = [
        (rid, f)
        for rid, f in fused.items()
        if f.in_plan and rooms[rid].points is not None and f.gaps is not None and f.gaps.polygon is not None
    ]
    three = np.ones(3) / 3.0
    for i, (c, t) in enumerate(zip(centrelines, np.asarray(thickness_m), strict=True)):
        a, b = c[:2], c[2:]
        length = float(np.hypot(*(b - a)))
        if length < min_run_m:
            continue
        u = (b - a) / length
        n = np.array([-u[1], u[0]])
        nbins = max(int(np.ceil(length / 0.05)), 1)  # each room's frame may round it one off
        stands_any, open_any = np.zeros(nbins, dtype=bool), np.zeros(nbins, dtype=bool)
        looked = False
        for side in (1.0, -1.0):
            face = np.concatenate([a + side * (t / 2) * n, b + side * (t / 2) * n])
            probe = shapely.LineString((face.reshape(2, 2) + side * 0.3 * n).tolist())
            for rid, f in placed:
                if not f.gaps.polygon.intersects(probe):  # not this room's side of the wall
                    continue
                room, pl = rooms[rid], f.placed.placement
                back = (face.reshape(2, 2) - np.asarray(pl.t)) @ pl.rotation  # into the room frame
                cols = wall_columns(room.points, room.floor_z, back.reshape(4), (side * n) @ pl.rotation)
                seen = np.convolve(cols.face_low + cols.face_high, three, mode="same")
                ref = cols.reference(cols.face_low + cols.face_high)
                empty = seen <= empty_share * ref
                beyond = cols.through >= 2
                opened = empty & beyond
                near_beyond = np.convolve(beyond.astype(float), np.ones(3), mode="same") > 0
                crisp = models[rid].face_spread_m <= cfg.crisp_face_m
                stands = ~empty & ~near_beyond & crisp
                # only where the room lies beside the face: past the end of its own wall a room sees
                # nothing of the face (a stretch of the next room's wall), only the floor beyond it
                # through a door, which is no opening there
                mine = _beside(f.gaps.polygon, a, u, side * n, t, len(stands))
                opened |= door_runs(empty & mine, beyond, cfg)
                opened &= mine
                stands &= mine
                k = min(nbins, len(stands))
                stands_any[:k] |= stands[:k]
                open_any[:k] |= opened[:k]
                looked = True
        for mask, out in ((stands_any, standing), (open_any, through)):
            if not looked:
                continue
            runs = [
                (i0 * 0.05, min(i1 * 0.05, length))
                for i0, i1 in true_runs(mask)
                if (i1 - i0) * 0.05 >= min_run_m
            ]
            if runs:
                out[i] = runs
    return WallEvidence(standing, through)


def door_runs(empty: NDArray[np.bool_], beyond: NDArray[np.bool_], cfg: FuseConfig) -> NDArray[np.bool_]:
    """(B,) the 5 cm columns of every door-wide run of empty face (door_min_m to door_max_m) seen through
    in at least door_through_share of its columns, as the door finder reads a door
    (tasks.fuse.openings.find_doors): all of it is open. Past a door in a corridor wall the capture often
    sees only the jambs and the floor beside them (the far wall lies beyond reach), and the middle of the
    door, empty but with nothing counted beyond it, is as open as its edges."""
    out = np.zeros(len(empty), dtype=bool)
    for i0, i1 in true_runs(empty):
        width = (i1 - i0) * 0.05
        if cfg.door_min_m <= width <= cfg.door_max_m and beyond[i0:i1].mean() >= cfg.door_through_share:
            out[i0:i1] = True
    return out


def _beside(
    polygon: Polygon, start: NDArray, along: NDArray, normal: NDArray, thickness: float, bins: int
) -> NDArray[np.bool_]:
    """(bins,) the 5 cm columns of a plan wall's face (from `start` along `along`) beside which the room's
    polygon lies: their middles 15 cm off the face on the `normal` side inside it (grown by 5 cm)."""
    s = (np.arange(bins) + 0.5) * 0.05
    pts = start + s[:, None] * along + (thickness / 2 + 0.15) * normal
    return shapely.contains_xy(polygon.buffer(0.05), pts[:, 0], pts[:, 1])


def _fuse_room(
    room: RoomInput,
    placed: Placed,
    model: RoomModel | None,
    plan_rooms: dict[str, PlanRoom],
    centrelines: Segments,
    thickness: WallThickness,
    plan_doors: Segments,
    cfg: FuseConfig,
) -> FusedRoom:
    walls = as_segments(room.walls)
    doors = np.array([d.segment for d in model.doors]).reshape(-1, 4) if model else np.zeros((0, 4))
    inward = model.inward if model else np.zeros((len(walls), 2))
    if placed.placement is None or model is None:
        return FusedRoom(placed, walls, room.origin, room.support, room.height_m, inward, doors, None)
    pl = placed.placement
    furniture = furniture_walls(walls, model, placed, cfg)
    keep = ~furniture
    walls_p, doors_p, inward_p = pl.segments(walls[keep]), pl.segments(doors), inward[keep] @ pl.rotation.T
    plan_room = plan_rooms[placed.correspondence.plan_room or ""]
    shell = shell_polygon(plan_room.polygon, centrelines, thickness.thickness_m, plan_doors)
    gaps = fill_gaps(walls_p, shell, cfg.gap_end_tol_m)
    closed_doors = _closed_plan_doors(room, pl, walls, inward, plan_doors, cfg)
    return FusedRoom(
        placed,
        np.concatenate([walls_p, gaps.walls]),
        np.concatenate([np.asarray(room.origin, dtype=str)[keep], np.full(len(gaps.walls), GAP_FILLED)]),
        np.concatenate([np.asarray(room.support, dtype=np.float64)[keep], np.zeros(len(gaps.walls))]),
        room.height_m,
        np.concatenate([inward_p, _filled_inward(gaps.walls, gaps.polygon)]),
        doors_p,
        gaps,
        closed_doors,
        as_segments(plan_doors),
    )


def furniture_walls(walls: Segments, model: RoomModel, placed: Placed, cfg: FuseConfig) -> NDArray[np.bool_]:
    """(N,) model walls that are no walls of the room: shell walls without a plan face after registration
    that the cloud does not show reaching up to just below the ceiling (tasks.fuse.openings.tops), in a
    capture that shows its matched walls reaching it (it looked up there): a wardrobe's front and side
    that the wall model took for the room's wall (and drew on to the next wall), a wall of the next room
    seen through a door. Gap filling then closes the room along the plan's wall behind them."""
    walls = as_segments(walls)
    out = np.zeros(len(walls), dtype=bool)
    fit = placed.fit
    if fit is None or model.tops is None or not model.shell.any():
        return out
    if not model.face_spread_m <= cfg.crisp_face_m:  # a smeared capture cannot tell
        return out
    shell = np.flatnonzero(model.shell)
    if len(fit.matched) != len(shell):
        return out
    top = np.array([share_along(w, model.tops.at, 0.10) for w in walls[shell]])
    matched = fit.matched >= 0
    w = lengths(walls[shell])
    if not matched.any() or np.average(top[matched], weights=w[matched]) < cfg.furniture_top_share:
        return out
    out[shell[~matched & (top < cfg.furniture_top_share)]] = True
    return out


def _filled_inward(walls: Segments, polygon: Polygon | None) -> NDArray:
    from tasks.fuse.register2d import inward_normals

    return inward_normals(walls, polygon) if len(walls) else np.zeros((0, 2))


def span_seen(
    room: RoomInput, placement, walls: Segments, inward: NDArray, span: NDArray, max_offset_m: float
) -> SpanState | None:
    """How a room's capture saw a plan-frame span (a door's extent) on its own model wall parallel to it
    within max_offset_m (tasks.fuse.openings.span_state), or None when the room has no such wall or no
    cloud."""
    if room.points is None or len(walls) == 0:
        return None
    ends = (np.asarray(span, dtype=np.float64).reshape(2, 2) - np.asarray(placement.t)) @ placement.rotation
    mid = ends.mean(axis=0)
    u = (ends[1] - ends[0]) / max(float(np.hypot(*(ends[1] - ends[0]))), 1e-12)
    for j, w in enumerate(as_segments(walls)):
        length = float(lengths(w[None])[0])
        v = (w[2:] - w[:2]) / max(length, 1e-12)
        n = np.array([-v[1], v[0]])
        s0, s1 = float((ends[0] - w[:2]) @ v), float((ends[1] - w[:2]) @ v)
        if abs(float(u @ v)) < 0.99 or abs(float((mid - w[:2]) @ n)) > max_offset_m:
            continue
        if max(s0, s1) <= 0 or min(s0, s1) >= length:
            continue
        return span_state(room.points, room.floor_z, w, inward[j], s0, s1)
    return None


def _closed_plan_doors(
    room: RoomInput, placement, walls: Segments, inward: NDArray, plan_doors: Segments, cfg: FuseConfig
) -> tuple[int, ...]:
    """Plan doors that this room's capture shows closed: a model wall runs along the door gap (within
    0.25 m), its face (where its points lie) shows across the gap (closed_door_share of it, up to a
    door's height), nothing was seen through it and the capture's face is crisp (crisp_face_m)."""
    out = []
    for k, d in enumerate(as_segments(plan_doors)):
        seen = span_seen(room, placement, walls, inward, d, 0.25)
        if seen is not None and _closed(seen, cfg):
            out.append(k)
    return tuple(out)


def _closed(seen: SpanState, cfg: FuseConfig) -> bool:
    return seen.closed(cfg.closed_door_share, cfg.door_through_share, cfg.crisp_face_m)


def cross_check_doors(
    fused: dict[str, FusedRoom], rooms: dict[str, RoomInput], models: dict[str, RoomModel], cfg: FuseConfig
) -> dict[str, FusedRoom]:
    """Both sides of a wall must agree on a door: a door seen in one room is dropped when another placed
    room's capture shows that stretch of the wall closed from its side (its own wall within 0.45 m: the
    wall's thickness; its face crisp and seen across the door's span, nothing through: a corridor's
    smeared cloud sees into a room obliquely through the next door and reads the unseen face beside it
    as open, the room beyond saw it whole; a smeared face cannot testify either way); a plan door one
    room shows closed stays open when another room saw a door there or, crisp, saw through it."""
    placed = {rid: f for rid, f in fused.items() if f.in_plan and rid in models}
    out = dict(fused)
    for rid, f in placed.items():
        keep, dropped = [], []
        for d in f.doors:
            against = [
                other
                for other, g in placed.items()
                if other != rid
                and (
                    seen := span_seen(
                        rooms[other], g.placed.placement, rooms[other].walls, models[other].inward, d, 0.45
                    )
                )
                is not None
                and _closed(seen, cfg)
            ]
            (dropped if against else keep).append(d)
        out[rid] = replace(
            f,
            doors=np.asarray(keep, dtype=np.float64).reshape(-1, 4),
            doors_contradicted=np.asarray(dropped, dtype=np.float64).reshape(-1, 4),
        )
    doors = np.asarray([d for f in out.values() if f.in_plan for d in f.doors]).reshape(-1, 4)
    for rid, f in out.items():
        if not f.closed_plan_doors:
            continue
        still = []
        for k in f.closed_plan_doors:
            if len(doors) and _overlaps(f.plan_doors[k], doors):
                continue
            seen_open = [
                other
                for other, g in placed.items()
                if other != rid
                and (
                    seen := span_seen(
                        rooms[other],
                        g.placed.placement,
                        rooms[other].walls,
                        models[other].inward,
                        f.plan_doors[k],
                        0.25,
                    )
                )
                is not None
                and seen.face_spread_m <= cfg.crisp_face_m
                and seen.through_share >= cfg.door_through_share
                and (seen.face_share or 0.0) < cfg.closed_door_share
            ]
            if not seen_open:  # another crisp capture saw through it: a door its finder missed
                still.append(k)
        out[rid] = replace(f, closed_plan_doors=tuple(still))
    return out


def _overlaps(span: NDArray, doors: NDArray, max_offset_m: float = 0.45) -> bool:
    """Whether a door (plan frame) lies along the span (parallel, within max_offset_m) over a third of it."""
    a, b = span[:2], span[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    for d in doors:
        v = (d[2:] - d[:2]) / max(float(np.hypot(*(d[2:] - d[:2]))), 1e-12)
        if abs(float(u @ v)) < 0.99 or abs(float((0.5 * (d[:2] + d[2:]) - a) @ n)) > max_offset_m:
            continue
        s0, s1 = sorted([float((d[:2] - a) @ u), float((d[2:] - a) @ u)])
        if min(s1, length) - max(s0, 0.0) >= length / 3:
            return True
    return False


# --------------------------------------------------------------------------------------------- geojson


def rooms_on_sides(
    centrelines: Segments, thickness_m: NDArray, plan_rooms: list[PlanRoom], survey_of: dict[str, str]
) -> list[tuple[str | None, str | None]]:
    """(room on the left, room on the right) of every plan wall: the survey room placed in the plan room
    found 5 cm beyond the wall's face on that side (the plan room id when no survey room is there)."""
    out = []
    for c, t in zip(as_segments(centrelines), thickness_m, strict=True):
        a, b = c[:2], c[2:]
        u = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
        n = np.array([-u[1], u[0]])
        mid = 0.5 * (a + b)
        sides = []
        for side in (1.0, -1.0):
            p = mid + side * (t / 2 + 0.05) * n
            hit = next((r.id for r in plan_rooms if r.polygon.buffer(0.02).contains(shapely.Point(*p))), None)
            sides.append(survey_of.get(hit, hit) if hit else None)
        out.append((sides[0], sides[1]))
    return out


DOOR_MERGE_M = 0.6
"""Doors seen by two rooms (one on each face of a wall) within this of each other, parallel and
overlapping, are one door in floor.geojson."""
HOST_REACH_M = 0.25
"""A door's wall is a parallel plan wall whose centreline lies within half its thickness plus this."""


def _unit(seg: NDArray) -> NDArray:
    d = np.asarray(seg[2:], dtype=np.float64) - np.asarray(seg[:2], dtype=np.float64)
    return d / max(float(np.hypot(*d)), 1e-12)


def _near(a: NDArray, b: NDArray, reach: float) -> bool:
    """Whether segments a and b are parallel, within `reach` across and overlapping along a."""
    u = _unit(a)
    if abs(float(u @ _unit(b))) < 0.95:
        return False
    n = np.array([-u[1], u[0]])
    mid_b = 0.5 * (b[:2] + b[2:])
    if abs(float((mid_b - a[:2]) @ n)) > reach:
        return False
    sa = sorted([0.0, float((a[2:] - a[:2]) @ u)])
    sb = sorted([float((b[:2] - a[:2]) @ u), float((b[2:] - a[:2]) @ u)])
    return min(sa[1], sb[1]) - max(sa[0], sb[0]) > 0.0


def host_wall(door: NDArray, centrelines: Segments, thickness_m: NDArray) -> int | None:
    """The plan wall a door belongs to: parallel, its centreline within half the wall's thickness plus
    HOST_REACH_M of the door's middle, and nearest along (a door in the plan's gap between two walls
    belongs to the nearer of them)."""
    door = np.asarray(door, dtype=np.float64)
    mid = 0.5 * (door[:2] + door[2:])
    best, best_cost = None, np.inf
    for i, (c, t) in enumerate(zip(as_segments(centrelines), thickness_m, strict=True)):
        u = _unit(c)
        if abs(float(u @ _unit(door))) < 0.95:
            continue
        n = np.array([-u[1], u[0]])
        across = abs(float((mid - c[:2]) @ n))
        if across > float(t) / 2 + HOST_REACH_M:
            continue
        s = float((mid - c[:2]) @ u)
        length = float(np.hypot(*(c[2:] - c[:2])))
        along = max(0.0, -s, s - length)
        if along > 1.5:
            continue
        cost = along + across
        if cost < best_cost:
            best, best_cost = i, cost
    return best


def floor_doors(floor: FusedFloor) -> list[dict[str, Any]]:
    """The floor's doors, each once: the openings the placed rooms saw (a door seen from both sides is one),
    then the plan's doors that no room saw and no capture showed closed. Each lies on its wall's
    centreline (`wall`: the index of that plan wall, None when no plan wall holds it)."""
    groups: list[list[tuple[str, NDArray]]] = []
    for rid, f in floor.rooms.items():
        if not f.in_plan:
            continue
        for d in np.asarray(f.doors, dtype=np.float64).reshape(-1, 4):
            group = next((g for g in groups if any(_near(m, d, DOOR_MERGE_M) for _, m in g)), None)
            if group is None:
                groups.append([(rid, d)])
            else:
                group.append((rid, d))
    closed = {k for f in floor.rooms.values() if f.in_plan for k in f.closed_plan_doors}
    found: list[tuple[NDArray, str, list[str]]] = []
    for g in groups:
        ref = g[0][1]
        members = [m if _unit(m) @ _unit(ref) > 0 else np.r_[m[2:], m[:2]] for _, m in g]
        found.append((np.mean(members, axis=0), "observed", sorted({rid for rid, _ in g})))
    for k, d in enumerate(np.asarray(floor.plan_doors, dtype=np.float64).reshape(-1, 4)):
        if k in closed or any(_near(seg, d, DOOR_MERGE_M) for seg, _, _ in found):
            continue
        found.append((d, "plan", []))
    feats = []
    thick = floor.thickness.thickness_m
    for seg, source, seen_by in found:
        host = host_wall(seg, floor.centrelines, thick)
        if host is not None:  # onto the wall's centreline
            c = floor.centrelines[host]
            u = _unit(c)
            seg = np.r_[c[:2] + u * ((seg[:2] - c[:2]) @ u), c[:2] + u * ((seg[2:] - c[:2]) @ u)]
        props = {
            "kind": "door",
            "source": source,
            "rooms": seen_by,
            "wall_id": host,
            "width_m": float(np.hypot(*(seg[2:] - seg[:2]))),
        }
        feats.append(_line(seg, props))
    return feats


def floor_features(floor: FusedFloor) -> list[dict[str, Any]]:
    """floor.geojson: placed rooms (polygon, id, plan room, area), their walls (inner faces with origin),
    the plan walls (centrelines with thickness, its source and the room on each side) and the doors, each
    once (floor_doors)."""
    survey_of = {f.placed.correspondence.plan_room: rid for rid, f in floor.rooms.items() if f.in_plan}
    feats: list[dict[str, Any]] = []
    thick = floor.thickness.thickness_m
    for rid, f in floor.rooms.items():
        if not f.in_plan:
            continue
        poly = f.gaps.polygon if f.gaps is not None else None
        if poly is not None:
            feats.append(
                {
                    "type": "Feature",
                    "geometry": shapely.geometry.mapping(poly),
                    "properties": {
                        "kind": "room",
                        "id": rid,
                        "room_id": rid,
                        "plan_room": f.placed.correspondence.plan_room,
                        "area_m2": float(poly.area),
                        "closed": bool(f.gaps.closed),
                    },
                }
            )
        for w, o in zip(f.walls, f.origin, strict=True):
            host = host_wall(w, floor.centrelines, thick)
            props = {
                "kind": "wall_face",
                "room_id": rid,
                "origin": str(o),
                "wall_id": host,
                "thickness_m": None if host is None else float(thick[host]),
                "rooms": [rid],
            }
            feats.append(_line(w, props))
    sides = rooms_on_sides(floor.centrelines, thick, floor.plan_rooms, survey_of)
    for i, (c, t, s, (left, right)) in enumerate(
        zip(floor.centrelines, thick, floor.thickness.source, sides, strict=True)
    ):
        feats.append(
            _line(
                c,
                {
                    "kind": "wall",
                    "wall_id": i,
                    "thickness_m": float(t),
                    "thickness_source": str(s),
                    "origin": "plan",
                    "rooms": [left, right],
                    "room_left": left,
                    "room_right": right,
                },
            )
        )
    feats += floor_doors(floor)
    return feats


def _line(seg: NDArray, props: dict[str, Any]) -> dict[str, Any]:
    s = [float(v) for v in seg]
    return {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": [[s[0], s[1]], [s[2], s[3]]]},
        "properties": props,
    }
