"""The fused floor as the deliverables draw it: the plan's walls at their fused thickness (what stands,
what was removed), the added walls, the doors on their walls, the rooms with name, area and height,
and the changes. Read from fuse's floor.geojson and per-room walls, changes.parquet and the plan.

Frame: the plan frame (metres, x right, y up), z = 0 on the floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.geometry
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.deliver.config import DeliverConfig
from tasks.fuse.floor import host_wall


@dataclass(frozen=True)
class Wall:
    """A wall box: its centreline (the IFC axis), thickness and height."""

    key: str
    """Its identity (IFC GUIDs are derived from it): "wall:<index>" for the plan's, "added:<index>"."""
    centreline: NDArray[np.float64]
    thickness_m: float
    height_m: float
    status: str
    """"existing", "demolished" (removed along most of its length) or "added"."""
    origin: str = "plan"
    rooms: tuple[str | None, str | None] = (None, None)
    wall_id: int | None = None
    """Index among floor.geojson's walls (None for an added wall)."""

    @property
    def length_m(self) -> float:
        return float(np.hypot(*(self.centreline[2:] - self.centreline[:2])))

    @property
    def axis(self) -> NDArray[np.float64]:
        return (self.centreline[2:] - self.centreline[:2]) / max(self.length_m, 1e-12)

    def along(self, p: NDArray[np.float64]) -> float:
        """The position of a point along the centreline from its start (m)."""
        return float((np.asarray(p, dtype=np.float64) - self.centreline[:2]) @ self.axis)


@dataclass(frozen=True)
class Door:
    key: str
    segment: NDArray[np.float64]
    """On its wall's centreline (plan frame)."""
    wall_id: int | None
    source: str
    rooms: tuple[str, ...] = ()

    @property
    def width_m(self) -> float:
        return float(np.hypot(*(self.segment[2:] - self.segment[:2])))


@dataclass(frozen=True)
class Room:
    id: str
    plan_room: str | None
    label: str | None
    """The label printed in its plan room (e.g. "101"), when read."""
    polygon: shapely.Polygon | shapely.MultiPolygon
    height_m: float

    @property
    def area_m2(self) -> float:
        return float(self.polygon.area)


@dataclass(frozen=True)
class ChangeMark:
    segment: NDArray[np.float64]
    kind: str
    """"added", "removed" or "unknown"."""
    room_id: str
    wall_id: int | None = None
    """Removed and unknown pieces: the plan wall they lie on."""


@dataclass
class Floor:
    walls: list[Wall]
    """floor.geojson's walls, in its order (index = wall_id)."""
    added: list[Wall]
    doors: list[Door]
    rooms: list[Room]
    changes: list[ChangeMark]
    plan_walls: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    """The plan's own walls (underlay): (M, 4) centrelines."""
    plan_thickness_m: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    plan_doors: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))

    def removed_on(self, wall_id: int) -> list[ChangeMark]:
        return [c for c in self.changes if c.kind == "removed" and c.wall_id == wall_id]

    def doors_on(self, wall_id: int) -> list[Door]:
        return [d for d in self.doors if d.wall_id == wall_id]


# ------------------------------------------------------------------------------------------- geometry


def outline(
    centreline: NDArray[np.float64], thickness_m: float, s0: float = 0.0, s1: float | None = None
) -> NDArray[np.float64]:
    """(4, 2) corners, counter-clockwise, of the stretch s0..s1 along a centreline at a thickness."""
    c = np.asarray(centreline, dtype=np.float64)
    d = c[2:] - c[:2]
    length = float(np.hypot(*d))
    u = d / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    s1 = length if s1 is None else s1
    a, b = c[:2] + u * s0, c[:2] + u * s1
    h = 0.5 * thickness_m * n
    return np.array([a - h, b - h, b + h, a + h])


def subtract(span: tuple[float, float], cuts: list[tuple[float, float]], min_m: float = 0.01) -> list:
    """The pieces of the interval `span` outside every interval of `cuts` (pieces under min_m dropped)."""
    pieces = [span]
    for c0, c1 in sorted((min(c), max(c)) for c in cuts):
        nxt = []
        for p0, p1 in pieces:
            if c1 <= p0 or c0 >= p1:
                nxt.append((p0, p1))
                continue
            if c0 > p0:
                nxt.append((p0, c0))
            if c1 < p1:
                nxt.append((c1, p1))
        pieces = nxt
    return [(float(a), float(b)) for a, b in pieces if b - a >= min_m]


def standing_pieces(floor: Floor, wall: Wall) -> list[tuple[float, float]]:
    """The stretches of a plan wall that stand: its length minus the removed pieces and its doors."""
    if wall.status == "demolished":
        return []
    cuts = []
    if wall.wall_id is not None:
        cuts += [
            (wall.along(c.segment[:2]), wall.along(c.segment[2:])) for c in floor.removed_on(wall.wall_id)
        ]
        cuts += [(wall.along(d.segment[:2]), wall.along(d.segment[2:])) for d in floor.doors_on(wall.wall_id)]
    return subtract((0.0, wall.length_m), cuts)


