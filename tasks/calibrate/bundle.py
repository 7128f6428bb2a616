"""Camera and stereo adjustment: Brown intrinsics of one camera from its target views (OpenCV's adjustment),
then the IR→RGB relative pose with both cameras adjusted together (the thesis' single bundle adjustment,
or cv2.stereoCalibrate), started from the two mono calibrations."""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from tasks.calibrate.config import CalibrateConfig
from tasks.calibrate.targets import (
    TargetDetection,
    TargetPattern,
    grid_spacing_px,
    parse_pattern,
    refine_corners,
)
from tasks.camera import CameraModel, Redetection, Reject, RigidPose, ViewResidual

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class CameraFit:
    """One camera calibrated from its views."""

    camera: CameraModel
    detections: tuple[TargetDetection, ...]
    """The views used, in order."""
    view_rms_px: tuple[float, ...]
    rvecs: tuple[NDArray, ...]
    """Board → camera rotation vectors per view."""
    tvecs: tuple[NDArray, ...]
    rejects: tuple[Reject, ...] = ()
    """Views dropped for a high residual."""
    coverage: float = 0.0
    """Share of the image's 8 x 6 cells holding target points of the used views: the distortion model is
    measured there and extrapolated elsewhere (thesis 3.1.2: fill the image format)."""


def image_coverage(
    detections: Sequence[TargetDetection], size: tuple[int, int], cells: tuple[int, int] = (8, 6)
) -> float:
    """Share of an image's grid cells that contain at least one detected target point."""
    if not detections:
        return 0.0
    pts = np.concatenate([d.points for d in detections])
    cx = np.clip((pts[:, 0] / size[0] * cells[0]).astype(int), 0, cells[0] - 1)
    cy = np.clip((pts[:, 1] / size[1] * cells[1]).astype(int), 0, cells[1] - 1)
    return float(len(set(zip(cx.tolist(), cy.tolist(), strict=True))) / (cells[0] * cells[1]))


def list_names(items: Sequence[Any], limit: int = 12) -> str:
    """The names (or files) of items as one comma-separated line for an error message, the first `limit`."""
    names = [getattr(x, "name", getattr(x, "file", x)) for x in items]
    names = [str(n) for n in names]
    return ", ".join(names[:limit]) + (f" … ({len(names) - limit} more)" if len(names) > limit else "")


def check_same_size(items: Sequence[tuple[str, tuple[int, int]]], camera: str) -> tuple[int, int]:
    """The common (w, h) of named images, or a ValueError naming the files of each size."""
    by_size: dict[tuple[int, int], list[str]] = {}
    for name, size in items:
        by_size.setdefault(tuple(size), []).append(name)
    if len(by_size) > 1:
        parts = "; ".join(f"{w}x{h}: {list_names(n, 6)}" for (w, h), n in sorted(by_size.items()))
        raise ValueError(f"mixed image sizes among the {camera.upper()} calibration images: {parts}")
    if not by_size:
        raise ValueError(f"no {camera.upper()} calibration images")
    return next(iter(by_size))


def _too_few(
    camera: str, used: Sequence[Any], rejects: Sequence[Reject], need: int, what: str = "views"
) -> str:
    rej = "; ".join(str(r) for r in rejects[:12]) + (
        f"; … ({len(rejects) - 12} more)" if len(rejects) > 12 else ""
    )
    return (
        f"too few usable {camera.upper()} calibration {what}: {len(used)} (need {need}): "
        f"{list_names(used) or 'none'}" + (f"; rejected: {rej}" if rejects else "")
    )


def _calib_flags(cfg: CalibrateConfig) -> int:
    return cv2.CALIB_FIX_K3 if cfg.fix_k3 else 0


