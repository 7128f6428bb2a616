"""The stage table: for each stage, what it reads, which config section it owns and how its outputs are
loaded and saved. Each `run_*` here is the thin shell around a pure stage function: load the inputs from
the artefact store, call, write the outputs into the folder the store commits. Orchestration (Prefect)
lives in flows/; formats live in tasks/artefacts.py; the computation lives in each stage's module.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.artefacts import StageResult

ProgressFn = Callable[[str], None]


@dataclass(frozen=True)
class StageContext:
    """What a stage run gets besides its config: its upstream results, raw input files, the survey's
    sensor profile, and a progress callback."""

    room: str
    upstream: dict[str, StageResult]
    raw_inputs: dict[str, str]
    """Name -> path of raw survey files this stage reads (their content hashes are in the key)."""
    profile: dict[str, Any]
    progress: ProgressFn
    extra_config: dict[str, Any] = field(default_factory=dict)
    """Section name -> config of the stage's `extra_sections`."""
    params: dict[str, Any] = field(default_factory=dict)
    """Survey-given values (the plan's scale)."""


@dataclass(frozen=True)
class Stage:
    name: str
    section: str
    """Config section the stage owns (its config in the cache key)."""
    module: str
    """The module holding the stage's computation (its source is part of the code version)."""
    run: Callable[[StageContext, Any, Path], dict[str, Any]]
    """(context, config section, output folder) -> metrics; writes its files into the folder."""
    uses_profile: bool = False
    """Whether the survey's sensor profile is an input (then its content is part of the cache key)."""
    extra_sections: tuple[str, ...] = ()
    """Further config sections the stage reads (a stage that runs several methods: register reads sfm
    and scale); they enter its cache key too and reach `run` as `ctx.extra_config`."""

    def code_version(self) -> str:
        """Hash of the computation's module source and of this stage's shell, so editing either
        invalidates the stage (and, through content hashes, what depends on it). Read once per process."""
        return _code_version(self.module, self.run)


@functools.cache
def _code_version(module_name: str, run: Callable[..., Any]) -> str:
    module = sys.modules.get(module_name) or importlib.import_module(module_name)
    digest = hashlib.sha256(Path(inspect.getfile(module)).read_bytes())
    digest.update(inspect.getsource(run).encode())
    return digest.hexdigest()[:16]


# ------------------------------------------------------------------------------------------------ shells


def run_calibrate(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """The survey's calibration from its target images, else the sensor profile's values (said so)."""
    from tasks.calibration import calibrate_folder, profile_calibration, write_calibration

    folder = ctx.raw_inputs.get("calibration")
    if folder:
        ctx.progress(f"calibrating from {folder}")
        calib = calibrate_folder(Path(folder), cfg)
    else:
        ctx.progress(f"no calibration data: using the {ctx.profile.get('name')} profile's values")
        calib = profile_calibration(ctx.profile)
    write_calibration(calib, out)
    data = calib.to_json()
    return {"metrics": {"source": calib.source, **_calibration_figures(data)}}


def _calibration_figures(data: dict[str, Any]) -> dict[str, Any]:
    figures: dict[str, Any] = {}
    for cam in ("ir", "rgb"):
        if data.get(cam):
            figures[f"{cam}_rms_px"] = data[cam].get("rms_px")
            figures[f"{cam}_fx_px"] = data[cam]["K"][0][0]
    if data.get("ir_to_rgb"):
        figures["baseline_mm"] = 1000.0 * float(np.linalg.norm(data["ir_to_rgb"]["t_m"]))
    figures["stereo_rms_px"] = data.get("stereo_rms_px")
    return figures


def run_plan(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """The coarse plan raster as metric walls (centrelines + thickness) and rooms (thesis 4.2.3)."""
    from tasks.plan.stage import run

    return run(ctx, cfg, out)


def run_ingest(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.ingest import ingest_capture

    return {"metrics": ingest_capture(Path(ctx.raw_inputs["capture"]), out, ctx.profile, cfg, ctx.progress)}


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
    with open(path) as fh:
        first = fh.readline().split(",")[0].strip()
    try:
        float(first)
    except ValueError:
        return False
    return True


def run_register(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """SfM -> metric scale -> fused coloured cloud, or the track-based fallback (thesis 3.2)."""
    import tempfile

    from tasks.calibration import Calibration
    from tasks.register import register_room

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


def run_preprocess(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.preprocess.stage import run

    return run(ctx, cfg, out)


def run_walls(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.walls.stage import run

    return run(ctx, cfg, out)


ROOM_DELIVERABLES = {"walls": ("walls.parquet", "plan.geojson", "model.ply", "preview.png")}
"""Stage -> files published to outputs/rooms/<id>/ (PIPELINE.md "Deliverables")."""

BUILDING_DELIVERABLES = {"plan": ("plan_walls.parquet", "rooms.geojson", "plan_preview.png")}
"""Stage -> files published to outputs/ (PIPELINE.md "Deliverables")."""


STAGES: dict[str, Stage] = {
    stage.name: stage
    for stage in (
        Stage("calibrate", "calibrate", "tasks.calibration", run_calibrate, uses_profile=True),
        Stage("plan", "plan", "tasks.plan", run_plan),
        Stage("ingest", "ingest", "tasks.ingest", run_ingest, uses_profile=True),
        Stage("register", "register", "tasks.register", run_register, True, ("sfm", "scale")),
        Stage("preprocess", "preprocess", "tasks.preprocess", run_preprocess),
        Stage("walls", "walls", "tasks.walls", run_walls),
    )
}
