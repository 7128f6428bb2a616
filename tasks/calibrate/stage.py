"""The calibrate stage's entry: the survey's calibration from its target images, else the sensor profile's
values (said so), written as calibration.json (the contract) and calibration_residuals.json."""

from __future__ import annotations

import glob
import logging
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tasks.calibrate.config import CalibrateConfig
from tasks.calibrate.files import calibrate_files, calibrate_folder
from tasks.calibrate.targets import parse_pattern
from tasks.camera import Calibration, profile_calibration
from tasks.context import StageContext

log = logging.getLogger(__name__)


def run(ctx: StageContext, cfg: CalibrateConfig, out: Path) -> dict[str, Any]:
    """The survey's calibration from its target images, else the sensor profile's values (said so)."""
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
    """The manifest's headline figures of a calibration.json: per camera RMS and focal length, baseline."""
    figures: dict[str, Any] = {}
    for cam in ("ir", "rgb"):
        if data.get(cam):
            figures[f"{cam}_rms_px"] = data[cam].get("rms_px")
            figures[f"{cam}_fx_px"] = data[cam]["K"][0][0]
    if data.get("ir_to_rgb"):
        figures["baseline_mm"] = 1000.0 * float(np.linalg.norm(data["ir_to_rgb"]["t_m"]))
    figures["stereo_rms_px"] = data.get("stereo_rms_px")
    return figures


def write_calibration(calib: Calibration, out_dir: Path) -> Path:
    """DIR/calibration.json (the contract) and DIR/calibration_residuals.json (source, views, coverage,
    rejects), each written atomically; returns the path of calibration.json."""
    from tasks.artefacts import write_json

    out_dir = Path(out_dir)
    write_json(out_dir / "calibration_residuals.json", _json_safe(calib.residuals_json()))
    return write_json(out_dir / "calibration.json", _json_safe(calib.to_json()))


def _json_safe(obj: Any) -> Any:
    """`obj` with NumPy scalars as Python numbers and non-finite floats as null (strict JSON)."""
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def _glob(pattern: str, what: str) -> list[str]:
    """Sorted files matching a CLI glob (`~` expanded, `**` recursive); ValueError naming the option if none."""
    files = sorted(f for f in glob.glob(os.path.expanduser(pattern), recursive=True) if os.path.isfile(f))
    if not files:
        raise ValueError(f"no files match {what} {pattern!r}")
    return files


# to be replaced by the CLI running the stage through the pipeline
def run_calibrate(
    ir_glob: str,
    rgb_glob: str | None,
    pattern: str,
    out_dir: Path,
    *,
    flat_glob: str | None = None,
    known_distances: Sequence[float] | None = None,
    cfg: CalibrateConfig | None = None,
) -> Path:
    """`indoor-survey calibrate --ir GLOB [--rgb GLOB] --pattern P --out DIR`: writes DIR/calibration.json
    (plus DIR/calibration_residuals.json) and returns its path. IR and RGB images pair by the numbers in
    their names (else by sorted order); `--ir` alone calibrates one camera."""
    cfg = replace(cfg or CalibrateConfig(), pattern=str(parse_pattern(pattern)))
    ir = _glob(ir_glob, "--ir")
    rgb = _glob(rgb_glob, "--rgb") if rgb_glob else None
    flats = _glob(flat_glob, "flat-target") if flat_glob else None
    calib = calibrate_files(ir, rgb, cfg, flat_paths=flats, known_distances=known_distances)
    path = write_calibration(calib, Path(out_dir))
    log.info("wrote %s (%s)", path, "IR+RGB" if rgb else "IR only")
    return path