def calibrate_camera(
    detections: Sequence[TargetDetection],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig | None = None,
    camera: str = "ir",
    prior_rejects: Sequence[Reject] = (),
) -> CameraFit:
    """Intrinsics and Brown distortion of one camera from its detections (OpenCV's adjustment, k1 k2 p1 p2 k3).
    Views whose RMS exceeds `max_view_rms_px` are dropped once and the camera re-adjusted.
    Raises ValueError naming the files for mixed image sizes or fewer than `min_views` views."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(pattern)
    size = check_same_size([(d.name, d.size) for d in detections], camera) if detections else None
    dets = list(detections)
    dropped: list[Reject] = []
    for attempt in range(2):
        if len(dets) < cfg.min_views or size is None:
            raise ValueError(_too_few(camera, dets, [*prior_rejects, *dropped], cfg.min_views))
        obj = [pat.object_points().reshape(-1, 1, 3)] * len(dets)
        img = [d.points.reshape(-1, 1, 2).astype(np.float32) for d in dets]
        rms, K, dist, rvecs, tvecs, _si, _se, per_view = cv2.calibrateCameraExtended(
            obj, img, size, None, None, flags=_calib_flags(cfg)
        )
        per_view = np.asarray(per_view, dtype=np.float64).reshape(-1)
        bad = per_view > cfg.max_view_rms_px
        if attempt == 1 or not bad.any():
            break
        for d, e in zip(dets, per_view, strict=True):
            if e > cfg.max_view_rms_px:
                dropped.append(
                    Reject(
                        d.name,
                        camera,
                        "high_residual",
                        f"reprojection RMS {e:.2f} px > {cfg.max_view_rms_px:g} px",
                    )
                )
        dets = [d for d, b in zip(dets, bad, strict=True) if not b]
    cam = CameraModel(K, np.asarray(dist).reshape(-1)[:5], size, float(rms))
    log.info("%s camera: %d views, RMS %.3f px, fx %.2f fy %.2f", camera, len(dets), rms, cam.fx, cam.fy)
    coverage = image_coverage(dets, size)
    if coverage < cfg.min_coverage:
        log.warning(
            "%s views cover only %.0f %% of the image (cells with target points): lens distortion near the image "
            "borders is extrapolated; add views with the target near the corners",
            camera.upper(),
            coverage * 100,
        )
    return CameraFit(
        cam,
        tuple(dets),
        tuple(float(e) for e in per_view),
        tuple(np.asarray(r).reshape(3) for r in rvecs),
        tuple(np.asarray(t).reshape(3) for t in tvecs),
        tuple(dropped),
        coverage,
    )


def redetect_outliers(
    camera: CameraModel,
    detections: Sequence[TargetDetection],
    images: Mapping[str, NDArray[np.uint8]],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig,
    camera_name: str = "ir",
) -> tuple[list[TargetDetection], list[Redetection]]:
    """Chessboard corners whose detection is far off where a first calibration puts them, refined again from
    that place. cornerSubPix keeps its start when its solution leaves the search window, so a corner whose
    start was a few pixels off (the classic detector's outer corners on small, tilted boards) stays off; one
    such corner 3.6 px off cost a synthetic survey 0.5 % of its focal length and every room's scale with it.

    Each view's pose is solved (PnP) with `camera`; a point whose residual exceeds `redetect_sigma` times the
    robust per-axis noise of all points (1.4826 · MAD, so the threshold follows the data) is predicted from
    the view's pose without the flagged points and refined there. The new corner is kept when it lies within
    half its old distance of the prediction; a corner that refines back to where it was (a model error, not
    a detection error) is left alone. Returns the detections (points replaced where kept) and what changed."""
    pat = parse_pattern(pattern)
    if pat.kind != "chessboard" or not detections:
        return list(detections), []
    obj = pat.object_points().astype(np.float64)
    K, dist = camera.K, camera.dist

    def pose(
        o: NDArray, pts: NDArray, guess: tuple[NDArray, NDArray] | None = None
    ) -> tuple[NDArray, NDArray]:
        if guess is None:
            _ok, rv, tv = cv2.solvePnP(o, pts, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        else:
            _ok, rv, tv = cv2.solvePnP(
                o, pts, K, dist, guess[0].copy(), guess[1].copy(), True, cv2.SOLVEPNP_ITERATIVE
            )
        return rv, tv

    poses, errors = [], []
    for d in detections:
        pts = d.points.astype(np.float64)
        rv, tv = pose(obj, pts)
        poses.append((rv, tv))
        errors.append(cv2.projectPoints(obj, rv, tv, K, dist)[0].reshape(-1, 2) - pts)
    sigma = 1.4826 * float(np.median(np.abs(np.concatenate(errors))))
    limit = cfg.redetect_sigma * sigma
    out: list[TargetDetection] = []
    found: list[Redetection] = []
    for d, (rv, tv), err in zip(detections, poses, errors, strict=True):
        bad = np.linalg.norm(err, axis=1) > limit
        if not bad.any() or d.name not in images or (~bad).sum() < max(6, bad.sum()):
            out.append(d)
            continue
        pts = d.points.astype(np.float64)
        rv, tv = pose(obj[~bad], pts[~bad], (rv, tv))
        pred = cv2.projectPoints(obj[bad], rv, tv, K, dist)[0].reshape(-1, 2)
        new = refine_corners(images[d.name], pred, grid_spacing_px(d.points, pat), cfg).astype(np.float64)
        before = np.linalg.norm(pts[bad] - pred, axis=1)
        after = np.linalg.norm(new - pred, axis=1)
        take = after < 0.5 * before
        if not take.any():
            out.append(d)
            continue
        idx = np.flatnonzero(bad)[take]
        moved = d.points.copy()
        moved[idx] = new[take]
        out.append(replace(d, points=moved))
        found += [
            Redetection(
                d.name,
                camera_name,
                int(i),
                float(np.linalg.norm(new[k] - pts[i])),
                float(before[k]),
                float(after[k]),
            )
            for i, k in zip(idx, np.flatnonzero(take), strict=True)
        ]
    for r in found:
        log.info(
            "%s %s: corner %d detected again %.2f px away (residual %.2f -> %.2f px)",
            camera_name.upper(),
            r.file,
            r.point,
            r.shift_px,
            r.before_px,
            r.after_px,
        )
    return out, found


@dataclass(frozen=True, eq=False)
class StereoFit:
    ir: CameraModel
    rgb: CameraModel
    ir_to_rgb: RigidPose
    stereo_rms_px: float
    views: tuple[ViewResidual, ...]


def pair_names(ir_names: Sequence[str], rgb_names: Sequence[str]) -> list[tuple[str, str]]:
    """Pair IR and RGB images by the last number in their file names (left03 ↔ right03), or by sorted order
    when names carry no unique numbers. Raises ValueError naming the images without a partner."""

    def number(name: str) -> int | None:
        found = re.findall(r"\d+", Path(name).stem)
        return int(found[-1]) if found else None

    ir_num = {number(n): n for n in ir_names}
    rgb_num = {number(n): n for n in rgb_names}
    numbered = (
        None not in ir_num
        and None not in rgb_num
        and len(ir_num) == len(ir_names)
        and len(rgb_num) == len(rgb_names)
    )
    if numbered:
        lone_ir = [ir_num[k] for k in sorted(ir_num) if k not in rgb_num]  # type: ignore[type-var]
        lone_rgb = [rgb_num[k] for k in sorted(rgb_num) if k not in ir_num]  # type: ignore[type-var]
        if lone_ir or lone_rgb:
            raise ValueError(
                "IR and RGB calibration images do not pair up by number: "
                + "; ".join(
                    s
                    for s in (
                        f"IR without RGB: {list_names(lone_ir)}" if lone_ir else "",
                        f"RGB without IR: {list_names(lone_rgb)}" if lone_rgb else "",
                    )
                    if s
                )
            )
        return [(ir_num[k], rgb_num[k]) for k in sorted(ir_num)]  # type: ignore[type-var]
    if len(ir_names) != len(rgb_names):
        raise ValueError(
            f"cannot pair {len(ir_names)} IR with {len(rgb_names)} RGB calibration images "
            f"(names carry no unique numbers): IR {list_names(sorted(ir_names))}; RGB {list_names(sorted(rgb_names))}"
        )
    return list(zip(sorted(ir_names), sorted(rgb_names), strict=True))


def _relative_pose_guess(
    ir_fit: CameraFit, rgb_fit: CameraFit, both: Sequence[tuple[int, int]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Median of the per-pair relative poses of the two mono calibrations (R, t: X_rgb = R X_ir + t)."""
    rel_r, rel_t = [], []
    for i, j in both:
        Ri = cv2.Rodrigues(ir_fit.rvecs[i])[0]
        Rj = cv2.Rodrigues(rgb_fit.rvecs[j])[0]
        R = Rj @ Ri.T
        rel_r.append(R)
        rel_t.append(rgb_fit.tvecs[j] - R @ ir_fit.tvecs[i])
    return Rotation.from_matrix(np.array(rel_r)).mean().as_matrix(), np.median(np.array(rel_t), axis=0)


def _project_params(params: NDArray, X: NDArray) -> NDArray:
    """Pinhole + Brown projection of (..., 3) camera-frame points with params fx fy cx cy k1 k2 p1 p2 k3."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = params
    x = X[..., 0] / X[..., 2]
    y = X[..., 1] / X[..., 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=-1)


def _initial_boards(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    stations: Sequence[tuple[int | None, int | None]],
    R0: NDArray,
    t0: NDArray,
) -> NDArray[np.float64]:
    """(S, 6) start board poses (board → IR rotation vector, translation) per station, from the IR camera's
    mono calibration, or from the RGB camera's carried into the IR frame by the relative pose guess."""
    n_st = len(stations)
    boards = np.zeros((n_st, 6))
    for s, (i, j) in enumerate(stations):
        if i is not None:
            boards[s] = np.r_[ir_fit.rvecs[i], ir_fit.tvecs[i]]
        else:  # seen by the RGB camera only: carry its board pose into the IR frame
            Rb = cv2.Rodrigues(rgb_fit.rvecs[j])[0]
            boards[s] = np.r_[cv2.Rodrigues(R0.T @ Rb)[0].ravel(), R0.T @ (rgb_fit.tvecs[j] - t0)]
    return boards


def _intrinsic_params(cam: CameraModel) -> NDArray:
    """(9,) fx fy cx cy k1 k2 p1 p2 k3 of a camera (the adjustment's parameter order)."""
    k1, k2, p1, p2, k3 = cam.dist
    return np.array([cam.fx, cam.fy, cam.cx, cam.cy, k1, k2, p1, p2, k3])


def _station_rows(ir_st: NDArray, rgb_st: NDArray, n_pts: int, n_st: int) -> list[NDArray[np.intp]]:
    """Per station, the residual rows its board pose touches: its IR view's, then its RGB view's (the
    residual vector holds all IR views first)."""
    n_ir_rows = 2 * n_pts * len(ir_st)
    st_rows = [np.zeros(0, np.intp)] * n_st
    for k, s_ in enumerate(ir_st):
        st_rows[s_] = np.r_[st_rows[s_], np.arange(2 * n_pts * k, 2 * n_pts * (k + 1))]
    for k, s_ in enumerate(rgb_st):
        rows = n_ir_rows + np.arange(2 * n_pts * k, 2 * n_pts * (k + 1))
        st_rows[s_] = np.r_[st_rows[s_], rows]
    return st_rows


def _grouped_jacobian(
    residuals: Callable[[NDArray], NDArray], x: NDArray, n_glob: int, st_rows: list[NDArray[np.intp]]
) -> NDArray:
    """Jacobian by forward differences, columns grouped: each board pose touches only its own station's rows,
    so one evaluation per board parameter serves all stations (about 30 evaluations instead of 100+).
    `x` holds `n_glob` shared parameters, then 6 per station."""
    n_st = len(st_rows)
    f0 = residuals(x)
    J = np.zeros((f0.size, x.size))
    for c in range(n_glob):
        h = 1e-7 * max(abs(x[c]), 1e-2)
        xp = x.copy()
        xp[c] += h
        J[:, c] = (residuals(xp) - f0) / h
    for k in range(6):
        xp = x.copy()
        cols = n_glob + 6 * np.arange(n_st) + k
        h = 1e-7 * np.maximum(np.abs(x[cols]), 1e-2)
        xp[cols] += h
        d = residuals(xp) - f0
        for s_ in range(n_st):
            J[st_rows[s_], cols[s_]] = d[st_rows[s_]] / h[s_]
    return J


def _bundle_stereo(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    stations: Sequence[tuple[int | None, int | None]],
    pat: TargetPattern,
    cfg: CalibrateConfig,
    R0: NDArray,
    t0: NDArray,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """One least-squares adjustment of both cameras' intrinsics and distortion, the relative pose and one board
    pose per station (board → IR), over every valid observation of either camera.
    Returns (ir params, rgb params, R, t, per-station IR RMS (NaN if none), per-station RGB RMS)."""
    from scipy.optimize import least_squares

    obj = pat.object_points().astype(np.float64)
    n_pts = len(obj)
    n_st = len(stations)
    boards = _initial_boards(ir_fit, rgb_fit, stations, R0, t0)
    ir_st = np.array([s for s, (i, _) in enumerate(stations) if i is not None], dtype=np.intp)
    rgb_st = np.array([s for s, (_, j) in enumerate(stations) if j is not None], dtype=np.intp)
    ir_obs = np.array([ir_fit.detections[i].points for i, _ in stations if i is not None], dtype=np.float64)
    rgb_obs = np.array([rgb_fit.detections[j].points for _, j in stations if j is not None], dtype=np.float64)

    p_ir, p_rgb = _intrinsic_params(ir_fit.camera), _intrinsic_params(rgb_fit.camera)
    free = np.ones(9, bool)
    if cfg.fix_k3:
        free[8] = False
    if not cfg.stereo_refine_intrinsics:
        free[:] = False
    nf = int(free.sum())
    rel0 = np.r_[Rotation.from_matrix(R0).as_rotvec(), t0]
    x0 = np.concatenate([p_ir[free], p_rgb[free], rel0, boards.ravel()])

    def unpack(x: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        a, b = p_ir.copy(), p_rgb.copy()
        a[free] = x[:nf]
        b[free] = x[nf : 2 * nf]
        return a, b, x[2 * nf : 2 * nf + 6], x[2 * nf + 6 :].reshape(n_st, 6)

    def residuals(x: NDArray) -> NDArray:
        a, b, rel, bd = unpack(x)
        Rb = Rotation.from_rotvec(bd[:, :3]).as_matrix()
        X = np.einsum("sij,pj->spi", Rb, obj) + bd[:, None, 3:]
        r_ir = _project_params(a, X[ir_st]) - ir_obs
        X_rgb = X[rgb_st] @ Rotation.from_rotvec(rel[:3]).as_matrix().T + rel[3:]
        r_rgb = _project_params(b, X_rgb) - rgb_obs
        return np.concatenate([r_ir.ravel(), r_rgb.ravel()])

    st_rows = _station_rows(ir_st, rgb_st, n_pts, n_st)
    n_glob = 2 * nf + 6

    def jacobian(x: NDArray) -> NDArray:
        return _grouped_jacobian(residuals, x, n_glob, st_rows)

    sol = least_squares(
        residuals, x0, jac=jacobian, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200
    )
    a, b, rel, _ = unpack(sol.x)
    res = residuals(sol.x)
    e_ir = np.sum(res[: ir_obs.size].reshape(-1, n_pts, 2) ** 2, axis=2)
    e_rgb = np.sum(res[ir_obs.size :].reshape(-1, n_pts, 2) ** 2, axis=2)
    view_ir = np.full(n_st, np.nan)
    view_rgb = np.full(n_st, np.nan)
    view_ir[ir_st] = np.sqrt(e_ir.mean(axis=1))
    view_rgb[rgb_st] = np.sqrt(e_rgb.mean(axis=1))
    return a, b, Rotation.from_rotvec(rel[:3]).as_matrix(), rel[3:].copy(), view_ir, view_rgb


_StereoSolution = tuple[
    CameraModel, CameraModel, NDArray, NDArray, float, float, float, tuple[ViewResidual, ...]
]
"""(IR camera, RGB camera, R and t of X_rgb = R X_ir + t, RMS over both cameras, IR RMS, RGB RMS,
per-view residuals)."""


def _stereo_by_bundle(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    pairs: Sequence[tuple[str, str]],
    ir_idx: dict[str, int],
    rgb_idx: dict[str, int],
    pat: TargetPattern,
    cfg: CalibrateConfig,
    R0: NDArray,
    t0: NDArray,
) -> _StereoSolution:
    """The "bundle" solver: every station (pair) whose target either camera found, adjusted together."""
    size_ir, size_rgb = ir_fit.camera.size, rgb_fit.camera.size
    stations = [(ir_idx.get(a), rgb_idx.get(b)) for a, b in pairs if a in ir_idx or b in rgb_idx]
    names = [
        (a if a in ir_idx else None, b if b in rgb_idx else None)
        for a, b in pairs
        if a in ir_idx or b in rgb_idx
    ]
    a_par, b_par, R, T, v_ir, v_rgb = _bundle_stereo(ir_fit, rgb_fit, stations, pat, cfg, R0, t0)
    e_ir, e_rgb = v_ir[np.isfinite(v_ir)], v_rgb[np.isfinite(v_rgb)]
    rms_ir = float(np.sqrt(np.mean(e_ir**2)))
    rms_rgb = float(np.sqrt(np.mean(e_rgb**2)))
    rms = float(np.sqrt((np.sum(e_ir**2) + np.sum(e_rgb**2)) / (e_ir.size + e_rgb.size)))

    def model(p: NDArray, size: tuple[int, int], r: float) -> CameraModel:
        K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
        return CameraModel(K, p[4:9], size, r)

    ir, rgb = model(a_par, size_ir, rms_ir), model(b_par, size_rgb, rms_rgb)
    views = tuple(
        ViewResidual(na, None if np.isnan(ei) else float(ei), nb, None if np.isnan(er) else float(er))
        for (na, nb), ei, er in zip(names, v_ir, v_rgb, strict=True)
    )
    return ir, rgb, R, T, rms, rms_ir, rms_rgb, views


def _stereo_by_opencv(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    used: Sequence[tuple[str, str]],
    ir_idx: dict[str, int],
    rgb_idx: dict[str, int],
    pat: TargetPattern,
    cfg: CalibrateConfig,
    R0: NDArray,
    t0: NDArray,
) -> _StereoSolution:
    """The "opencv" solver: cv2.stereoCalibrate on the complete pairs only."""
    size_ir, size_rgb = ir_fit.camera.size, rgb_fit.camera.size
    obj = [pat.object_points().reshape(-1, 1, 3)] * len(used)
    p_ir = [ir_fit.detections[ir_idx[a]].points.reshape(-1, 1, 2) for a, _ in used]
    p_rgb = [rgb_fit.detections[rgb_idx[b]].points.reshape(-1, 1, 2) for _, b in used]
    flags = cv2.CALIB_USE_EXTRINSIC_GUESS | _calib_flags(cfg)
    flags |= cv2.CALIB_USE_INTRINSIC_GUESS if cfg.stereo_refine_intrinsics else cv2.CALIB_FIX_INTRINSIC
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    K1, d1 = ir_fit.camera.K.copy(), ir_fit.camera.dist.copy().reshape(1, 5)
    K2, d2 = rgb_fit.camera.K.copy(), rgb_fit.camera.dist.copy().reshape(1, 5)
    out = cv2.stereoCalibrateExtended(
        obj,
        p_ir,
        p_rgb,
        K1,
        d1,
        K2,
        d2,
        size_ir,
        R0.copy(),
        t0.reshape(3, 1).copy(),
        flags=flags,
        criteria=crit,
    )
    rms, K1, d1, K2, d2, R, T = out[:7]
    per_view = np.asarray(out[11], dtype=np.float64).reshape(-1, 2)
    rms_ir = float(np.sqrt(np.mean(per_view[:, 0] ** 2)))
    rms_rgb = float(np.sqrt(np.mean(per_view[:, 1] ** 2)))
    ir = CameraModel(K1, np.asarray(d1).reshape(-1)[:5], size_ir, rms_ir)
    rgb = CameraModel(K2, np.asarray(d2).reshape(-1)[:5], size_rgb, rms_rgb)
    views = tuple(
        ViewResidual(a, float(e[0]), b, float(e[1])) for (a, b), e in zip(used, per_view, strict=True)
    )
    return ir, rgb, R, T, rms, rms_ir, rms_rgb, views


def calibrate_stereo(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    pairs: Sequence[tuple[str, str]],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig | None = None,
) -> StereoFit:
    """Relative pose of the RGB camera with both cameras adjusted together (thesis 3.1.2: interior and exterior
    orientation of the IR and RGB images in one adjustment), started from the mono calibrations and the median of
    the per-pair relative poses. `pairs` are the synchronized (IR, RGB) image names; with the "bundle" solver a
    pair whose one image was rejected still contributes the other. The stereo RMS is over every observation of
    both cameras in the adjustment."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(pattern)
    ir_idx = {d.name: i for i, d in enumerate(ir_fit.detections)}
    rgb_idx = {d.name: i for i, d in enumerate(rgb_fit.detections)}
    used = [(a, b) for a, b in pairs if a in ir_idx and b in rgb_idx]
    need = max(cfg.min_stereo_pairs, 1) if cfg.stereo_solver == "bundle" else cfg.min_views
    if len(used) < need:
        missing = [f"{a}+{b}" for a, b in pairs if a not in ir_idx or b not in rgb_idx]
        raise ValueError(
            f"too few IR+RGB calibration pairs with the target found in both images: {len(used)} (need {need}): "
            f"{', '.join(f'{a}+{b}' for a, b in used) or 'none'}"
            + (f"; incomplete pairs: {', '.join(missing[:12])}" if missing else "")
        )
    R0, t0 = _relative_pose_guess(ir_fit, rgb_fit, [(ir_idx[a], rgb_idx[b]) for a, b in used])
    if cfg.stereo_solver == "bundle":
        ir, rgb, R, T, rms, rms_ir, rms_rgb, views = _stereo_by_bundle(
            ir_fit, rgb_fit, pairs, ir_idx, rgb_idx, pat, cfg, R0, t0
        )
    else:
        ir, rgb, R, T, rms, rms_ir, rms_rgb, views = _stereo_by_opencv(
            ir_fit, rgb_fit, used, ir_idx, rgb_idx, pat, cfg, R0, t0
        )
    # re-orthonormalize: the adjustment's R is a rotation up to rounding
    u, _s, vt = np.linalg.svd(np.asarray(R))
    pose = RigidPose(u @ vt, np.asarray(T).reshape(3))
    log.info(
        "stereo (%s): %d views, %d complete pairs, RMS %.3f px (IR %.3f, RGB %.3f), baseline %.1f mm",
        cfg.stereo_solver,
        len(views),
        len(used),
        rms,
        rms_ir,
        rms_rgb,
        np.linalg.norm(pose.t_m) * 1000,
    )
    return StereoFit(ir, rgb, pose, float(rms), views)
