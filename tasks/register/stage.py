"""The register stage's entry: the room's ingested frames (and the survey's calibration, IMU track and plan
walls when there are) → poses.parquet, cloud.ply and scale.json."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tasks import artefacts as art
from tasks.camera import Calibration
from tasks.cloud import DegenerateInputError
from tasks.context import StageContext
from tasks.register.config import RegisterConfig
from tasks.register.room import register_room


def fit_to_frames(calibration: Calibration, sizes: dict[str, Any], from_profile: bool) -> Calibration:
    """Input validation: the calibration against the frames' sizes (ingest's camera_info.json
    `frame_sizes`), before any registration work. A sensor profile's values (a survey without
    calibration data) are scaled to a stream recorded at another resolution of the same aspect (a
    Kinect's 320x240 mode); any other mismatch is a one-line error."""
    cameras = {
        "ir": (calibration.ir, sizes.get("depth"), "depth"),
        "rgb": (calibration.rgb, sizes.get("rgb"), "colour"),
    }
    scaled = {}
    for name, (camera, size, stream) in cameras.items():
        if camera is None or size is None or tuple(size) == camera.size:
            continue
        what = (
            f"the calibration's {name.upper()} camera is {camera.size[0]}x{camera.size[1]}, the capture's "
            f"{stream} frames are {size[0]}x{size[1]}"
        )
        if not from_profile:
            raise DegenerateInputError(f"{what}: calibrate at the frames' resolution")
        try:
            scaled[name] = camera.scaled((int(size[0]), int(size[1])))
        except ValueError:
            raise DegenerateInputError(
                f"{what} (another aspect than the sensor profile's): give the survey a calibration"
            ) from None
    return replace(calibration, **scaled) if scaled else calibration


def run(ctx: StageContext, cfg: RegisterConfig, out: Path) -> dict[str, Any]:
    """SfM -> metric scale -> fused coloured cloud, or the track-based fallback (thesis 3.2)."""
    ingest = ctx.upstream["ingest"]
    camera_info = art.read_json(ingest.file("camera_info.json"))
    calibration = None
    if "calibrate" in ctx.upstream:
        calibrate = ctx.upstream["calibrate"]
        calibration = Calibration.from_json(art.read_json(calibrate.file("calibration.json")))
        from_profile = calibrate.manifest.get("metrics", {}).get("source") == "profile"
        calibration = fit_to_frames(calibration, camera_info.get("frame_sizes") or {}, from_profile)
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
