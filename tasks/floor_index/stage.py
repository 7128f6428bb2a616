"""outputs/rooms.parquet: per survey room, which stages are done, the wall model's size and closure, the
room's floor area and the frame its walls are in; rooms without a result carry their one-line reason."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyarrow as pa

from tasks import artefacts as art
from tasks.context import StageContext
from tasks.floor_index.config import FloorIndexConfig

ROOMS_SCHEMA = pa.schema(
    [
        ("room_id", pa.string()),
        ("plan_room", pa.string()),
        ("stages_done", pa.list_(pa.string())),
        ("walls", pa.int32()),
        ("closed", pa.bool_()),
        ("area_m2", pa.float64()),
        ("frame", pa.string()),
        ("error", pa.string()),
    ]
)


def room_row(room: dict[str, Any], results: dict[str, art.StageResult], error: str | None) -> dict[str, Any]:
    """One room's row from its stage results (the walls stage's manifest and room polygon)."""
    row: dict[str, Any] = {
        "room_id": room["id"],
        "plan_room": room.get("plan_room"),
        "stages_done": list(results),
        "walls": None,
        "closed": None,
        "area_m2": None,
        "frame": None,
        "error": error,
    }
    walls = results.get("walls")
    if walls is not None:
        manifest = walls.manifest
        metrics = manifest.get("metrics", {})
        row.update(walls=metrics.get("walls"), closed=metrics.get("closed"), frame=manifest.get("frame"))
        features = art.read_json(walls.file("plan.geojson")).get("features", [])
        areas = [f["properties"].get("area_m2") for f in features if f["properties"].get("kind") == "room"]
        row["area_m2"] = float(areas[0]) if areas else None
    return row


def run(ctx: StageContext, cfg: FloorIndexConfig, out: Path) -> dict[str, Any]:
    rows = []
    for room in ctx.params["rooms"]:
        results = ctx.rooms.get(room["id"], {})
        error = ctx.failed_rooms.get(room["id"])
        if results or cfg.include_failed:
            rows.append(room_row(room, results, error))
    columns = {name: [row[name] for row in rows] for name in ROOMS_SCHEMA.names}
    art.write_table(out / "rooms.parquet", columns, ROOMS_SCHEMA)
    closed = sum(bool(row["closed"]) for row in rows)
    return {
        "metrics": {
            "rooms": len(rows),
            "with_walls": sum(row["walls"] is not None for row in rows),
            "closed": closed,
            "failed": sorted(ctx.failed_rooms),
        }
    }
