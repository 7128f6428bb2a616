"""Metric scale (thesis 3.2.1, eq 3.16, appendix A.1): metric poses from SfM and depth.

SfM orients the colour frames up to an unknown scale. Every registered frame observes some of the sparse
SfM points; the depth image of the same frame measures those points in metres. For each frame the
7-parameter similarity (Helmert, eq 3.16) X_object = λ · R · X_local + T between the SfM points (local) and
their depth points in the RGB camera frame (object) is solved in closed form with Horn's unit quaternion
method (appendix A.1, eq A.10-A.13) inside RANSAC, then the per-frame scales are combined robustly (median,
with the MAD and IQR as spread). `apply_scale` turns the SfM poses into metric depth-camera-to-room poses.

The estimate is unbiased for Kinect-like depth: the depth camera's radial error (estimated on the capture,
`tasks.register.fusion.RadialDepthError`) is taken out before the depth is compared, the depth points
that fall on one colour pixel are averaged in inverse depth rather than the nearest kept (`depth_in_rgb`),
and the per-frame and overall medians of depth ratios commute with z = b·c/d, so even disparity noise
leaves them unbiased. Left in, the first two made every scale short by about 0.25 % and 0.1 %.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.camera import Calibration, CameraModel, strided_depth_points
from tasks.cloud import DegenerateInputError
from tasks.register.config import ScaleConfig
from tasks.register.fusion import radial_position
from tasks.register.sfm import SfmResult
from tasks.threads import imap_ordered

ROOM_FROM_CAMERA_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Room axes from the first camera's: x right, y forward (the optical axis), z up (minus the image y)."""


@dataclass
class FrameScale:
    """The similarity of one frame (eq 3.16): X_rgb = scale · R · X_sfm + t."""

    name: str
    scale: float
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    correspondences: int
    inliers: int
    rms_m: float
    """RMS residual of the inliers (m)."""
    depth_noise_m_at_1m: float = 0.0
    """The frame's `depth_noise_coefficient` (window spread per squared metre of range)."""


@dataclass
class ScaleReport:
    """The combined scale (metres per SfM unit) and how well the frames agree."""

    scale: float
    mad: float
    """Median absolute deviation of the per-frame scales times 1.4826 (a robust standard deviation)."""
    iqr: float
    """Inter-quartile range of the per-frame scales."""
    relative_spread: float
    """mad / scale."""
    frames_used: list[str]
    frames: list[FrameScale] = field(default_factory=list)
    relative_trend: float = 0.0
    """Change of the per-frame scales from the first frame to the last (Theil-Sen line through them in
    capture order) / scale: a reconstruction bent by the mapper drifts in scale along the capture, while
    depth noise spreads the scales without a trend."""
    radial_k_inv_m: float = 0.0
    """The depth camera's radial inverse-depth error (1/m at the image corners) taken out of the depth."""
    same_surface_tol_m: float = 0.0
    """Depth points landing on one colour pixel within this of the nearest were averaged (inverse depth)."""
    depth_noise_m_at_1m: float = 0.0
    """Median over the frames of the depth's window spread per squared metre of range: the surface and edge
    tolerances grow to `step_noise_factor` times it · z² where that passes `same_surface_tol_m`."""

    def to_json(self) -> dict[str, Any]:
        return {
            "scale": self.scale,
            "spread_mad": self.mad,
            "spread_iqr": self.iqr,
            "relative_spread": self.relative_spread,
            "relative_trend": self.relative_trend,
            "radial_k_inv_m": self.radial_k_inv_m,
            "same_surface_tol_m": self.same_surface_tol_m,
            "depth_noise_m_at_1m": self.depth_noise_m_at_1m,
            "frames_used": len(self.frames_used),
            "frame_names": self.frames_used,
            "per_frame": {
                f.name: {"scale": f.scale, "inliers": f.inliers, "rms_m": f.rms_m} for f in self.frames
            },
        }


# ------------------------------------------------------------------------------------ closed-form similarity


