"""The plan stage: the survey's plan image and scale in; the plan's walls (centrelines and thickness), rooms
and doors, and a preview picture out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import shapely.geometry

from tasks import artefacts
from tasks.context import StageContext
from tasks.plan.config import PlanConfig, PlanScale
from tasks.plan.labels import read_room_labels
from tasks.plan.parse import parse_plan
from tasks.plan.raster import load_plan_image


def run(ctx: StageContext, cfg: PlanConfig, out: Path) -> dict[str, Any]:
    """The coarse plan raster as metric walls (centrelines + thickness) and rooms (thesis 4.2.3)."""
    known = ctx.params.get("known_distance")
    scale = PlanScale(
        m_per_px=ctx.params.get("m_per_px"),
        known_distance=tuple(known) if known else None,
        outline_length_m=ctx.params.get("outline_length_m"),
    )
    return {"metrics": write_parsed_plan(Path(ctx.raw_inputs["plan"]), out, scale, cfg)}


def write_parsed_plan(image_path: Path, out_dir: Path, scale: PlanScale, cfg: PlanConfig) -> dict[str, Any]:
    """Parse the image and write plan_walls.parquet, rooms.geojson and plan_preview.png into `out_dir`;
    returns the metrics."""
    if not image_path.is_file():
        raise ValueError(f"{image_path}: no such image file")
    image = load_plan_image(image_path)
    res = parse_plan(image, scale, cfg, name=str(image_path))
    artefacts.write_table(
        out_dir / "plan_walls.parquet", artefacts.segments_table(res.walls, thickness_m=res.thickness_m)
    )
    polygons = [poly for poly, _ in res.rooms]
    if scale.corners_px is None:  # the printed room numbers, read where the rooms lie on the input image
        printed = read_room_labels(image, polygons, res.m_per_px)
    else:  # a rectified photo: the polygons are not on the input image's pixels
        printed = [None] * len(polygons)
    features = [
        {
            "type": "Feature",
            "geometry": shapely.geometry.mapping(poly),
            "properties": {"room_id": f"R{n + 1}", "label": label or text, "area_m2": float(poly.area)},
        }
        for n, ((poly, label), text) in enumerate(zip(res.rooms, printed, strict=True))
    ]
    features += [
        {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [d[:2].tolist(), d[2:].tolist()]},
            "properties": {"kind": "door"},
        }
        for d in res.doors
    ]
    artefacts.write_geojson(out_dir / "rooms.geojson", features, crs_note="plan frame, metres")
    artefacts.write_png(out_dir / "plan_preview.png", res.preview)
    return {**res.metrics, "labels_read": sum(t is not None for t in printed)}
