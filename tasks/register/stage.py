"""The register stage's entry: the room's ingested frames (and the survey's calibration, IMU track and plan
walls when there are) → poses.parquet, cloud.ply and scale.json."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.camera import Calibration
from tasks.cloud import DegenerateInputError
from tasks.context import StageContext
from tasks.register.config import RegisterConfig, SfmConfig
from tasks.register.room import register_room


def run(ctx: StageContext, cfg: RegisterConfig, out: Path) -> dict[str, Any]:
    """SfM -> metric scale -> fused coloured cloud, or the track-based fallback (thesis 3.2)."""
    ingest = ctx.upstream["ingest"]
    camera_info = art.read_json(ingest.file("camera_info.json"))
    calibration = None
    if "calibrate" in ctx.upstream:
        calibration = Calibration.from_json(art.read_json(ctx.upstream["calibrate"].file("calibration.json")))
    track = read_track(Path(ctx.raw_inputs["track"])) if "track" in ctx.raw_inputs else None
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


def read_track(path: Path) -> NDArray[np.float64]:
    """(K, 3) t_ns, x, y of a foot-mounted IMU track CSV (header line allowed)."""
    try:
        data = np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1 if not _starts_numeric(path) else 0)
    except ValueError as exc:
        raise art.ArtefactError(f"{path}: not a track CSV of t_ns,x,y ({exc})") from exc
    if data.shape[1] < 3:
        raise art.ArtefactError(f"{path}: a track needs three columns t_ns,x,y")
    return data[:, :3]


def _starts_numeric(path: Path) -> bool:
    """Whether the file's first field is a number (no header line)."""
    with open(path) as fh:
        first = fh.readline().split(",")[0].strip()
    try:
        float(first)
    except ValueError:
        return False
    return True


# to be replaced by the CLI running the stage through the pipeline
def run_register_room(
    capture: Path,
    out_dir: Path,
    intrinsics: tuple[float, float, float, float] | str | None = None,
    depth_units_per_m: float | None = None,
    calibration_path: Path | None = None,
    profile_name: str = "kinect_v1",
    track: NDArray[np.float64] | None = None,
    plan_walls: NDArray[np.float64] | None = None,
    cfg: RegisterConfig | None = None,
    sfm_cfg: SfmConfig | None = None,
) -> dict[str, Any]:
    """`indoor-survey register-room CAPTURE --out DIR [--intrinsics fx,fy,cx,cy] [--depth-scale U]
    [--calibration FILE]`: ingest → sfm → scale → register on one room; writes DIR/poses.parquet,
    DIR/cloud.ply and DIR/scale.json and returns the metrics. `intrinsics` override both streams' pinhole
    intrinsics (no distortion); `depth_units_per_m` overrides the depth PNG units."""
    import json

    from tasks.artefacts import POSES_SCHEMA, write_json, write_ply_points, write_table
    from tasks.config import load_sensor_profile
    from tasks.ingest.capture import ingest_capture
    from tasks.ingest.config import IngestConfig

    profile = load_sensor_profile(profile_name)
    out_dir = Path(out_dir)
    calibration = None
    if calibration_path is not None:
        calibration = Calibration.from_json(json.loads(Path(calibration_path).read_text()))
    with tempfile.TemporaryDirectory(prefix="register-") as tmp:
        stage = Path(tmp) / "ingest"
        stage.mkdir()
        icfg = IngestConfig(tum_depth_units_per_m=depth_units_per_m) if depth_units_per_m else IngestConfig()
        ingest_metrics = ingest_capture(Path(capture), stage, profile, icfg)
        if not (stage / "frames.parquet").exists():
            raise DegenerateInputError(f"{capture}: a registered cloud needs no registration")
        camera_info = json.loads((stage / "camera_info.json").read_text())
        if intrinsics is not None:
            vals = [float(v) for v in (intrinsics.split(",") if isinstance(intrinsics, str) else intrinsics)]
            if len(vals) != 4:
                raise ValueError(f"--intrinsics needs fx,fy,cx,cy, got {intrinsics!r}")
            fx, fy, cx, cy = vals
            for stream in ("depth", "rgb"):
                if stream in camera_info:
                    camera_info[stream] = {
                        **camera_info[stream],
                        "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                        "dist": [0.0] * 5,
                        "source": "cli",
                    }
        work = Path(tmp) / "sfm"
        work.mkdir()
        result = register_room(
            stage / "frames.parquet",
            camera_info,
            calibration,
            cfg or RegisterConfig(),
            sfm_cfg or SfmConfig(),
            work,
            track=track,
            plan_walls=plan_walls,
            profile=profile,
            depth_units_per_m=depth_units_per_m,
        )
    write_table(out_dir / "poses.parquet", result.poses, POSES_SCHEMA)
    write_ply_points(out_dir / "cloud.ply", result.cloud.points, result.cloud.colors)
    write_json(out_dir / "scale.json", result.scale)
    return {"ingest": ingest_metrics, **result.metrics, "frame": result.frame}