def pair_added(
    segments: NDArray[np.float64],
    rooms: list[str],
    polygons: dict[str, Any],
    centrelines: NDArray[np.float64],
    thickness: NDArray[np.float64],
    cfg: DeliverConfig,
) -> list[tuple[NDArray[np.float64], float]]:
    """Added walls as (centreline, thickness) from the added faces: two parallel overlapping faces within
    pair_gap_m are one wall between them; a face on a plan wall's line (a closed door) takes that wall's
    line and thickness; any other lone face is a wall of added_thickness_m behind it (away from its room)."""
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    used = np.zeros(len(segs), dtype=bool)
    out: list[tuple[NDArray[np.float64], float]] = []
    for i, a in enumerate(segs):
        if used[i]:
            continue
        u = (a[2:] - a[:2]) / max(float(np.hypot(*(a[2:] - a[:2]))), 1e-12)
        n = np.array([-u[1], u[0]])
        best, best_gap = None, np.inf
        for j in range(i + 1, len(segs)):
            b = segs[j]
            if used[j]:
                continue
            ub = (b[2:] - b[:2]) / max(float(np.hypot(*(b[2:] - b[:2]))), 1e-12)
            if abs(float(u @ ub)) < 0.98:
                continue
            gap = abs(float((0.5 * (b[:2] + b[2:]) - a[:2]) @ n))
            sb = sorted([float((b[:2] - a[:2]) @ u), float((b[2:] - a[:2]) @ u)])
            overlap = min(float(np.hypot(*(a[2:] - a[:2]))), sb[1]) - max(0.0, sb[0])
            if 0.005 < gap <= cfg.pair_gap_m and overlap > 0 and gap < best_gap:
                best, best_gap = j, gap
        if best is not None:
            used[i] = used[best] = True
            b = segs[best]
            off = float((0.5 * (b[:2] + b[2:]) - a[:2]) @ n)
            sb = [float((b[:2] - a[:2]) @ u), float((b[2:] - a[:2]) @ u)]
            s0 = min(0.0, *sb)
            s1 = max(float(np.hypot(*(a[2:] - a[:2]))), *sb)
            base = a[:2] + 0.5 * off * n
            out.append((np.r_[base + u * s0, base + u * s1], abs(off)))
            continue
        used[i] = True
        host = host_wall(a, centrelines, thickness) if len(centrelines) else None
        if host is not None:
            c = centrelines[host]
            uc = (c[2:] - c[:2]) / max(float(np.hypot(*(c[2:] - c[:2]))), 1e-12)
            seg = np.r_[c[:2] + uc * ((a[:2] - c[:2]) @ uc), c[:2] + uc * ((a[2:] - c[:2]) @ uc)]
            out.append((seg, float(thickness[host])))
            continue
        t = cfg.added_thickness_m
        mid = 0.5 * (a[:2] + a[2:])
        poly = polygons.get(rooms[i])
        side = 1.0
        if poly is not None and poly.contains(shapely.Point(*(mid + 0.05 * n))):
            side = -1.0  # the room is on the normal's side: the wall lies behind, on the other
        out.append((a + np.r_[side * 0.5 * t * n, side * 0.5 * t * n], t))
    return out


# -------------------------------------------------------------------------------------------- reading


def _segment(feat: dict[str, Any]) -> NDArray[np.float64]:
    c = feat["geometry"]["coordinates"]
    return np.array([c[0][0], c[0][1], c[-1][0], c[-1][1]], dtype=np.float64)


def room_heights(fuse: art.StageResult, report: dict[str, Any]) -> dict[str, float]:
    """Room id -> its height (floor to ceiling, m) from fuse's per-room walls."""
    heights = {}
    for rid in report.get("rooms", {}):
        name = f"{rid}.walls.parquet"
        if fuse.has(name):
            table = art.read_table(fuse.file(name))
            if "height" in table.column_names and table.num_rows:
                h = float(np.nanmedian(table["height"].to_numpy()))
                if np.isfinite(h) and h > 0:
                    heights[rid] = h
    return heights


def plan_labels(plan: art.StageResult) -> tuple[dict[str, str], NDArray, NDArray, NDArray]:
    """(plan room id -> printed label, plan wall centrelines, their thickness, plan doors)."""
    labels: dict[str, str] = {}
    doors = []
    data = art.read_json(plan.file("rooms.geojson"))
    for feat in data.get("features", []):
        props, geom = feat.get("properties") or {}, feat.get("geometry") or {}
        if geom.get("type") == "Polygon" and props.get("label") not in (None, ""):
            labels[str(props.get("room_id"))] = str(props["label"])
        elif geom.get("type") == "LineString" and props.get("kind") == "door":
            doors.append(_segment(feat))
    segs, table = art.read_segments(plan.file("plan_walls.parquet"))
    thick = (
        table["thickness_m"].to_numpy().astype(np.float64)
        if "thickness_m" in table.column_names
        else np.full(len(segs), 0.1)
    )
    return labels, segs, thick, np.asarray(doors, dtype=np.float64).reshape(-1, 4)


