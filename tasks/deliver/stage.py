"""The deliver stage (building, after fuse and changes): the fused floor as the files a surveyor's
clients open, and every room's cloud in the floor frame.

Outputs (published to outputs/):
- floor.dxf (tasks.deliver.dxf), floor.ifc (tasks.deliver.ifc), floor.ply (tasks.deliver.mesh);
- floor.prj: the plan frame as a local engineering CRS (WKT), the sidecar of fuse's floor.geojson;
- <room>.cloud.ply -> outputs/rooms/<room>/cloud.ply (tasks.deliver.clouds).
Every file is in the plan frame (metres, x right, y up), z = 0 on the floor.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tasks import artefacts as art
from tasks.context import StageContext
from tasks.deliver import clouds, dxf, ifc, mesh
from tasks.deliver.config import DeliverConfig
from tasks.deliver.floor import ChangeMark, Floor, plan_labels, read_changes, read_floor, room_heights
from tasks.fuse.stage import PLAN_CRS_WKT


def load_floor(
    fuse: art.StageResult, plan: art.StageResult, changes: art.StageResult | None, cfg: DeliverConfig
) -> Floor:
    """The floor the deliverables draw (tasks.deliver.floor) from the stages' files."""
    report = art.read_json(fuse.file("fuse.json"))
    labels, plan_walls, plan_thick, plan_doors = plan_labels(plan)
    marks: list[ChangeMark] = []
    if changes is not None and changes.has("changes.parquet"):
        marks = read_changes(changes.file("changes.parquet"))
    floor = read_floor(fuse.file("floor.geojson"), room_heights(fuse, report), labels, marks, cfg)
    floor.plan_walls, floor.plan_thickness_m, floor.plan_doors = plan_walls, plan_thick, plan_doors
    return floor


def write_room_clouds(
    ctx: StageContext, report: dict[str, Any], cfg: DeliverConfig, out: Path
) -> dict[str, dict[str, Any]]:
    """<room>.cloud.ply for every room with a levelled cloud; per room its frame and point counts."""
    found: dict[str, dict[str, Any]] = {}
    for rid in sorted(ctx.rooms):
        pre = ctx.rooms[rid].get("preprocess")
        if pre is None or not (pre.has("levelled.ply") and pre.has("levelling.json")):
            continue
        rep = report.get("rooms", {}).get(rid, {})
        placement = np.asarray(rep["matrix"]) if rep.get("placed") and "matrix" in rep else None
        reason = rep.get("reason") or ("fuse has no result for it" if not rep else "")
        cloud = clouds.room_cloud(
            pre.file("levelled.ply"), art.read_json(pre.file("levelling.json")), placement, reason
        )
        points, colors = clouds.voxel_reduce(cloud.points, cloud.colors, cfg.cloud_voxel_m)
        clouds.write_cloud(out / f"{rid}.cloud.ply", points, colors)
        found[rid] = {
            "frame": cloud.frame,
            "points_in": len(cloud.points),
            "points_out": len(points),
            "floor_z_p01_m": round(float(np.percentile(points[:, 2], 1)), 4),
        }
    return found


def run(ctx: StageContext, cfg: DeliverConfig, out: Path) -> dict[str, Any]:
    """Write the deliverables (module doc)."""
    fuse, plan = ctx.upstream["fuse"], ctx.upstream["plan"]
    floor = load_floor(fuse, plan, ctx.upstream.get("changes"), cfg)
    ctx.progress(
        f"{len(floor.walls)} walls, {len(floor.added)} added, {len(floor.doors)} doors, {len(floor.rooms)} rooms"
    )
    (out / "floor.prj").write_text(PLAN_CRS_WKT)
    dxf_counts = dxf.write(floor, out / "floor.dxf")
    ifc_counts = ifc.write(floor, out / "floor.ifc", cfg.timestamp, cfg.door_height_m)
    mesh_counts = mesh.write(floor, out / "floor.ply", cfg.slab_thickness_m, cfg.door_height_m)
    room_clouds = write_room_clouds(ctx, art.read_json(fuse.file("fuse.json")), cfg, out)
    metrics = {
        "dxf_entities": dxf_counts,
        "ifc": ifc_counts,
        "mesh": mesh_counts,
        "walls": len(floor.walls),
        "walls_demolished": sum(w.status == "demolished" for w in floor.walls),
        "walls_added": len(floor.added),
        "doors": len(floor.doors),
        "doors_without_wall": sum(d.wall_id is None for d in floor.doors),
        "rooms": len(floor.rooms),
        "cloud_voxel_m": cfg.cloud_voxel_m,
        "room_clouds": room_clouds,
        "rooms_without_cloud": {
            **{rid: "no levelled cloud" for rid in ctx.rooms if rid not in room_clouds},
            **ctx.failed_rooms,
        },
        "changes_read": "changes" in ctx.upstream,
    }
    return {"frame": "plan frame (m), z = 0 on the floor", "metrics": metrics}
