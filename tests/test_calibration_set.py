"""The survey generator's calibration set (tasks/synth/calibration_set.py) calibrated by the calibrate stage
(`calibrate_folder`) against the set's own truth: intrinsics, lens distortion over the WHOLE image of both
cameras, relative pose, disparity offset, baseline and shift (issue 5, "the generator's calibration set").
The only calibration of the generator's sets in the suite: each costs a minute at full size."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from tasks.calibrate.files import calibrate_folder
from tasks.camera import Calibration, CameraModel
from tasks.synth.calibration_set import CalibrationSetConfig, write_calibration_set

REPO = Path(__file__).resolve().parents[1]


def _profile() -> dict:
    return yaml.safe_load((REPO / "configs" / "sensors" / "kinect_v1.yaml").read_text())


def _distortion_field(cam: CameraModel, step: int = 2) -> np.ndarray:
    """Lens displacement (px) at a dense pixel grid over the whole image, its last row and column included:
    the pixel minus the pinhole pixel of the same ray."""
    w, h = cam.size
    us = np.unique(np.r_[np.arange(0, w, step), w - 1]).astype(np.float64)
    vs = np.unique(np.r_[np.arange(0, h, step), h - 1]).astype(np.float64)
    u, v = np.meshgrid(us, vs)
    uv = np.column_stack([u.ravel(), v.ravel()])
    xy = cam.undistort_pixels(uv)
    return uv - (xy @ cam.K[:2, :2].T + cam.K[:2, 2])


def _write(folder: Path, size: str, seed: int, cfg: CalibrationSetConfig | None = None) -> dict:
    cfg = cfg or CalibrationSetConfig()
    return write_calibration_set(folder, _profile(), size, np.random.default_rng(seed), cfg)


@pytest.mark.slow
@pytest.mark.parametrize("size", ["mini", "full"])
def test_generator_set_recovers_truth_everywhere(size, generator_calibration_set):
    folder, truth_json = generator_calibration_set(size)
    truth = Calibration.from_json(truth_json)
    calib = calibrate_folder(folder)
    cfg = CalibrationSetConfig()
    n_all = cfg.n_views + cfg.n_rgb_edge_views
    # every RGB view is usable; the IR images of the edge views hold only part of the board and are rejected as
    # partial (never as target-free, which the stage treats as an error)
    assert all(r.camera == "ir" and r.kind == "partial" for r in calib.rejects), calib.rejects
    assert len(calib.rejects) >= n_all // 6
    rgb_used = [v.rgb for v in calib.views if v.rgb is not None and v.rms_rgb_px is not None]
    pairs = [v for v in calib.views if v.rms_ir_px is not None and v.rms_rgb_px is not None]
    assert len(rgb_used) == n_all and len(pairs) >= 8
    assert dict(calib.coverage)["rgb"] == pytest.approx(1.0, abs=0.07)
    lines = [f"generator set ({size}): {len(pairs)} complete pairs, coverage {dict(calib.coverage)}"]
    for label, est, tru in (("IR", calib.ir, truth.ir), ("RGB", calib.rgb, truth.rgb)):
        rel = np.array([est.fx / tru.fx, est.fy / tru.fy, est.cx / tru.cx, est.cy / tru.cy]) - 1
        err = np.linalg.norm(_distortion_field(est) - _distortion_field(tru), axis=1)
        lines.append(
            f"  {label}: fx fy cx cy rel err {np.round(rel * 100, 3)} %, distortion max {err.max():.3f} px over "
            f"the whole image (median {np.median(err):.3f}), RMS {est.rms_px:.3f} px"
        )
        assert np.abs(rel).max() < 0.005, label
        assert np.isfinite(err).all() and err.max() < 0.3, label
    dt_mm = np.linalg.norm(calib.ir_to_rgb.t_m - truth.ir_to_rgb.t_m) * 1000
    dr_deg = np.degrees(
        np.linalg.norm(Rotation.from_matrix(calib.ir_to_rgb.R @ truth.ir_to_rgb.R.T).as_rotvec())
    )
    dm, tm = calib.depth_model, truth.depth_model
    d_off, d_base = dm.offset / tm.offset - 1, dm.baseline_m / tm.baseline_m - 1
    lines.append(
        f"  IR→RGB {dt_mm:.2f} mm {dr_deg:.3f}°; disparity offset {d_off * 100:+.3f} %, "
        f"baseline {d_base * 100:+.3f} %"
    )
    print("\n" + "\n".join(lines))
    assert dt_mm < 2.0 and dr_deg < 0.2
    assert abs(d_off) < 0.01 and abs(d_base) < 0.01
    assert dm.shift_x_px == tm.shift_x_px


@pytest.mark.slow
def test_generator_set_layout_size_and_determinism(generator_calibration_set, tmp_path):
    """Same rng, same set; the mini set stays small; edge views put the RGB board near every image corner."""
    folder_a, a = generator_calibration_set("mini")
    b = _write(tmp_path / "b", "mini", 5)  # the session's set was written with seed 5 too
    assert a == b
    files_a = sorted(p.relative_to(folder_a) for p in folder_a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert files_a == files_b
    assert all((folder_a / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in files_a)
    total_mb = sum((folder_a / f).stat().st_size for f in files_a) / 1e6
    cfg = CalibrationSetConfig()
    n_all = cfg.n_views + cfg.n_rgb_edge_views
    assert len(list((folder_a / "ir").glob("*.png"))) == n_all
    assert len(list((folder_a / "rgb").glob("*.png"))) == n_all
    print(f"\nmini calibration set: {len(files_a)} files, {total_mb:.2f} MB")
    assert total_mb < 3.2


def test_generator_set_rejects_too_few_views(tmp_path):
    with pytest.raises(ValueError, match="at least 8"):
        _write(tmp_path, "mini", 0, CalibrationSetConfig(n_views=7))
