"""The register stage's entry: the room's ingested frames (and the survey's calibration, IMU track and plan
walls when there are) → poses.parquet, cloud.ply and scale.json."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from tasks import artefacts as art
from tasks.camera import Calibration
from tasks.context import StageContext
from tasks.register.config import RegisterConfig
from tasks.register.room import register_room


def run(ctx: StageContext, cfg: RegisterConfig, out: Path) -> dict[str, Any]:
    """SfM -> metric scale -> fused coloured cloud, or the track-based fallback (thesis 3.2)."""
    ingest = ctx.upstream["ingest"]
    camera_info = art.read_json(ingest.file("camera_info.json"))
    calibration = None
    if "calibrate" in ctx.upstream:
        calibration = Calibration.from_json(art.read_json(ctx.upstream["calibrate"].file("calibration.json")))
    track = art.read_track(Path(ctx.raw_inputs["track"])) if "track" in ctx.raw_inputs else None
    plan_walls = None
    if "plan" in ctx.upstream:
        segments, table = art.read_segments(ctx.upstream["plan"].file("plan_walls.parquet"))
        # (M, 5): the thickness lets the fallback put frames against the walls' faces, not centrelines
        plan_walls = np.column_stack([segments, table["thickness_m"].to_numpy()])
    with tempfile.TemporaryDirectory(prefix="sfm-") as workdir:
        result = register_room(
            ingest.file("frames.parquet"),
            camera_info,
            calibration,
            cfg,
            ctx.extra_config["sfm"],
            Path(workdir),
            track=track,
            plan_walls=plan_walls,
            progress=ctx.progress,
            scale_cfg=ctx.extra_config["scale"],
            profile=ctx.profile,
        )
    art.write_table(out / "poses.parquet", result.poses, art.POSES_SCHEMA)
    art.write_ply_points(out / "cloud.ply", result.cloud.points, result.cloud.colors)
    art.write_json(out / "scale.json", result.scale)
    return {"metrics": {**result.metrics, "frame": result.frame}}
