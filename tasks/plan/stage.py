"""The plan stage: the survey's plan image and scale in; the plan's walls (centrelines and thickness), rooms
and doors, and a preview picture out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import shapely.geometry
from numpy.typing import NDArray

from tasks import artefacts
from tasks.context import StageContext
from tasks.plan.config import PlanConfig, PlanScale
from tasks.plan.labels import read_room_labels
from tasks.plan.parse import parse_plan
from tasks.plan.raster import load_plan_image
from tasks.preview import Key, View, frame_picture


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
    artefacts.write_png(
        out_dir / "plan_preview.png", framed_preview(res.preview, res.metrics, image_path.name)
    )
    return {**res.metrics, "labels_read": sum(t is not None for t in printed)}


def framed_preview(preview: NDArray[np.uint8], metrics: dict[str, Any], name: str) -> NDArray[np.uint8]:
    """The parse's picture in the plan frame's metres, with a title, axes, a 1 m bar, a north arrow (plan
    up) and the keys of its marks (the wall thickness scale is drawn inside it). A working pixel c spans
    x = (c f - 1/2 .. c f + f - 1/2) s for the downsampling f and the plan's scale s."""
    s, sp = float(metrics["m_per_px"]), float(metrics["working_m_per_px"])
    view = View(x0_m=-s / 2, y_top_m=s / 2, m_per_px=sp)
    keys = [
        Key("wall raster", (200, 200, 200), "box"),
        Key("door", (200, 0, 200)),
        Key("plan region", (255, 120, 0), "dash"),
    ]
    return frame_picture(preview, view, f"plan {name}: walls by thickness, rooms, doors", keys)
