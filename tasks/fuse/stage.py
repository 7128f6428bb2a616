"""The fuse stage (building, after every room): load each finished room's walls, cloud and track times and
the parsed plan, place and fuse them (tasks.fuse.floor), write the fused floor.

Outputs (its own folder; the publish step copies them):
- floor.geojson: placed rooms, their walls (inner faces, origin), plan walls with fused thickness and the
  rooms on each side, doors;
- thickness.parquet: per plan wall, the fused thickness and its source, the thesis' residual figure and the
  distance between the rooms' model lines (tasks.fuse.thickness: the comparison);
- fuse.json: per room, the correspondence and its source, the transform, residuals and fit score, or
  why the room was not placed; whether it closed; per plan wall, the stretches crisp captures show
  standing or seen through (the changes stage);
- <room>.walls.parquet and <room>.plan.geojson: the room's walls in the plan frame when placed (its own
  frame otherwise, and the file says so): what outputs/rooms/<room>/ should hold after fusion;
- <room>.coverage.png: where the capture saw floor or ceiling (room frame; fuse.json has its grid);
- <room>.surfaces.png: where its cloud shows something standing, 0.15-1.9 m (room frame, 5 cm cells;
  fuse.json has its grid, and whether the capture's faces are crisp enough to tell an opening);
- <room>.tops.png: where its cloud shows something just below the ceiling (top_band_m; room frame, 5 cm
  cells; fuse.json has its grid): what reaches the ceiling, as a wall does and furniture does not.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import shapely.geometry
from shapely.geometry import shape

from tasks import artefacts as art
from tasks.context import StageContext
from tasks.fuse.config import FuseConfig
from tasks.fuse.correspond import PlanRoom
from tasks.fuse.floor import FusedFloor, FusedRoom, floor_features, fuse_floor
from tasks.fuse.place import RoomInput

PLAN_FRAME = "plan frame (m)"
PLAN_CRS_WKT = (
    'LOCAL_CS["indoor-survey plan frame",'
    'LOCAL_DATUM["plan raster: x right, y up, metres",32767],'
    'UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
    'AXIS["X",EAST],AXIS["Y",NORTH]]'
)
"""The plan frame as a local engineering CRS (WKT 1, what floor.prj holds): metres, x right and y up on the
plan raster, not georeferenced (GeoJSON's default WGS84 would read the metres as degrees)."""
PLAN_CRS = {"type": "name", "properties": {"name": PLAN_CRS_WKT}}
"""The GeoJSON (2008) "crs" member naming PLAN_CRS_WKT, which GDAL and QGIS read."""


def write_plan_geojson(path: Path, features: list[dict[str, Any]]) -> Path:
    """A FeatureCollection in the plan frame: the "crs" member (PLAN_CRS) and the frame note."""
    return art.write_json(
        path, {"type": "FeatureCollection", "crs": PLAN_CRS, "frame": PLAN_FRAME, "features": features}
    )


def read_plan(plan: art.StageResult) -> tuple[list[PlanRoom], np.ndarray, np.ndarray, np.ndarray]:
    """(plan rooms, centrelines (M, 4), thickness (M,), doors (D, 4)) from the plan stage's files."""
    segments, table = art.read_segments(plan.file("plan_walls.parquet"))
    thickness = (
        table["thickness_m"].to_numpy().astype(np.float64)
        if "thickness_m" in table.column_names
        else np.full(len(segments), np.nan)
    )
    data = art.read_json(plan.file("rooms.geojson"))
    rooms, doors = [], []
    for n, feat in enumerate(data.get("features", [])):
        geom, props = feat.get("geometry") or {}, feat.get("properties") or {}
        if geom.get("type") == "Polygon":
            label = props.get("label")
            rooms.append(
                PlanRoom(
                    str(props.get("room_id", f"R{n + 1}")),
                    None if label in (None, "") else str(label),
                    shape(geom),
                )
            )
        elif geom.get("type") == "LineString" and props.get("kind") == "door":
            c = geom["coordinates"]
            doors.append([*c[0][:2], *c[-1][:2]])
    return rooms, segments, thickness, np.asarray(doors, dtype=np.float64).reshape(-1, 4)


def load_room(room_id: str, results: dict[str, art.StageResult], plan_room: str | None) -> RoomInput:
    """A finished room's walls, cloud (in the walls' frame), floor and ceiling, camera times and positions."""
    walls_res = results["walls"]
    segs, table = art.read_segments(walls_res.file("walls.parquet"))
    cols = table.column_names
    origin = np.asarray(
        table["origin"].to_pylist() if "origin" in cols else ["observed"] * len(segs), dtype=str
    )
    support = table["support"].to_numpy().astype(np.float64) if "support" in cols else np.ones(len(segs))
    height = float(np.nanmedian(table["height"].to_numpy())) if "height" in cols and len(segs) else 2.5
    points, floor_z, ceiling_z, back = None, 0.0, height, np.eye(4)
    pre = results.get("preprocess")
    if pre is not None and pre.has("levelling.json"):
        lev = art.read_json(pre.file("levelling.json"))
        if lev.get("source") != "register":  # walls went back into the given cloud's frame (tasks/walls)
            back = np.linalg.inv(np.asarray(lev["transform"], dtype=np.float64))
        floor_z = float(lev["floor_z_m"]) + back[2, 3]
        ceiling_z = float(lev["ceiling_z_m"]) + back[2, 3]
        if pre.has("levelled.ply"):
            pts = art.read_cloud(pre.file("levelled.ply")).points
            points = pts @ back[:3, :3].T + back[:3, 3]
    in_plan, camera = False, None
    reg = results.get("register")
    if reg is not None:
        metrics = reg.manifest.get("metrics", {})
        in_plan = metrics.get("frame") == "plan"
        if reg.has("poses.parquet"):
            camera = _camera_txy(reg.file("poses.parquet"), pre)
    return RoomInput(
        room_id, segs, origin, support, height, in_plan, plan_room, points, floor_z, ceiling_z, camera
    )


def _camera_txy(poses: Path, pre: art.StageResult | None) -> np.ndarray:
    """(K, 3) t_ns, x, y of the camera in the levelled frame (where registered rooms' walls are)."""
    table = art.read_table(poses).to_pydict()
    xyz = np.column_stack([table["tx"], table["ty"], table["tz"]]).astype(np.float64)
    if pre is not None and pre.has("levelling.json"):
        tr = np.asarray(art.read_json(pre.file("levelling.json"))["transform"], dtype=np.float64)
        xyz = xyz @ tr[:3, :3].T + tr[:3, 3]
    t = np.asarray(table["t_ns"], dtype=np.float64)
    ok = np.isfinite(xyz).all(axis=1)
    return np.column_stack([t[ok], xyz[ok, 0], xyz[ok, 1]])


def run(ctx: StageContext, cfg: FuseConfig, out: Path) -> dict[str, Any]:
    """Place and fuse every finished room (see the module doc)."""
    plan_rooms, centrelines, thickness, doors = read_plan(ctx.upstream["plan"])
    labels = {str(r["id"]): r.get("plan_room") for r in ctx.params.get("rooms", [])}
    rooms = []
    for rid in sorted(ctx.rooms):
        try:
            rooms.append(load_room(rid, ctx.rooms[rid], labels.get(rid)))
        except (art.ArtefactError, KeyError, ValueError) as exc:
            ctx.progress(f"room {rid}: cannot be read ({exc}); the others still fuse")
    track = art.read_track(Path(ctx.raw_inputs["track"])) if "track" in ctx.raw_inputs else None
    ctx.progress(f"fusing {len(rooms)} rooms into {len(plan_rooms)} plan rooms")
    floor = fuse_floor(rooms, plan_rooms, centrelines, thickness, doors, track, cfg)
    return write_outputs(floor, rooms, ctx.failed_rooms, out, cfg)


def write_outputs(
    floor: FusedFloor, rooms: list[RoomInput], failed: dict[str, str], out: Path, cfg: FuseConfig
) -> dict[str, Any]:
    """Write the stage's files (module doc) and return its manifest entries."""
    write_plan_geojson(out / "floor.geojson", floor_features(floor))
    t, r = floor.thickness, floor.thickness_residuals
    art.write_table(
        out / "thickness.parquet",
        art.segments_table(
            floor.centrelines,
            thickness_m=t.thickness_m,
            source=t.source.tolist(),
            thickness_residuals_m=r.thickness_m,
            source_residuals=r.source.tolist(),
            thickness_lines_m=floor.thickness_lines.thickness_m,
            room_left=[s[0] or "" for s in t.sides],
            room_right=[s[1] or "" for s in t.sides],
        ),
    )
    report: dict[str, Any] = {"rooms": {}, "failed_rooms": dict(failed)}
    by_id = {r.id: r for r in rooms}
    for rid, f in floor.rooms.items():
        report["rooms"][rid] = _room_report(f)
        _write_room(out, rid, f, by_id[rid])
        model = floor.models.get(rid)
        if model is not None and model.coverage is not None:
            art.write_png(out / f"{rid}.coverage.png", model.coverage.seen.astype(np.uint8) * 255)
            report["rooms"][rid]["coverage"] = {
                "origin": model.coverage.origin,
                "cell_m": model.coverage.cell_m,
            }
        if model is not None and model.surfaces is not None:
            art.write_png(out / f"{rid}.surfaces.png", model.surfaces.seen.astype(np.uint8) * 255)
            report["rooms"][rid]["surfaces"] = {
                "origin": model.surfaces.origin,
                "cell_m": model.surfaces.cell_m,
                "face_spread_m": model.face_spread_m if math.isfinite(model.face_spread_m) else None,
                "crisp": bool(model.face_spread_m <= cfg.crisp_face_m),
            }
        if model is not None and model.tops is not None:
            art.write_png(out / f"{rid}.tops.png", model.tops.seen.astype(np.uint8) * 255)
            report["rooms"][rid]["tops"] = {"origin": model.tops.origin, "cell_m": model.tops.cell_m}
    if floor.evidence is not None:
        report["standing"] = {str(i): runs for i, runs in floor.evidence.standing.items()}
        report["seen_through"] = {str(i): runs for i, runs in floor.evidence.seen_through.items()}
    art.write_json(out / "fuse.json", report)
    placed = [rid for rid, f in floor.rooms.items() if f.in_plan]
    metrics = {
        "rooms": len(floor.rooms),
        "placed": len(placed),
        "closed": sum(1 for f in floor.rooms.values() if f.gaps is not None and f.gaps.closed),
        "sources": {rid: f.placed.correspondence.source for rid, f in floor.rooms.items()},
        "fit_scores": {rid: round(f.placed.fit.score, 4) for rid, f in floor.rooms.items() if f.placed.fit},
        "not_placed": {rid: f.placed.reason for rid, f in floor.rooms.items() if not f.in_plan},
        "thickness_sources": {s: int((t.source == s).sum()) for s in ("measured", "plan", "default")},
    }
    return {"frame": PLAN_FRAME, "metrics": metrics}


def _room_report(f: FusedRoom) -> dict[str, Any]:
    p = f.placed
    rep: dict[str, Any] = {
        "plan_room": p.correspondence.plan_room,
        "source": p.correspondence.source,
        "notes": list(p.correspondence.notes),
        "placed": f.in_plan,
        "reason": p.reason,
        "start": p.start,
        "ambiguous_turn": p.ambiguous,
    }
    if p.fit is not None:
        rep.update(
            fit_score=p.fit.score,
            rms_m=p.fit.rms_m,
            residuals_m=[None if not math.isfinite(v) else v for v in p.fit.residual_m.tolist()],
            angle_residuals_deg=[
                None if not math.isfinite(v) else v for v in p.fit.angle_residual_deg.tolist()
            ],
            iterations=p.fit.iterations,
            converged=p.fit.converged,
            doors_used=p.fit.doors_used,
        )
    if p.placement is not None:
        rep.update(
            theta_deg=math.degrees(p.placement.theta), t_m=list(p.placement.t), matrix=p.placement.matrix()
        )
    if f.gaps is not None:
        rep.update(closed=f.gaps.closed, open_reason=f.gaps.reason, gap_filled=len(f.gaps.walls))
    rep["doors"] = f.doors.tolist()
    rep["doors_contradicted"] = f.doors_contradicted.tolist()
    rep["closed_plan_doors"] = list(f.closed_plan_doors)
    return rep


def _write_room(out: Path, rid: str, f: FusedRoom, room: RoomInput) -> None:
    frame = PLAN_FRAME if f.in_plan else f"own room frame (not placed: {f.placed.reason})"
    art.write_table(
        out / f"{rid}.walls.parquet",
        art.segments_table(
            f.walls, height=np.full(len(f.walls), f.height_m), origin=f.origin.tolist(), support=f.support
        ),
        art.WALLS_SCHEMA,
    )
    feats = [
        {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [[w[0], w[1]], [w[2], w[3]]]},
            "properties": {"room_id": rid, "kind": "wall", "origin": str(o), "support": float(s)},
        }
        for w, o, s in zip(f.walls.tolist(), f.origin, f.support, strict=True)
    ]
    poly = f.gaps.polygon if f.gaps is not None else None
    if poly is not None:
        feats.append(
            {
                "type": "Feature",
                "geometry": shapely.geometry.mapping(poly),
                "properties": {"room_id": rid, "kind": "room", "area_m2": float(poly.area)},
            }
        )
    if f.in_plan:
        write_plan_geojson(out / f"{rid}.plan.geojson", feats)
    else:
        art.write_geojson(out / f"{rid}.plan.geojson", feats, frame)