def read_floor(
    floor_geojson: Path,
    heights: dict[str, float],
    labels: dict[str, str],
    changes: list[ChangeMark],
    cfg: DeliverConfig,
) -> Floor:
    """The floor from floor.geojson, the rooms' heights, the plan's labels and the changes (their
    removed and unknown pieces not yet put on their walls)."""
    data = art.read_json(floor_geojson)
    feats = data.get("features")
    if not isinstance(feats, list):
        raise art.ArtefactError(f"{floor_geojson}: not a GeoJSON FeatureCollection (no 'features' list)")
    rooms: list[Room] = []
    default_h = float(np.median(list(heights.values()))) if heights else cfg.default_height_m
    for feat in feats:
        p = feat["properties"]
        if p.get("kind") == "room":
            rid = str(p["room_id"])
            plan_room = p.get("plan_room")
            rooms.append(
                Room(
                    rid,
                    plan_room,
                    labels.get(str(plan_room)),
                    shapely.geometry.shape(feat["geometry"]),
                    heights.get(rid, default_h),
                )
            )
    walls: list[Wall] = []
    for feat in feats:
        p = feat["properties"]
        if p.get("kind") != "wall":
            continue
        sides = tuple(p.get("rooms") or (p.get("room_left"), p.get("room_right")))
        hs = [heights[r] for r in sides if r in heights]
        thickness = float(p["thickness_m"])
        if not (np.isfinite(thickness) and thickness > 0):
            raise art.ArtefactError(f"{floor_geojson}: wall {len(walls)} has thickness {thickness!r}")
        walls.append(
            Wall(
                f"wall:{len(walls)}",
                _segment(feat),
                thickness,
                max(hs) if hs else default_h,
                "existing",
                str(p.get("origin", "plan")),
                (sides[0], sides[1]),
                len(walls),
            )
        )
    doors = []
    for feat in feats:
        p = feat["properties"]
        if p.get("kind") == "door":
            wid = p.get("wall_id")
            doors.append(
                Door(
                    f"door:{len(doors)}",
                    _segment(feat),
                    None if wid is None else int(wid),
                    str(p.get("source", "")),
                    tuple(p.get("rooms") or ()),
                )
            )
    centres = np.array([w.centreline for w in walls]).reshape(-1, 4)
    thick = np.array([w.thickness_m for w in walls])
    placed = []
    for c in changes:
        wid = host_wall(c.segment, centres, thick) if c.kind != "added" and len(walls) else None
        placed.append(ChangeMark(c.segment, c.kind, c.room_id, wid))
    for i, w in enumerate(walls):  # removed along most of its length: demolished
        gone = sum(
            abs(w.along(c.segment[2:]) - w.along(c.segment[:2]))
            for c in placed
            if c.kind == "removed" and c.wall_id == i
        )
        if gone >= 0.9 * w.length_m:
            walls[i] = Wall(
                w.key, w.centreline, w.thickness_m, w.height_m, "demolished", w.origin, w.rooms, i
            )
    added_faces = [c for c in placed if c.kind == "added"]
    polys = {r.id: r.polygon for r in rooms}
    added = []
    for k, (seg, t) in enumerate(
        pair_added(
            np.array([c.segment for c in added_faces]).reshape(-1, 4),
            [c.room_id for c in added_faces],
            polys,
            centres,
            thick,
            cfg,
        )
    ):
        near = [r.id for r in rooms if r.polygon.buffer(t).intersects(shapely.LineString(seg.reshape(2, 2)))]
        hs = [heights[r] for r in near if r in heights]
        added.append(
            Wall(f"added:{k}", seg, t, max(hs) if hs else default_h, "added", "observed", (None, None))
        )
    return Floor(walls, added, doors, rooms, placed)


def read_changes(path: Path) -> list[ChangeMark]:
    table = art.read_table(path).to_pydict()
    need = {"x0", "y0", "x1", "y1", "kind", "room_id"}
    if not need <= set(table):
        raise art.ArtefactError(f"{path}: changes table lacks columns {sorted(need - set(table))}")
    return [
        ChangeMark(np.array([x0, y0, x1, y1], dtype=np.float64), str(k), str(r or ""))
        for x0, y0, x1, y1, k, r in zip(
            table["x0"], table["y0"], table["x1"], table["y1"], table["kind"], table["room_id"], strict=True
        )
    ]
