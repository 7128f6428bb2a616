"""The calibrate stage's entry: the survey's calibration from its target images, else the sensor profile's
values (said so), written as calibration.json (the contract) and calibration_residuals.json."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tasks.calibrate.config import CalibrateConfig
from tasks.calibrate.files import calibrate_folder
from tasks.camera import Calibration, profile_calibration
from tasks.context import StageContext


def run(ctx: StageContext, cfg: CalibrateConfig, out: Path) -> dict[str, Any]:
    """The survey's calibration from its target images, else the sensor profile's values (said so).
    OpenCV runs single-threaded meanwhile: its parallel corner refinement and calibration sum in an order
    that changes from run to run (1e-8 px in the focal length), and every room's registration downstream
    would see a new calibration each time."""
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _calibrate(ctx, cfg, out)
    finally:
        cv2.setNumThreads(threads)


def _calibrate(ctx: StageContext, cfg: CalibrateConfig, out: Path) -> dict[str, Any]:
    given = ctx.raw_inputs.get("calibration")
    if given and Path(given).is_file():  # a calibration.json made earlier (by this stage or `calibrate`)
        ctx.progress(f"using the calibration in {given}")
        calib = read_calibration(Path(given))
    elif given:
        ctx.progress(f"calibrating from {given}")
        calib = calibrate_folder(Path(given), cfg)
    else:
        ctx.progress(f"no calibration data: using the {ctx.profile.get('name')} profile's values")
        calib = profile_calibration(ctx.profile)
    write_calibration(calib, out)
    data = calib.to_json()
    figures = {"source": calib.source, **_calibration_figures(data)}
    if calib.source == "targets":
        figures["redetected_corners"] = len(calib.redetected)
    return {"metrics": figures}


def read_calibration(path: Path) -> Calibration:
    """A calibration.json; a one-line error naming the file when it is not one."""
    from tasks.artefacts import ArtefactError, read_json

    try:
        return Calibration.from_json(read_json(path))
    except (ArtefactError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a calibration.json ({' '.join(str(exc).split())})") from exc


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
