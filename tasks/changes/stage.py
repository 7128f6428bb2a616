"""The changes stage (building, after fuse): read the fused rooms and the plan, detect the changes
(tasks.changes.detect), write changes.parquet, changes.geojson and the overlay changes.png."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import shapely.geometry

from tasks import artefacts as art
from tasks.changes.config import ChangesConfig
from tasks.changes.detect import Change, PlacedRoom, RoomChange, added_walls, removed_walls, room_changes
from tasks.changes.overlay import overlay_png
from tasks.context import StageContext
from tasks.fuse.openings import Coverage
from tasks.fuse.register2d import Placement
from tasks.fuse.stage import read_plan

CHANGES_EVIDENCE_SCHEMA = pa.schema(
    [*art.CHANGES_SCHEMA, ("support", pa.float64()), ("distance_m", pa.float64())]
)
"""changes.parquet: the deliverable's columns plus the evidence (support share, distance)."""


def placed_rooms(fuse: art.StageResult) -> tuple[list[PlacedRoom], dict[str, str]]:
    """The placed rooms from fuse's files (walls in the plan frame, doors, coverage, surfaces), and the plan
    room of every room."""
    report = art.read_json(fuse.file("fuse.json"))
    rooms, plan_of = [], {}
    for rid, rep in report["rooms"].items():
        plan_of[rid] = rep.get("plan_room")
        if not rep.get("placed"):
            continue
        segs, table = art.read_segments(fuse.file(f"{rid}.walls.parquet"))
        origin = np.asarray(table["origin"].to_pylist(), dtype=str)
        keep = origin != "gap_filled"
        placement = Placement(np.radians(rep["theta_deg"]), tuple(rep["t_m"]))
        cov = _grid(fuse, rid, rep, "coverage", placement)
        standing = _grid(fuse, rid, rep, "surfaces", placement)
        top = _grid(fuse, rid, rep, "tops", placement)
        poly = None
        data = art.read_json(fuse.file(f"{rid}.plan.geojson"))
        for feat in data["features"]:
            if feat["properties"].get("kind") == "room":
                poly = shapely.geometry.shape(feat["geometry"])
        rooms.append(
            PlacedRoom(
                rid,
                segs[keep],
                table["support"].to_numpy()[keep],
                np.asarray(rep.get("doors", []), dtype=np.float64).reshape(-1, 4),
                cov,
                rep.get("plan_room"),
                poly,
                tuple(rep.get("closed_plan_doors", [])),
                standing,
                rep["surfaces"]["crisp"] if "surfaces" in rep else None,
                top,
            )
        )
    return rooms, plan_of


def _grid(fuse: art.StageResult, rid: str, rep: dict, name: str, placement: Placement):
    """A room's coverage, surfaces or tops grid (fuse's <room>.<name>.png), looked up from the plan frame."""
    if name not in rep or not fuse.has(f"{rid}.{name}.png"):
        return None
    seen = art.read_image(fuse.file(f"{rid}.{name}.png"), unchanged=True) > 0
    return Coverage(tuple(rep[name]["origin"]), rep[name]["cell_m"], seen).moved(placement)


def detect_all(
    rooms: list[PlacedRoom],
    centrelines: np.ndarray,
    thickness: np.ndarray,
    doors: np.ndarray,
    plan_polys: dict,
    cfg: ChangesConfig,
    evidence: dict[str, dict[int, list[tuple[float, float]]]] | None = None,
) -> tuple[list[Change], list[RoomChange]]:
    """Every wall-level and room-level change (`evidence`: fuse's "standing" and "seen_through" stretches
    of the plan's walls, tasks.fuse.floor.wall_evidence)."""
    changes: list[Change] = []
    polys = list(plan_polys.values())
    for room in rooms:
        own = room.polygon if room.polygon is not None else plan_polys.get(room.plan_room)
        changes += added_walls(room, centrelines, thickness, doors, cfg, polys, own)
    evidence = evidence or {}
    changes += removed_walls(
        centrelines,
        thickness,
        rooms,
        cfg,
        standing=evidence.get("standing"),
        seen_through=evidence.get("seen_through"),
    )
    return changes, room_changes(rooms, plan_polys, cfg)


def run(ctx: StageContext, cfg: ChangesConfig, out: Path) -> dict[str, Any]:
    """Detect and write the changes (module doc)."""
    fuse = ctx.upstream["fuse"]
    plan_rooms, centrelines, _, doors = read_plan(ctx.upstream["plan"])
    _, thick_table = art.read_segments(fuse.file("thickness.parquet"))
    thickness = thick_table["thickness_m"].to_numpy().astype(np.float64)
    rooms, _ = placed_rooms(fuse)
    plan_polys = {p.id: p.polygon for p in plan_rooms}
    report = art.read_json(fuse.file("fuse.json"))
    evidence = {
        key: {int(i): [tuple(r) for r in runs] for i, runs in report[key].items()}
        for key in ("standing", "seen_through")
        if key in report
    }
    changes, room_level = detect_all(rooms, centrelines, thickness, doors, plan_polys, cfg, evidence)
    return write_outputs(changes, room_level, plan_polys, centrelines, thickness, out)


def write_outputs(
    changes: list[Change],
    room_level: list[RoomChange],
    plan_polys: dict,
    centrelines: np.ndarray,
    thickness: np.ndarray,
    out: Path,
) -> dict[str, Any]:
    cols = ("x0", "y0", "x1", "y1", "kind", "room_id", "support", "distance_m")
    table = {c: [getattr(ch, c) for ch in changes] for c in cols}
    art.write_table(out / "changes.parquet", table, CHANGES_EVIDENCE_SCHEMA)
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [[c.x0, c.y0], [c.x1, c.y1]]},
            "properties": {
                "level": "wall",
                "kind": c.kind,
                "room_id": c.room_id,
                "support": c.support,
                "distance_m": c.distance_m if np.isfinite(c.distance_m) else None,
            },
        }
        for c in changes
    ]
    feats += [
        {
            "type": "Feature",
            "geometry": shapely.geometry.mapping(r.polygon),
            "properties": {
                "level": "room",
                "kind": r.kind,
                "room_ids": list(r.room_ids),
                "plan_rooms": list(r.plan_rooms),
                "share": r.share,
            },
        }
        for r in room_level
    ]
    art.write_geojson(out / "changes.geojson", feats, "plan frame (m)")
    art.write_png(out / "changes.png", overlay_png(centrelines, thickness, plan_polys, changes, room_level))
    kinds = [c.kind for c in changes]
    return {
        "frame": "plan frame (m)",
        "metrics": {
            "added": kinds.count("added"),
            "removed": kinds.count("removed"),
            "unknown": kinds.count("unknown"),
            "room_changes": [
                {"kind": r.kind, "rooms": list(r.room_ids), "plan_rooms": list(r.plan_rooms)}
                for r in room_level
            ],
        },
    }
