"""The Kinect v1 disparity model (eq 3.11-3.12): offset and b·c by least squares from flat-target frames at
known distances, with residuals."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from tasks.calibrate.bundle import list_names
from tasks.calibrate.config import CalibrateConfig
from tasks.camera import DepthModel, FlatTargetResidual

log = logging.getLogger(__name__)


def fit_disparity_model(
    frames: Sequence[NDArray],
    known_distances: Sequence[float | NDArray],
    *,
    focal_px: float | None = None,
    names: Sequence[str] | None = None,
    cfg: CalibrateConfig | None = None,
    shift_x_px: float | None = None,
) -> DepthModel:
    """Offset and b·c of eq 3.11-3.12 by least squares from raw disparity frames of a flat target.

    frames: raw Kinect d_k images (H, W), 2047 = no measurement. known_distances: per frame the target's depth H
    in metres (a plane perpendicular to the optical axis), or an (H, W) array of per-pixel depths (a tilted
    target). The observation equation d_k = offset − (b·c / subpixel_scale) · (1/H) is linear in the unknowns;
    pixels of the central `flat_roi_fraction` are used, with two rounds of 3.5·MAD outlier trimming.
    focal_px (the IR focal length c in native disparity pixels) splits b·c into the baseline b; shift_x_px (the
    disparity/IR column shift in the frames' pixels) defaults to cfg.depth_shift_x_px scaled to the frame width."""
    cfg = cfg or CalibrateConfig()
    names = list(names) if names is not None else [f"frame{i:03d}" for i in range(len(frames))]
    if len(frames) != len(known_distances) or len(names) != len(frames):
        raise ValueError(
            f"{len(frames)} flat-target frames but {len(known_distances)} known distances "
            f"({list_names(names)}): give one distance per frame"
        )
    scale = 0.125
    invalid = 2047
    dk, inv_h, fr = _flat_target_samples(frames, known_distances, names, cfg, invalid)
    if np.ptp(inv_h) < 1e-6:
        raise ValueError(f"flat-target frames must span at least two distances: {list_names(names)}")
    keep = np.ones(dk.size, bool)
    for _ in range(3):
        A = np.stack([np.ones(keep.sum()), -inv_h[keep] / scale], axis=1)
        sol, *_ = np.linalg.lstsq(A, dk[keep], rcond=None)
        res = dk - (sol[0] - sol[1] * inv_h / scale)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res) <= max(3.5 * mad, 1.0)
    offset, bc = float(sol[0]), float(sol[1])
    res = dk - (offset - bc * inv_h / scale)
    residuals = _frame_residuals(dk, inv_h, fr, keep, offset, bc, scale, names)
    rms_depth = float(np.sqrt(np.nanmean([r.depth_error_m**2 for r in residuals])))
    model = DepthModel(
        offset=offset,
        bc_m_px=bc,
        focal_px=None if focal_px is None else float(focal_px),
        shift_x_px=float(shift_x_px)
        if shift_x_px is not None
        else cfg.depth_shift_x_px * np.asarray(frames[0]).shape[1] / cfg.disparity_native_width_px,
        subpixel_scale=scale,
        invalid_raw=invalid,
        rms_raw=float(np.sqrt(np.mean(res[keep] ** 2))),
        rms_depth_m=rms_depth,
        residuals=tuple(residuals),
    )
    log.info(
        "disparity model: offset %.2f, b·c %.3f m·px (b %s), RMS %.2f d_k, %.1f mm",
        offset,
        bc,
        "?" if model.baseline_m is None else f"{model.baseline_m * 1000:.1f} mm",
        model.rms_raw,
        rms_depth * 1000,
    )
    return model


def _flat_target_samples(
    frames: Sequence[NDArray],
    known_distances: Sequence[float | NDArray],
    names: list[str],
    cfg: CalibrateConfig,
    invalid: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int_]]:
    """The fit's observations: (P,) raw d_k, (P,) known inverse depth 1/H and (P,) frame index of every valid
    pixel in the central `flat_roi_fraction` of each frame. ValueError naming frames with too few of them."""
    dk_all, inv_h_all, frame_all = [], [], []
    empty = []
    for i, (frame, dist) in enumerate(zip(frames, known_distances, strict=True)):
        raw = np.asarray(frame)
        if raw.ndim != 2:
            raise ValueError(f"flat-target frame {names[i]} is not a single-channel disparity image")
        h, w = raw.shape
        depth = np.broadcast_to(np.asarray(dist, dtype=np.float64), raw.shape)
        m = np.zeros(raw.shape, bool)
        fy0, fx0 = int(h * (1 - cfg.flat_roi_fraction) / 2), int(w * (1 - cfg.flat_roi_fraction) / 2)
        m[fy0 : h - fy0, fx0 : w - fx0] = True
        m &= (raw < invalid) & np.isfinite(depth) & (depth > 0)
        if m.sum() < 10:
            empty.append(names[i])
            continue
        dk_all.append(raw[m].astype(np.float64))
        inv_h_all.append(1.0 / depth[m])
        frame_all.append(np.full(int(m.sum()), i))
    if empty:
        raise ValueError(f"flat-target frames without valid disparities in their centre: {list_names(empty)}")
    dk = np.concatenate(dk_all)
    inv_h = np.concatenate(inv_h_all)
    fr = np.concatenate(frame_all)
    return dk, inv_h, fr


def _frame_residuals(
    dk: NDArray[np.float64],
    inv_h: NDArray[np.float64],
    fr: NDArray[np.int_],
    keep: NDArray[np.bool_],
    offset: float,
    bc: float,
    scale: float,
    names: list[str],
) -> list[FlatTargetResidual]:
    """How each frame's kept pixels fit the model (offset, b·c): mean d_k residual and depth error."""
    residuals = []
    for i in range(len(names)):
        sel = keep & (fr == i)
        if not sel.any():
            continue
        mean_dk = float(dk[sel].mean())
        h_known = float(1.0 / inv_h[sel].mean())
        pred_mean = offset - bc * float(inv_h[sel].mean()) / scale
        h_model = bc / ((offset - mean_dk) * scale) if offset > mean_dk else float("nan")
        residuals.append(
            FlatTargetResidual(
                names[i], h_known, int(sel.sum()), mean_dk, mean_dk - pred_mean, h_model - h_known
            )
        )
    return residuals
