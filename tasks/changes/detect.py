"""Where the building differs from its plan (thesis 7.2, and its future work), in the plan frame.

Wall level (changes.parquet):
- **added**: pieces of the placed room models (observed walls, doors cut out) outside every plan wall's
  buffer (half its fused thickness plus a margin), standing in a plan room's free space and in the
  room's cloud from 0.15 to 1.9 m (the wall model is found near the ceiling: a lamp there is no wall),
  from a crisp capture (one whose frames disagree by centimetres shows ghosts of walls), reaching up to
  just below the ceiling (a wardrobe's front that the wall model took for a wall stops short). A
  model wall across a plan door gap is added only when the room's capture shows that door closed (its
  face seen across, nothing through), so a door the model merely spans (above the lintel) is no change;
- **removed**: plan walls that no placed room supports (no parallel model wall within a tolerance of the
  wall's face on that room's side, doors seen in any room cut out) where a room's capture covers the
  face (its floor or ceiling seen right beside it) and no crisp capture's cloud shows the wall standing
  there (a wall the model missed is still there);
- **unknown**: unsupported plan walls that no capture covers: no claim either way.
A moved door is the removed wall at its new place (the model's door) plus the added wall at its old one.

Room level (beyond the thesis, its own future work): a room larger than its plan room, two plan rooms
merged into one captured room, a plan room split by a new wall.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Polygon

from tasks.changes.config import ChangesConfig
from tasks.lines import Segments, as_segments, lengths, room_polygons, share_along, true_runs

ADDED, REMOVED, UNKNOWN = "added", "removed", "unknown"


class CoverageLike(Protocol):
    def at(self, xy: NDArray) -> NDArray[np.bool_]: ...


@dataclass(frozen=True)
class PlacedRoom:
    """One placed room as change detection sees it (plan frame)."""

    id: str
    walls: Segments
    """(N, 4) model walls (observed and extended; gap-filled walls are the plan's, not evidence)."""
    support: NDArray[np.float64]
    """(N,) share of each wall backed by data."""
    doors: Segments
    """(D, 4) doors seen in the model."""
    coverage: CoverageLike | None
    """Where the capture looked (None: nowhere known)."""
    plan_room: str | None = None
    polygon: Polygon | None = None
    """The model's room (closed walls), plan frame."""
    closed_plan_doors: tuple[int, ...] = ()
    """Indices of the plan's doors this room's capture shows closed."""
    surfaces: CoverageLike | None = None
    """Where its cloud shows something standing, 0.15-1.9 m above the floor (None: not known)."""
    crisp: bool | None = None
    """Its capture's wall faces are crisp (its frames agree; None: not known): a smeared capture shows
    ghosts of walls and claims no added wall."""
    tops: CoverageLike | None = None
    """Where its cloud shows something just below the ceiling (None: not known): a wall reaches up there,
    furniture the wall model took for a wall (a wardrobe's front or side) does not."""


@dataclass(frozen=True)
class Change:
    x0: float
    y0: float
    x1: float
    y1: float
    kind: str
    room_id: str
    support: float
    """Share of the piece backed by model data (added: the model wall's support; removed/unknown: the
    share of the plan face supported, below the threshold)."""
    distance_m: float
    """Added: distance of the piece from the nearest plan wall's centreline; removed/unknown: distance of
    the nearest parallel model wall from the face (inf: none)."""


@dataclass(frozen=True)
class RoomChange:
    kind: str
    """"room_enlarged" | "rooms_merged" | "room_split"."""
    room_ids: tuple[str, ...]
    plan_rooms: tuple[str, ...]
    polygon: Polygon
    share: float
    """The share of area that makes it a change (outside the plan room, of each merged room, of each part)."""
    extra: dict[str, Any] = field(default_factory=dict)


def _pieces(line: LineString | Any, min_length: float) -> list[NDArray]:
    """The (x0, y0, x1, y1) of every linear part of a shapely result at least min_length long."""
    out = []
    for g in getattr(line, "geoms", [line]):
        if g.is_empty or g.geom_type != "LineString" or g.length < min_length:
            continue
        c = np.asarray(g.coords)
        out.append(np.array([*c[0], *c[-1]]))
    return out


def plan_buffers(centrelines: Segments, thickness_m: NDArray, margin_m: float) -> Any:
    """Union of the plan walls' rectangles grown by the margin (flat ends: a door gap stays a gap)."""
    centrelines = as_segments(centrelines)
    rects = [
        LineString(c.reshape(2, 2)).buffer(t / 2 + margin_m, cap_style="flat", join_style="mitre")
        for c, t in zip(centrelines, thickness_m, strict=True)
    ]
    return shapely.union_all(rects) if rects else shapely.GeometryCollection()


def added_walls(
    room: PlacedRoom,
    centrelines: Segments,
    thickness_m: NDArray,
    plan_doors: Segments,
    cfg: ChangesConfig,
    plan_rooms: list[Polygon] | None = None,
    own: Polygon | None = None,
) -> list[Change]:
    """Pieces of the room's walls (its doors cut out) outside every plan wall's buffer: in a plan door
    gap that the room shows closed, or standing in a plan room's free space (farther than the margin
    inside its outline: where the plan's wall lines leave a gap at a junction the drawn wall is still
    there, and a wall modelled along the outline is no new wall). Without `plan_rooms` every piece outside
    the buffers and the open door gaps counts. With `own` (the room's polygon, else its plan room) only
    pieces within a wall's thickness (own_reach_m) of it: a wall or a cupboard of the next room that a
    corridor saw through a door is that room's to claim."""
    buffers = plan_buffers(centrelines, thickness_m, cfg.buffer_margin_m)
    doors = as_segments(room.doors)
    cut = (
        shapely.union_all([LineString(d.reshape(2, 2)).buffer(0.15, cap_style="flat") for d in doors])
        if len(doors)
        else None
    )
    gaps = [
        (k, LineString(d.reshape(2, 2)).buffer(t / 2 + cfg.buffer_margin_m, cap_style="flat"))
        for k, (d, t) in enumerate(
            zip(as_segments(plan_doors), _door_thickness(plan_doors, centrelines, thickness_m), strict=True)
        )
    ]
    open_gaps = [g for k, g in gaps if k not in room.closed_plan_doors]
    closed_gaps = shapely.union_all([g for k, g in gaps if k in room.closed_plan_doors])
    skip = shapely.union_all([buffers, *open_gaps]) if open_gaps else buffers
    if cut is not None:
        skip = skip.union(cut)
    free = (
        shapely.union_all([p.buffer(-cfg.buffer_margin_m) for p in plan_rooms])
        if plan_rooms is not None
        else None
    )
    out = []
    cl = shapely.linestrings(as_segments(centrelines).reshape(-1, 2, 2)) if len(centrelines) else None
    for w, sup in zip(as_segments(room.walls), room.support, strict=True):
        rest = LineString(w.reshape(2, 2)).difference(skip)
        for piece in _pieces(rest, cfg.min_length_m):
            mid = shapely.Point(*(0.5 * (piece[:2] + piece[2:])))
            if free is not None and not (free.contains(mid) or closed_gaps.contains(mid)):
                continue
            if own is not None and own.distance(mid) > cfg.own_reach_m:
                continue
            if room.crisp is False:  # a smeared capture shows ghosts of walls
                continue
            if (
                room.surfaces is not None
                and _standing_share(piece, room.surfaces, cfg) < cfg.added_face_share
            ):
                continue
            if (
                room.tops is not None
                and _standing_share(piece, room.tops, cfg, margin_m=cfg.top_margin_m) < cfg.added_top_share
            ):
                continue  # stops short of the ceiling: furniture
            dist = float(shapely.distance(cl, mid).min()) if cl is not None else math.inf
            out.append(Change(*piece.tolist(), ADDED, room.id, float(sup), dist))
    return out


def _standing_share(
    piece: NDArray,
    surfaces: CoverageLike,
    cfg: ChangesConfig,
    step_m: float = 0.05,
    margin_m: float | None = None,
) -> float:
    """Share of a piece's length along which the cloud shows something standing within margin_m (default
    face_margin_m)."""
    margin = cfg.face_margin_m if margin_m is None else margin_m
    return share_along(piece, surfaces.at, margin, step_m)


def _door_thickness(plan_doors: Segments, centrelines: Segments, thickness_m: NDArray) -> NDArray:
    """Thickness of the wall each plan door pierces (the nearest centreline's)."""
    doors = as_segments(plan_doors)
    if len(doors) == 0 or len(centrelines) == 0:
        return np.full(len(doors), 0.2)
    mid = shapely.points(0.5 * (doors[:, :2] + doors[:, 2:]))
    lines = shapely.linestrings(as_segments(centrelines).reshape(-1, 2, 2))
    k = np.array([int(np.argmin(shapely.distance(lines, m))) for m in mid])
    return np.asarray(thickness_m)[k]


def _side_samples(c: NDArray, t: float, side: float, step: float) -> tuple[NDArray, NDArray, NDArray]:
    """Samples along a wall's face on one side: (face points (K, 2), unit normal into that side, along s)."""
    a, b = c[:2], c[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = side * np.array([-u[1], u[0]])
    s = np.arange(step / 2, length, step)
    return a + s[:, None] * u + (t / 2) * n, n, s


def centre_support(
    centre: NDArray, reach: float, rooms: list[PlacedRoom], doors: Segments | None = None
) -> tuple[NDArray[np.bool_], float]:
    """(K,) whether a model wall (of any placed room, the doors cut out) runs past each centreline sample
    within `reach` of it, measured across the model wall (the sample projects onto it): inside the drawn
    wall or just beyond its face, so a wall drawn thicker than built is still there while a door's
    opening is not bridged by the wall ends beside it. Also the nearest such distance (inf: none).
    `doors` (plan frame) are cut from every room's walls (a door seen from one side is an opening in the
    wall the room on the other side models across it, near its ceiling); by default each room's own."""
    pieces = []
    for room in rooms:
        walls = as_segments(room.walls)
        if len(walls) == 0:
            continue
        g = shapely.union_all(shapely.linestrings(walls.reshape(-1, 2, 2)))
        cut_by = as_segments(room.doors if doors is None else doors)
        if len(cut_by):
            cut = [LineString(d.reshape(2, 2)).buffer(0.3, cap_style="flat") for d in cut_by]
            g = g.difference(shapely.union_all(cut))
        pieces += _pieces(g, 0.0)
    if not pieces:
        return np.zeros(len(centre), dtype=bool), math.inf
    w = np.array(pieces)
    a, d = w[:, :2], w[:, 2:] - w[:, :2]
    length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    u = d / length[:, None]
    rel = centre[:, None, :] - a[None]
    along = (rel * u[None]).sum(-1)
    across = np.abs(rel[..., 0] * u[None, :, 1] - rel[..., 1] * u[None, :, 0])
    across = np.where((along >= 0) & (along <= length[None]), across, np.inf)
    best = across.min(axis=1)
    return best <= reach, float(best.min()) if len(best) else math.inf


def removed_walls(
    centrelines: Segments,
    thickness_m: NDArray,
    rooms: list[PlacedRoom],
    cfg: ChangesConfig,
    step_m: float = 0.05,
    standing: dict[int, list[tuple[float, float]]] | None = None,
    seen_through: dict[int, list[tuple[float, float]]] | None = None,
) -> list[Change]:
    """Stretches of plan walls (per centreline sample) that no placed room's walls support: removed where
    some room's coverage sees the wall's face from its side, unknown where none does (only plan walls
    beside a placed room are judged); runs shorter than min_length_m are dropped. A door seen in any
    room's model where the plan has a wall is such a stretch (a door moved there): every room's doors
    are cut from every room's walls. With fuse's wall evidence (plan wall index -> stretches along it,
    metres; tasks.fuse.floor.wall_evidence), what the captures' points show decides instead of their
    coverage: where a crisp capture shows the wall `standing` it is no change whatever the wall models
    made of it, and an unsupported stretch is removed only where a crisp capture saw through it
    (`seen_through`), else unknown (the ceiling seen beside a wall is not the wall seen gone)."""
    out: list[Change] = []
    doors = np.concatenate([as_segments(r.doors) for r in rooms]) if rooms else np.zeros((0, 4))
    for i, (c, t) in enumerate(zip(as_segments(centrelines), thickness_m, strict=True)):
        length = float(lengths(c[None])[0])
        if length < cfg.min_length_m:
            continue
        centre, _, along = _side_samples(c, 0.0, 1.0, step_m)
        near = [
            r
            for r in rooms
            if r.polygon is None or r.polygon.distance(LineString(c.reshape(2, 2))) <= t / 2 + 0.3
        ]
        if not near:
            continue
        supported, nearest = centre_support(centre, float(t) / 2 + cfg.support_tol_m, near, doors)
        seen = np.zeros(len(centre), dtype=bool)
        votes: dict[str, int] = {}
        for side in (1.0, -1.0):
            face, n, _ = _side_samples(c, float(t), side, step_m)
            for room in near:
                cov = _seen(face, n, room, cfg)
                seen |= cov
                votes[room.id] = votes.get(room.id, 0) + int(cov.sum())
        for s0, s1 in (standing or {}).get(i, []):
            supported |= (along >= s0) & (along <= s1)
        if seen_through is not None:
            seen = np.zeros(len(centre), dtype=bool)
            for s0, s1 in seen_through.get(i, []):
                seen |= (along >= s0) & (along <= s1)
        share = float(supported.mean())
        owner = max(votes, key=lambda r: votes[r])
        a = c[:2]
        u = (c[2:] - a) / length
        for kind, mask in ((REMOVED, ~supported & seen), (UNKNOWN, ~supported & ~seen)):
            for i0, i1 in true_runs(mask):
                if (i1 - i0) * step_m < cfg.min_length_m:
                    continue
                p0, p1 = a + (i0 * step_m) * u, a + min(i1 * step_m, length) * u
                out.append(Change(*p0, *p1, kind, owner, share, nearest))
    return out


def _seen(face: NDArray, n: NDArray, room: PlacedRoom, cfg: ChangesConfig) -> NDArray[np.bool_]:
    """(K,) face samples whose room side the capture saw (coverage at 0.1 .. reach m into the room)."""
    if room.coverage is None:
        return np.zeros(len(face), dtype=bool)
    out = np.zeros(len(face), dtype=bool)
    for d in np.arange(cfg.coverage_cell_m, cfg.coverage_reach_m + 1e-9, cfg.coverage_cell_m):
        out |= room.coverage.at(face + d * n)
    return out


# -------------------------------------------------------------------------------------------- room level


def room_changes(
    rooms: list[PlacedRoom], plan_rooms: dict[str, Polygon], cfg: ChangesConfig
) -> list[RoomChange]:
    """Room-level changes: enlarged (the model leaves its plan room by more than room_change_share of the
    plan room's area, not into a room it merged with), merged (the model covers more than half of two or
    more plan rooms), split (a plan room of which two placed rooms each hold more than a fifth, or whose
    one model's walls divide it into parts each over a fifth of it)."""
    out: list[RoomChange] = []
    share_min = cfg.room_change_share
    holders: dict[str, list[tuple[str, float]]] = {}
    for room in rooms:
        if room.polygon is None:
            continue
        covered = {
            pid: room.polygon.intersection(p).area / p.area for pid, p in plan_rooms.items() if p.area > 0
        }
        for pid, share in covered.items():
            if share > 0.2:
                holders.setdefault(pid, []).append((room.id, share))
        merged = sorted(pid for pid, share in covered.items() if share > 0.5)
        if len(merged) >= 2:
            union = shapely.union_all([plan_rooms[p] for p in merged])
            out.append(
                RoomChange(
                    "rooms_merged", (room.id,), tuple(merged), room.polygon, min(covered[p] for p in merged)
                )
            )
            base = union
        elif room.plan_room in plan_rooms:
            base = plan_rooms[room.plan_room]
        else:
            continue
        outside = room.polygon.difference(base.buffer(0.1))
        if outside.area > share_min * base.area:
            out.append(
                RoomChange(
                    "room_enlarged",
                    (room.id,),
                    tuple(merged or [room.plan_room]),
                    outside,
                    outside.area / base.area,
                )
            )
        if room.plan_room in plan_rooms:
            _split_by_walls(room, plan_rooms[room.plan_room], out)
    for pid, hs in holders.items():
        if len(hs) >= 2:
            out.append(
                RoomChange(
                    "room_split",
                    tuple(sorted(r for r, _ in hs)),
                    (pid,),
                    plan_rooms[pid],
                    min(s for _, s in hs),
                )
            )
    return out


def _split_by_walls(room: PlacedRoom, plan_room: Polygon, out: list[RoomChange]) -> None:
    """A plan room divided by the model's own walls: two faces each over a fifth of it."""
    faces = [
        f
        for f in room_polygons(as_segments(room.walls), tol=0.02)
        if f.intersection(plan_room).area > 0.2 * plan_room.area
    ]
    if len(faces) >= 2:
        shares = [f.intersection(plan_room).area / plan_room.area for f in faces]
        out.append(
            RoomChange(
                "room_split",
                (room.id,),
                (room.plan_room or "",),
                plan_room,
                min(shares),
                {"parts": len(faces)},
            )
        )