def horn_similarity(
    local: NDArray[np.float64], obj: NDArray[np.float64], scale_formula: str = "asymmetric"
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares similarity obj ≈ λ · R · local + T (eq 3.16) in closed form with Horn's unit
    quaternions (appendix A.1): centroids (A.11), the cross-covariance M (A.12), the symmetric 4×4 N whose
    eigenvector of the largest eigenvalue is the rotation quaternion (A.13, A.7).

    Horn gives two scales: "asymmetric" λ = Σ obj'·R local' / Σ|local'|², the least-squares scale when the
    errors are in the object coordinates, and "symmetric" λ = sqrt(Σ|obj'|² / Σ|local'|²) for errors on
    both sides alike. Depth noise (and the RGB/depth sampling offset) dwarfs the error of triangulated SfM
    points, so the asymmetric one is the default (on 7-Scenes it moved the scale 0.15 % toward the given
    poses).

    local, obj: (N, 3), N >= 3 not collinear. Returns (λ, (3, 3) R, (3,) T)."""
    s = np.asarray(local, dtype=np.float64)
    d = np.asarray(obj, dtype=np.float64)
    if s.shape != d.shape or s.ndim != 2 or s.shape[1] != 3 or len(s) < 3:
        raise DegenerateInputError(f"similarity needs two (N>=3, 3) point sets, got {s.shape} and {d.shape}")
    lam, R, T, ss = _horn_batch(s[None], d[None], scale_formula)
    if ss[0] <= 1e-18:
        raise DegenerateInputError("similarity points coincide")
    return float(lam[0]), R[0], T[0]


def _horn_batch(
    s: NDArray[np.float64], d: NDArray[np.float64], scale_formula: str
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """`horn_similarity` of K point-set pairs at once: s, d (K, N, 3) → λ (K,), R (K, 3, 3), T (K, 3) and
    Σ|local'|² (K,), where a set whose points coincide (Σ|local'|² ≈ 0) gives λ = NaN."""
    sc, dc = s.mean(axis=1), d.mean(axis=1)
    s1, d1 = s - sc[:, None], d - dc[:, None]
    ss = (s1**2).sum(axis=(1, 2))
    M = np.einsum("kna,knb->kab", s1, d1)  # S_ab = Σ s'_a d'_b
    Sxx, Sxy, Sxz = M[:, 0, 0], M[:, 0, 1], M[:, 0, 2]
    Syx, Syy, Syz = M[:, 1, 0], M[:, 1, 1], M[:, 1, 2]
    Szx, Szy, Szz = M[:, 2, 0], M[:, 2, 1], M[:, 2, 2]
    N = np.stack(
        [
            np.stack([Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx], axis=-1),
            np.stack([Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz], axis=-1),
            np.stack([Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy], axis=-1),
            np.stack([Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz], axis=-1),
        ],
        axis=-2,
    )
    _w, v = np.linalg.eigh(N)
    q0, qx, qy, qz = np.moveaxis(v[:, :, -1], -1, 0)
    R = np.stack(
        [
            np.stack(
                [q0 * q0 + qx * qx - qy * qy - qz * qz, 2 * (qx * qy - q0 * qz), 2 * (qx * qz + q0 * qy)], -1
            ),
            np.stack(
                [2 * (qy * qx + q0 * qz), q0 * q0 - qx * qx + qy * qy - qz * qz, 2 * (qy * qz - q0 * qx)], -1
            ),
            np.stack(
                [2 * (qz * qx - q0 * qy), 2 * (qz * qy + q0 * qx), q0 * q0 - qx * qx - qy * qy + qz * qz], -1
            ),
        ],
        axis=-2,
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        if scale_formula == "symmetric":
            lam = np.sqrt((d1**2).sum(axis=(1, 2)) / ss)
        elif scale_formula == "asymmetric":
            lam = np.einsum("kni,knj,kij->k", d1, s1, R) / ss
        else:
            raise ValueError(f"unknown scale formula {scale_formula!r}: asymmetric or symmetric")
    lam = np.where(ss > 1e-18, lam, np.nan)
    T = dc - lam[:, None] * np.einsum("kij,kj->ki", R, sc)
    return lam, R, T, ss


_RANSAC_BATCH = 50
"""Hypotheses scored at once in `ransac_similarity` (bounds its (batch, N, 3) residuals)."""


def ransac_similarity(
    local: NDArray[np.float64],
    obj: NDArray[np.float64],
    cfg: ScaleConfig,
    rng: np.random.Generator,
) -> tuple[float, NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]] | None:
    """eq 3.16 inside RANSAC (appendix B): minimal samples of 3, inliers by the metric residual against a
    depth-dependent threshold, the final similarity refitted on all inliers. None when no sample works."""
    n = len(local)
    if n < 3:
        return None
    thr = cfg.inlier_threshold_m + cfg.inlier_threshold_rel * np.linalg.norm(obj, axis=1)
    # all hypotheses at once; the samples are drawn as one by one (the generator runs on to the next frame
    # exactly as far as a loop that stops at the first hypothesis explaining every point would draw)
    thr2 = thr**2
    state = rng.bit_generator.state
    idx = np.array([rng.choice(n, 3, replace=False) for _ in range(cfg.ransac_iterations)], dtype=np.intp)
    counts = np.full(len(idx), -1)
    a, b, c = obj[idx[:, 0]], obj[idx[:, 1]], obj[idx[:, 2]]
    usable = np.linalg.norm(np.cross(b - a, c - a), axis=1) >= 1e-4
    for lo in range(0, len(idx), _RANSAC_BATCH):
        k = np.flatnonzero(usable[lo : lo + _RANSAC_BATCH]) + lo
        if len(k) == 0:
            continue
        lam, R, T, _ss = _horn_batch(local[idx[k]], obj[idx[k]], cfg.scale_formula)
        fine = np.isfinite(lam)
        k, lam, R, T = k[fine], lam[fine], R[fine], T[fine]
        diff = obj[None] - (lam[:, None, None] * (local[None] @ R.transpose(0, 2, 1)) + T[:, None, :])
        counts[k] = (np.einsum("kni,kni->kn", diff, diff) < thr2[None]).sum(axis=1)
        if (counts[k] == n).any():
            break
    full = np.flatnonzero(counts == n)
    if len(full):
        rng.bit_generator.state = state
        for _ in range(full[0] + 1):
            rng.choice(n, 3, replace=False)
        counts = counts[: full[0] + 1]
    best: NDArray[np.bool_] | None = None
    if counts.max(initial=-1) > 2:
        j = int(np.argmax(counts))
        lam, R, T = horn_similarity(local[idx[j]], obj[idx[j]], cfg.scale_formula)
        best = np.linalg.norm(obj - (lam * local @ R.T + T), axis=1) < thr
    if best is None:
        return None
    inl = best
    for _ in range(2):  # refit on the inliers, re-select once
        lam, R, T = horn_similarity(local[inl], obj[inl], cfg.scale_formula)
        res = np.linalg.norm(obj - (lam * local @ R.T + T), axis=1)
        new = res < thr
        if new.sum() < 3:
            break
        inl = new
    lam, R, T = horn_similarity(local[inl], obj[inl], cfg.scale_formula)
    return lam, R, T, inl


# ------------------------------------------------------------------------------------ depth at SfM observations


def depth_in_rgb(
    depth_m: NDArray[np.floating],
    calib: Calibration,
    rgb_camera: CameraModel,
    cfg: ScaleConfig,
    radial_k: float = 0.0,
    noise_coef: float = 0.0,
) -> NDArray[np.float32]:
    """The depth image moved into the RGB camera (eq 3.13 back-projection, eq 3.14 IR→RGB): (H, W) z in the
    RGB frame at each RGB pixel of `rgb_camera` (the camera the SfM observations refer to), NaN where no
    depth point lands.

    The depth camera's radial error `radial_k` (inverse depth at the image corners, 1/m, see
    `tasks.register.fusion.RadialDepthError`) is taken out first: a Kinect v1's makes the depth short off
    the image centre, which made every scale short (-0.25 % on the synthetic rooms).

    Several depth points land on one RGB pixel wherever the depth image is the denser (at 320x240 the IR
    focal length is 1.12 times the colour one): the nearest surface wins (occlusion), and the points of
    that surface (within `max_depth_step_m` of the nearest, the window's edge test) are averaged in inverse
    depth, where Kinect noise is even. Keeping only the nearest point, the minimum of several noisy
    readings, made the depth short by about 0.1 %. The surface tolerance grows with the depth's own noise
    (`step_tolerance` with `noise_coef`, see `depth_noise_coefficient`)."""
    d = np.asarray(depth_m)
    stride = cfg.depth_stride or max(1, round(d.shape[1] / 320))
    pts = strided_depth_points(d, calib.ir, stride)
    pts = pts[(pts[:, 2] >= cfg.min_depth_m) & (pts[:, 2] <= cfg.max_depth_m)]
    if radial_k and len(pts):
        pts = remove_radial_error(pts, calib.ir, radial_k)
    pose = calib.ir_to_rgb
    p_rgb = pts if pose is None else pose.apply(pts)
    ui, vi, zz = rgb_camera.pixels(p_rgb)
    w, h = rgb_camera.size
    nearest = np.full((h, w), np.inf)
    np.minimum.at(nearest, (vi, ui), zz)
    near = nearest[vi, ui]
    same = zz <= near + step_tolerance(near, cfg, noise_coef)
    inv_sum = np.zeros((h, w))
    count = np.zeros((h, w))
    np.add.at(inv_sum, (vi[same], ui[same]), 1.0 / zz[same])
    np.add.at(count, (vi[same], ui[same]), 1.0)
    zbuf = np.full((h, w), np.nan, np.float32)
    hit = count > 0
    zbuf[hit] = (count[hit] / inv_sum[hit]).astype(np.float32)
    return zbuf


def remove_radial_error(
    pts: NDArray[np.float64], camera: CameraModel, radial_k: float
) -> NDArray[np.float64]:
    """Depth-camera points with the radial inverse-depth error taken out (1/z' = 1/z - k·ρ, ρ the squared
    image radius, 1 at the corners: `tasks.register.fusion.frame_points`' correction); each point slides
    along its ray. Points the correction would more than double (a k far beyond any sensor's) are
    dropped."""
    denom = 1.0 - radial_k * radial_position(pts, camera) * pts[:, 2]
    ok = denom > 0.5
    return pts[ok] / denom[ok, None]


def depth_noise_coefficient(depth_m: NDArray[np.floating]) -> float:
    """How much a depth image's readings spread on its own surfaces, per squared metre of range: the median
    over 3x3 windows holding nine readings of (max - min) / z² (m per m²; 0 when no window is complete).
    A disparity sensor's noise and quantization grow with z² (a Kinect v1's depth steps are 3-4 cm at
    3.5 m); for a low-noise sensor the value is small and the fixed tolerance rules."""
    import cv2

    # the depth's own precision (a float32 image stays float32: max and min are exact in it)
    d = np.asarray(depth_m)
    d = d if d.dtype == np.float32 else d.astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0)
    box = np.ones((3, 3), np.uint8)
    hi = cv2.dilate(np.where(valid, d, np.inf), box, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)
    lo = cv2.erode(np.where(valid, d, -np.inf), box, borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    ok = valid & np.isfinite(hi) & np.isfinite(lo)
    if not ok.any():
        return 0.0
    dd = d[ok].astype(np.float64)
    return float(np.median((hi[ok].astype(np.float64) - lo[ok]) / dd**2))


def step_tolerance(z: NDArray[np.float64], cfg: ScaleConfig, noise_coef: float = 0.0) -> NDArray[np.float64]:
    """The largest depth spread (m) at range z still taken as one surface: `max_depth_step_m`, or
    `step_noise_factor` times the depth's own spread there (`noise_coef` · z², `depth_noise_coefficient`)
    where that is larger. A fixed tolerance below the noise drops the windows whose noise happens to spread
    far, which keeps the nearer-reading ones (the nearest of noisy readings is short)."""
    return np.maximum(cfg.max_depth_step_m, cfg.step_noise_factor * noise_coef * np.square(z))


def observation_points(
    uv: NDArray[np.float64],
    zbuf: NDArray[np.float32],
    rgb_camera: CameraModel,
    cfg: ScaleConfig,
    noise_coef: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """(M, 2) observation pixels → ((M, 3) metric points in the RGB frame, (M,) valid). The depth is the
    median of the window around the pixel; windows over a depth edge (a spread beyond `step_tolerance`)
    are skipped."""
    h, w = zbuf.shape
    r = cfg.depth_window_px
    ui = np.rint(uv[:, 0]).astype(np.intp)
    vi = np.rint(uv[:, 1]).astype(np.intp)
    offs = np.arange(-r, r + 1)
    du, dv = np.meshgrid(offs, offs)
    uu = np.clip(ui[:, None] + du.ravel()[None], 0, w - 1)
    vv = np.clip(vi[:, None] + dv.ravel()[None], 0, h - 1)
    win = zbuf[vv, uu].astype(np.float64)
    # windows without any depth stay NaN (only the others go to the NaN-skipping reductions: their
    # all-NaN warning is process-wide state, which threads must not toggle)
    seen = np.isfinite(win).any(axis=1)
    z = np.full(len(win), np.nan)
    step = np.full(len(win), np.nan)
    if seen.any():
        z[seen] = np.nanmedian(win[seen], axis=1)
        step[seen] = np.nanmax(win[seen], axis=1) - np.nanmin(win[seen], axis=1)
    with np.errstate(invalid="ignore"):
        flat = step <= step_tolerance(z, cfg, noise_coef)
    valid = np.isfinite(z) & flat & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    rays = rgb_camera.undistort_pixels(uv)
    valid &= np.isfinite(rays).all(axis=1)
    pts = np.column_stack([rays * z[:, None], z])
    return pts, valid


# ------------------------------------------------------------------------------------ the stage


def frame_observations(
    name: str,
    depth_m: NDArray[np.floating],
    sfm: SfmResult,
    calib: Calibration,
    cfg: ScaleConfig,
    radial_k: float = 0.0,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float] | None:
    """One registered frame's SfM points and the metric points its depth gives at their observations
    (the depth without the radial error `radial_k`, see `depth_in_rgb`): ((M, 3) SfM, (M, 3) metric in
    the RGB frame, the depth's noise coefficient); None when the frame has too few usable ones."""
    if name not in sfm.observations or sfm.camera is None:
        return None
    rows, uv = sfm.observations[name]
    if len(rows) < cfg.min_points_per_frame:
        return None
    noise_coef = depth_noise_coefficient(depth_m)
    zbuf = depth_in_rgb(depth_m, calib, sfm.camera, cfg, radial_k, noise_coef)
    obj, valid = observation_points(uv, zbuf, sfm.camera, cfg, noise_coef)
    if valid.sum() < cfg.min_points_per_frame:
        return None
    return sfm.points[rows[valid]], obj[valid], noise_coef


def _fit_frame(
    name: str,
    observed: tuple[NDArray[np.float64], NDArray[np.float64], float],
    sfm: SfmResult,
    cfg: ScaleConfig,
    rng: np.random.Generator,
) -> FrameScale | None:
    """eq 3.16 for one registered frame: its SfM points against their depth points (`frame_observations`);
    None when its similarity explains too few of them."""
    local, obj, noise_coef = observed
    fit = ransac_similarity(local, obj, cfg, rng)
    if fit is None:
        return None
    lam, R, T, inl = fit
    if inl.sum() < max(cfg.min_points_per_frame, cfg.min_inlier_fraction * len(local)):
        return None
    res = np.linalg.norm(obj[inl] - (lam * local[inl] @ R.T + T), axis=1)
    scale = lam
    if cfg.scale_from == "range":
        pose = sfm.cam_from_world[name]
        z_sfm = local[inl] @ pose[2, :3] + pose[2, 3]
        ok = z_sfm > 0
        if ok.sum() < cfg.min_points_per_frame:
            return None
        scale = float(np.median(obj[inl][ok, 2] / z_sfm[ok]))
    return FrameScale(
        name, scale, R, T, len(local), int(inl.sum()), float(np.sqrt((res**2).mean())), noise_coef
    )


def combine_scales(frames: list[FrameScale], cfg: ScaleConfig) -> ScaleReport:
    """Robust combination of the per-frame scales (the thesis averages over frames; the median and a
    trimmed mean resist frames with a bad depth/colour pairing) with the MAD and IQR as spread."""
    if len(frames) < max(cfg.min_frames, 1):
        raise DegenerateInputError(
            f"metric scale needs at least {max(cfg.min_frames, 1)} frames with depth-matched SfM points, "
            f"got {len(frames)}"
        )
    s = np.array([f.scale for f in frames])
    med = float(np.median(s))
    if cfg.combine == "trimmed_mean":
        k = int(len(s) * cfg.trim_fraction)
        srt = np.sort(s)
        value = float(srt[k : len(s) - k].mean()) if len(s) - 2 * k > 0 else med
    else:
        value = med
    mad = float(1.4826 * np.median(np.abs(s - med)))
    q1, q3 = np.percentile(s, [25, 75])
    trend = 0.0
    if len(s) >= 3:
        from scipy.stats import theilslopes

        trend = float(theilslopes(s, np.linspace(0.0, 1.0, len(s)))[0])
    return ScaleReport(
        value,
        mad,
        float(q3 - q1),
        mad / value if value else float("inf"),
        [f.name for f in frames],
        frames,
        trend / value if value else float("inf"),
    )


def estimate_scale(
    sfm: SfmResult,
    depth_frames: Iterable[tuple[str, NDArray[np.floating]]],
    calib: Calibration,
    cfg: ScaleConfig,
    radial_k: float = 0.0,
) -> ScaleReport:
    """The scale stage (eq 3.16, App. A): per-frame Helmert fits of SfM points to depth, combined robustly.

    depth_frames: (frame name as in `sfm`, (H, W) depth in metres of the depth camera, 0/NaN = none),
    streamed; frames that SfM did not register are skipped. radial_k: the depth camera's radial
    inverse-depth error at the image corners (1/m; `tasks.register.fusion.estimate_radial_depth_error` on
    the capture), taken out of the depth before it is compared. Raises DegenerateInputError when no frame
    yields a scale."""
    rng = np.random.default_rng(cfg.random_seed)
    frames = []
    registered = ((name, depth) for name, depth in depth_frames if name in sfm.cam_from_world)

    def observe(frame: tuple[str, NDArray[np.floating]]) -> tuple[str, tuple | None]:
        return frame[0], frame_observations(frame[0], frame[1], sfm, calib, cfg, radial_k)

    # the depth work on the threads; the RANSAC fits in frame order (they share the seeded generator)
    for name, observed in imap_ordered(observe, registered):
        fs = None if observed is None else _fit_frame(name, observed, sfm, cfg, rng)
        if fs is not None:
            frames.append(fs)
    report = combine_scales(frames, cfg)
    report.radial_k_inv_m = float(radial_k)
    report.same_surface_tol_m = float(cfg.max_depth_step_m)
    report.depth_noise_m_at_1m = float(np.median([f.depth_noise_m_at_1m for f in frames]))
    return report


def apply_scale(
    sfm: SfmResult, scale: float, calib: Calibration, anchor: str | None = None
) -> dict[str, NDArray[np.float64]]:
    """Metric depth-camera-to-room poses: name -> (4, 4) T with X_room = T · X_depth (metres).

    The SfM frame is scaled to metres (X_metric = scale · X_sfm); the RGB pose becomes the depth camera's
    through the fixed IR→RGB pose (eq 3.14). The room frame is anchored at the depth camera of `anchor`
    (default: the first registered frame in input order) with x right, y forward, z up (ROOM_FROM_CAMERA_AXES),
    so a level sensor gives a level room."""
    if not sfm.cam_from_world:
        raise DegenerateInputError("no registered frame to place")
    if not np.isfinite(scale) or scale <= 0:
        raise DegenerateInputError(f"metric scale must be a positive number, got {scale}")
    rgb_from_ir = np.eye(4) if calib.ir_to_rgb is None else calib.ir_to_rgb.matrix
    world_from_ir = {}
    for name, T in sfm.cam_from_world.items():
        cam_from_world = T.copy()
        cam_from_world[:3, 3] *= scale
        world_from_ir[name] = np.linalg.inv(cam_from_world) @ rgb_from_ir
    if anchor is None:
        anchor = next(n for n in sfm.names if n in world_from_ir)
    room_from_world = np.eye(4)
    room_from_world[:3, :3] = ROOM_FROM_CAMERA_AXES
    room_from_world = room_from_world @ np.linalg.inv(world_from_ir[anchor])
    return {n: room_from_world @ T for n, T in world_from_ir.items()}
