"""The preprocess stage: the room's registered cloud (from registration, or given with the capture) in; the
levelled cloud, the furniture slice, the height histogram and the levelling out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tasks import artefacts as art
from tasks.context import StageContext
from tasks.preprocess.config import PreprocessConfig
from tasks.preprocess.pipeline import preprocess


def room_cloud(ctx: StageContext) -> tuple[art.Cloud, str]:
    """The room's registered cloud and where it came from: "register" (frames placed by this pipeline,
    in an arbitrary room frame) or "capture" (a cloud given in its own, meaningful frame)."""
    for stage, source in (("register", "register"), ("ingest", "capture")):
        result = ctx.upstream.get(stage)
        if result is not None and result.has("cloud.ply"):
            return art.read_cloud(result.file("cloud.ply")), source
    raise art.ArtefactError(f"room {ctx.room}: no registered cloud to preprocess (capture has frames only)")


def run(ctx: StageContext, cfg: PreprocessConfig, out: Path) -> dict[str, Any]:
    """The room's levelled cloud and furniture slice, the height histogram (table and picture) and the
    levelling (transform, floor, ceiling and whether it was captured, pivot, where the cloud came from)."""
    cloud, source = room_cloud(ctx)
    result = preprocess(cloud, cfg)
    art.write_cloud(out / "levelled.ply", result.cloud)
    art.write_cloud(out / "slice.ply", result.slice)
    art.write_png(out / "height_histogram.png", result.histogram_png)
    edges, counts = result.histogram
    art.write_table(
        out / "height_histogram.parquet", {"z_low_m": edges[:-1], "z_high_m": edges[1:], "count": counts}
    )
    art.write_json(
        out / "levelling.json",
        {
            "transform": np.asarray(result.levelling).tolist(),
            "floor_z_m": result.floor_z_m,
            "ceiling_z_m": result.ceiling_z_m,
            "height_m": result.height_m,
            "ceiling_captured": bool(result.metrics["ceiling_captured"]),
            "pivot_m": result.metrics.get("levelling_pivot_m"),
            "source": source,
        },
    )
    return {"metrics": result.metrics}
