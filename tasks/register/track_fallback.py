"""Track-based fallback (thesis 3.2.2) when SfM registers too few frames (a texture-poor hallway): each frame
is levelled by its floor normal (3.2.2.4; beyond the thesis, by every plane it sees: a frame close to a
corridor's wall sees no floor), turned toward the next point of the foot-mounted IMU track and
put at the track position (eq 3.17, 3.18), and, when the plan walls are given, its heading corrected by
making its Hough lines parallel to the coarse plan's walls (3.2.2.6); beyond the thesis, the track's drift
over the capture is modelled and every frame fitted to the walls' faces once more."""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from tasks.camera import Calibration, CameraModel
from tasks.cloud import DegenerateInputError
from tasks.lines import angle_difference, angles
from tasks.register.config import RegisterConfig
from tasks.register.fusion import frame_points, radial_position, transform_points
from tasks.register.joint_icp import JointIcpSettings, joint_icp, thin_view
from tasks.register.plan_icp import PlanFit, fit_to_plan, icp_to_plan, plan_faces, wall_lines


def depth_normals(
    depth_m: NDArray[np.floating], camera: CameraModel, step: int | None = None
) -> tuple[NDArray, NDArray]:
    """((N, 3) points, (N, 3) unit normals facing the camera) on a grid of every `step`-th depth pixel
    (default: about 160 columns), the normals from the cross product of neighbouring points' differences."""
    d = np.asarray(depth_m, dtype=np.float64)
    step = step or max(1, round(d.shape[1] / 160))
    rays = camera.pixel_rays()
    z = np.where(np.isfinite(d) & (d > 0), d, np.nan)
    P = np.concatenate([rays * z[..., None], z[..., None]], axis=2)[::step, ::step]
    dx = P[1:-1, 2:] - P[1:-1, :-2]
    dy = P[2:, 1:-1] - P[:-2, 1:-1]
    n = np.cross(dx, dy)
    c = P[1:-1, 1:-1]
    norm = np.linalg.norm(n, axis=2)
    ok = np.isfinite(norm) & (norm > 0) & np.isfinite(c).all(axis=2)
    n = n[ok] / norm[ok][:, None]
    c = c[ok]
    flip = (n * c).sum(axis=1) > 0
    n[flip] *= -1
    return c, n


def _floor_layer(
    pts: NDArray[np.float64], nrm: NDArray[np.float64], cfg: RegisterConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64], int] | None:
    """The floor of one frame: points whose normal is within the tolerance of the vertical, facing the
    camera from below, are candidates; the lowest layer of them is fitted with a plane, and the fit is
    refined with a halved tolerance on each pass. Returns ((3,) up direction in the camera frame, (3,) a
    point of the layer, layer points) or None when too few layer points are seen."""
    up = np.array([0.0, -1.0, 0.0])  # a level camera's up is minus the image y
    tol = np.radians(cfg.floor_angle_tol_deg)
    layer, c = None, np.zeros(3)
    for _ in range(max(cfg.floor_passes, 1)):
        cand = nrm @ up > np.cos(tol)
        if cand.sum() < cfg.floor_min_points:
            return None
        h = -(pts[cand] @ up)  # height below the camera
        # the floor is the lowest horizontal layer (tables and seats lie above it)
        layer = pts[cand][h > np.percentile(h, 90) - 0.15]
        if len(layer) < cfg.floor_min_points:
            return None
        c = layer.mean(axis=0)
        _, _, vt = np.linalg.svd(layer - c, full_matrices=False)
        n = vt[2] if vt[2] @ up > 0 else -vt[2]
        res = np.abs((layer - c) @ n)
        inl = res < max(3.0 * np.median(res), 0.01)
        c = layer[inl].mean(axis=0)
        _, _, vt = np.linalg.svd(layer[inl] - c, full_matrices=False)
        up = vt[2] if vt[2] @ up > 0 else -vt[2]
        tol = tol / 2
    return up, c, len(layer)


def level_frame(
    depth_m: NDArray[np.floating],
    camera: CameraModel,
    cfg: RegisterConfig,
    normals: tuple[NDArray, NDArray] | None = None,
) -> tuple[NDArray[np.float64], float, int] | None:
    """The floor of one frame (3.2.2.4), see `_floor_layer`. Returns ((3,) up direction in the camera
    frame, camera height above the floor (m), floor points) or None when too few floor points are seen.
    `normals`: the frame's `depth_normals`, when already computed."""
    pts, nrm = normals or depth_normals(depth_m, camera)
    if len(pts) < cfg.floor_min_points:
        return None
    fit = _floor_layer(pts, nrm, cfg)
    if fit is None:
        return None
    up, c, n = fit
    height = float(-(c @ up))
    if height <= 0:
        return None
    return up, height, n


@dataclass(frozen=True)
class FramePlane:
    """A plane one frame sees (camera frame): unit normal, (3, 3) covariance of that normal from the fit,
    the inliers' weighted centroid and their count."""

    normal: NDArray[np.float64]
    cov: NDArray[np.float64]
    centre: NDArray[np.float64]
    points: int


def _fit_plane(
    q: NDArray[np.float64], sigma: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Weighted (1/sigma^2) least-squares plane of (N, 3) points: (unit normal, centroid, (3, 3) covariance of
    the normal, scaled up by the residuals' reduced chi-square when they spread more than `sigma` says)."""
    w = 1.0 / sigma**2
    c = (w[:, None] * q).sum(axis=0) / w.sum()
    vals, vecs = np.linalg.eigh(((q - c) * w[:, None]).T @ (q - c))
    n = vecs[:, 0]
    chi2 = float((w * ((q - c) @ n) ** 2).sum()) / max(len(q) - 3, 1)
    cov = (vecs[:, 1:] / np.maximum(vals[1:], 1e-12)) @ vecs[:, 1:].T * max(chi2, 1.0)
    return n, c, cov


def _thin(points: NDArray[np.floating], cfg: RegisterConfig) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=np.float64)
    return p[:: max(1, int(np.ceil(len(p) / max(cfg.level_max_points, 1))))]


def _ransac_plane(
    p: NDArray[np.float64], band: NDArray[np.float64], min_points: int, rng: np.random.Generator
) -> NDArray[np.bool_] | None:
    """Inlier mask of the plane through 3 of the (N, 3) points that most points lie within their `band` of
    (300 draws), refined by weighted fits (three bands' width as the standard deviation); None below
    `min_points` inliers."""
    if len(p) < max(min_points, 3):
        return None
    tri = p[rng.integers(0, len(p), size=(300, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    n = n[ok] / norm[ok, None]
    inside = np.abs(p @ n.T - (tri[ok, 0] * n).sum(axis=1)) < band[:, None]
    count = inside.sum(axis=0)
    k = int(np.argmax(count))
    inl = inside[:, k]
    for _ in range(3):
        if inl.sum() < min_points:
            return None
        n1, c, _ = _fit_plane(p[inl], band[inl] / 3.0)
        inl = np.abs((p - c) @ n1) < band
    return inl if inl.sum() >= min_points else None


def depth_noise_scale(depth_m: NDArray[np.floating], step: int = 1) -> float:
    """A depth camera's noise at 1 m range (m) as one frame shows it, for a noise that grows with the square of
    the range (a Kinect's: a constant disparity noise): a plane's inverse depth is linear in the image, so
    the second differences of 1/z along the rows and the columns (every `step`-th pixel) are noise alone
    but at edges, and their robust spread over sqrt(6) is the inverse depth's noise, which is the noise at
    1 m. 0 when the frame has too few valid pixels."""
    d = np.asarray(depth_m, dtype=np.float64)[::step, ::step]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(np.isfinite(d) & (d > 0), 1.0 / d, np.nan)
    d2 = np.concatenate(
        [(inv[:, :-2] - 2 * inv[:, 1:-1] + inv[:, 2:]).ravel(), (inv[:-2] - 2 * inv[1:-1] + inv[2:]).ravel()]
    )
    d2 = d2[np.isfinite(d2)]
    return float(1.4826 * np.median(np.abs(d2)) / np.sqrt(6.0)) if len(d2) >= 100 else 0.0


def frame_planes(points: NDArray[np.floating], noise_m_at_1m: float, cfg: RegisterConfig) -> list[FramePlane]:
    """Beyond the thesis: the planes one frame sees (camera frame (N, 3) points within the depth range), for
    `level_by_planes`: sequential RANSAC, largest first, each refined by a weighted fit, the inlier band
    three standard deviations of the capture's depth noise (`noise_m_at_1m` z^2 + 1 mm, `depth_noise_scale`;
    at least 2 mm at 1 m: a depth camera's surfaces are rarely flatter, and a real wall is not a plane).
    Deterministic (fixed seed). Returns the planes with at least `level_plane_min_points` inliers."""
    p = _thin(points, cfg)
    sigma = max(noise_m_at_1m, 0.002) * p[:, 2] ** 2 + 0.001
    rng = np.random.default_rng(0)
    planes: list[FramePlane] = []
    left = np.arange(len(p))
    while (inl := _ransac_plane(p[left], 3.0 * sigma[left], cfg.level_plane_min_points, rng)) is not None:
        n, c, cov = _fit_plane(p[left[inl]], sigma[left[inl]])
        planes.append(FramePlane(n, cov, c, int(inl.sum())))
        left = left[~inl]
    return planes


def level_by_planes(
    planes: list[FramePlane], prior_up: NDArray[np.float64], cfg: RegisterConfig
) -> tuple[NDArray[np.float64], str, float]:
    """Beyond the thesis: the up direction (camera frame) of one frame from the planes it sees
    (`frame_planes`): a floor's or a ceiling's normal is up, every wall's is perpendicular to it. A frame
    seeing neither floor nor ceiling (a camera close to a corridor's wall) is levelled by its walls: one
    fixes the tilt across it, a second one seen at an angle (a far end wall, a door's reveal) the rest.
    Planes classed by `prior_up` (the capture's median up, `level_max_tilt_deg`); among the up directions
    they suggest (a horizontal plane's normal, the cross product of two walls, the prior made
    perpendicular to a wall, the prior), the one whose agreeing planes (`level_plane_tol_deg`) hold most
    points is refined by weighted least squares on them and the prior (`level_prior_deg`), the weights
    from each plane's fit (`level_plane_sd_deg` added). Returns (up, how it was fixed: "floor", "ceiling",
    "walls" (two directions or more), "wall" (one) joined by "+", or "median" when no plane agreed; the
    standard deviation (degrees) of the up in its least pinned direction, without the prior)."""
    prior = np.asarray(prior_up, dtype=np.float64) / np.linalg.norm(prior_up)
    tilt = np.radians(cfg.level_max_tilt_deg)
    floor_var = np.radians(cfg.level_plane_sd_deg) ** 2
    tol = np.radians(cfg.level_plane_tol_deg)
    vertical = [pl for pl in planes if abs(pl.normal @ prior) < np.sin(tilt)]
    horizontal = [pl for pl in planes if abs(pl.normal @ prior) > np.cos(tilt)]

    def misfit(pl: FramePlane, u: NDArray[np.float64], vert: bool) -> tuple[float, float]:
        """(angle off, its standard deviation) of a plane against the up u, radians."""
        if vert:
            return float(np.arcsin(min(abs(pl.normal @ u), 1.0))), float(np.sqrt(u @ pl.cov @ u + floor_var))
        var = 0.5 * float(np.trace(pl.cov)) + floor_var
        return float(np.arccos(min(abs(pl.normal @ u), 1.0))), float(np.sqrt(var))

    def agreeing(u: NDArray[np.float64]) -> list[tuple[FramePlane, bool]]:
        out = []
        for group, vert in ((vertical, True), (horizontal, False)):
            for pl in group:
                off, sd = misfit(pl, u, vert)
                if off <= max(tol, 3.0 * sd):
                    out.append((pl, vert))
        return out

    candidates = [prior]
    candidates += [pl.normal * np.sign(pl.normal @ prior) for pl in horizontal]
    candidates += [prior - (prior @ pl.normal) * pl.normal for pl in vertical]
    for a, b in itertools.combinations(vertical, 2):
        if abs(a.normal @ b.normal) < np.cos(np.radians(20.0)):
            c = np.cross(a.normal, b.normal)
            candidates.append(c * np.sign(c @ prior))
    candidates = [c / np.linalg.norm(c) for c in candidates if c @ prior / np.linalg.norm(c) > np.cos(tilt)]
    support = [sum(pl.points for pl, _ in agreeing(c)) for c in candidates]
    u = candidates[int(np.argmax(support))]
    info = np.zeros((2, 2))
    used: list[tuple[FramePlane, bool]] = []
    for _ in range(3):
        used = agreeing(u)
        # tangent basis at u; the up is u + E delta, normalised
        e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        E = np.stack([e1, np.cross(u, e1)], axis=1)
        info = np.zeros((2, 2))
        g = np.zeros(2)
        for pl, vert in used:
            _, sd = misfit(pl, u, vert)
            if vert:  # n . (u + E delta) = 0
                J = pl.normal @ E
                info += np.outer(J, J) / sd**2
                g -= J * (pl.normal @ u) / sd**2
            else:  # u + E delta = the normal (its tangent components)
                m = pl.normal * np.sign(pl.normal @ u)
                info += np.eye(2) / sd**2
                g += (m @ E) / sd**2
        prior_info = np.eye(2) / np.radians(cfg.level_prior_deg) ** 2
        delta = np.linalg.solve(info + prior_info, g + prior_info @ ((prior - u) @ E))
        u = u + E @ delta
        u /= np.linalg.norm(u)
    weakest = float(np.linalg.eigvalsh(info)[0])
    sd_deg = float(np.degrees(1.0 / np.sqrt(weakest))) if weakest > (2.0 / np.pi) ** 2 else float("inf")
    kinds = []
    heights = [float(pl.centre @ u) for pl, vert in used if not vert]
    if any(h < 0 for h in heights):
        kinds.append("floor")
    if any(h > 0 for h in heights):
        kinds.append("ceiling")
    walls = [pl.normal for pl, vert in used if vert]
    if walls:
        spread = np.linalg.eigvalsh(sum(np.outer(n, n) for n in walls))
        kinds.append("walls" if spread[1] > 0.1 * spread[2] else "wall")
    return u, "+".join(kinds) or "median", sd_deg


def _interp_track(track: NDArray[np.float64], t_ns: int) -> NDArray[np.float64]:
    t = track[:, 0].astype(np.float64)
    return np.array([np.interp(float(t_ns), t, track[:, 1]), np.interp(float(t_ns), t, track[:, 2])])


def track_heading(track: NDArray[np.float64], t_ns: int, min_step_m: float) -> float:
    """eq 3.17: the direction from the track position at `t_ns` to the next track point at least
    `min_step_m` away (the last heading before it at the end of the track), radians."""
    here = _interp_track(track, t_ns)
    later = track[track[:, 0] > t_ns, 1:3]
    far = np.linalg.norm(later - here, axis=1) >= min_step_m
    if far.any():
        d = later[np.argmax(far)] - here
    else:
        earlier = track[track[:, 0] <= t_ns, 1:3]
        far = np.linalg.norm(earlier - here, axis=1) >= min_step_m
        if not far.any():
            raise DegenerateInputError("the IMU track does not move: no heading for the fallback (eq 3.17)")
        d = here - earlier[np.flatnonzero(far)[-1]]
    return float(np.arctan2(d[1], d[0]))


def track_pose(
    up_cam: NDArray[np.float64], height_m: float, yaw_rad: float, xy: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Depth camera → plan (4, 4) from the levelling (up in the camera frame, camera height) and eq 3.17-3.18:
    the camera's optical axis, levelled, points along `yaw_rad`; the camera stands at `xy`, `height_m` above
    the floor (z = 0)."""
    u = up_cam / np.linalg.norm(up_cam)
    f = np.array([0.0, 0.0, 1.0]) - u[2] * u
    f /= np.linalg.norm(f)
    left = np.cross(u, f)
    cam_basis = np.stack([f, left, u], axis=1)  # columns: forward, left, up in camera coordinates
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    world_basis = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # the same directions in the plan
    T = np.eye(4)
    T[:3, :3] = world_basis @ cam_basis.T
    T[:3, 3] = [xy[0], xy[1], height_m]
    return T


def place_by_track(
    frames: Iterable[tuple[int, int, NDArray[np.floating]]],
    track: NDArray[np.float64],
    calibration: Calibration,
    cfg: RegisterConfig,
    plan_walls: NDArray[np.float64] | None = None,
    radial_k: float = 0.0,
) -> tuple[dict[int, NDArray[np.float64]], dict[str, Any]]:
    """The track-based fallback (3.2.2): frames (frame_id, t_ns, (H, W) depth m) are levelled by their floor
    (3.2.2.4), placed by the track (eq 3.17 heading toward the next track point, eq 3.18 translation) and,
    with plan walls ((M, 4) x0 y0 x1 y1 or (M, 5) with thickness, plan frame), their heading corrected by
    line parallelism (3.2.2.6); then, beyond the thesis and with `cfg.track_joint_icp` (on by
    default), all frames aligned to each other by a joint ICP (`joint_icp`) on their points with the
    capture's radial depth error `radial_k` (1/m at the image corner, `RadialDepthError`) taken out.
    Returns (frame_id -> (4, 4) depth camera → plan, metrics)."""
    track = np.asarray(track, dtype=np.float64)
    if track.ndim != 2 or track.shape[1] != 3 or len(track) < 2:
        raise DegenerateInputError(f"the IMU track must be (K>=2, 3) t_ns x y, got shape {track.shape}")
    track = track[np.argsort(track[:, 0])]
    use_plan = plan_walls is not None and len(plan_walls) > 0
    levels, times, cam_points, views = _level_frames(frames, calibration, cfg, use_plan, radial_k)
    fits = [v for v in levels.values() if v.height is not None]
    if not fits:
        raise DegenerateInputError(
            f"no floor found in any of {len(levels)} frames: cannot level them for the fallback"
        )
    default_up = np.median(np.array([f.up for f in fits]), axis=0)
    default_up /= np.linalg.norm(default_up)
    default_h = float(np.median([f.height for f in fits]))
    for v in levels.values():
        v.up, v.source, v.sd_deg = level_by_planes(v.planes, default_up, cfg)
    t_lo, t_hi = track[0, 0], track[-1, 0]
    inside = [f for f in times if t_lo <= times[f] <= t_hi]
    start = _TrackStart(track, times, levels, default_up, default_h, cfg)
    poses = {fid: start.pose(fid, np.zeros(2)) for fid in inside}
    angles: dict[int, float] = {}
    restarted = searched = 0
    drift_metrics: dict[str, Any] = {}
    mutual_metrics: dict[str, Any] = {}
    if use_plan:
        plan = _PlanPlacement(start, cam_points, np.asarray(plan_walls, dtype=np.float64), inside, poses)
        restarted = plan.restart_from_neighbours()
        searched = plan.search_headings()
        if cfg.track_drift_model and inside:
            drift_metrics = plan.fit_drift_model()
        if cfg.track_mutual_check and inside:
            mutual_metrics = plan.check_with_neighbours()
            inside = [f for f in inside if f not in set(mutual_metrics["unplaced"])]
        poses = {f: plan.fit[f].T for f in inside}
        angles = {f: plan.fit[f].angle + plan.starts[f] for f in inside}
    joint_metrics: dict[str, Any] = {}
    if cfg.track_joint_icp and use_plan:
        # without the plan the headings are the walk's (eq 3.17), tens of degrees off: beyond an ICP's reach
        settings = JointIcpSettings(
            iterations=cfg.track_joint_iterations, max_dist_m=tuple(cfg.track_joint_max_dist_m)
        )
        poses, joint_metrics = joint_icp(views, poses, settings)
    metrics = {
        "track_frames": len(poses),
        "frames_outside_track": len(times) - len(inside),
        "frames_with_own_floor_height": len(fits),
        "levelling": _levelling_metrics(levels),
        "frames_restarted_from_neighbours": restarted,
        "frames_heading_searched": searched,
        "camera_height_m": default_h,
        "heading_corrections_deg": [round(float(np.degrees(angles.get(f, 0.0))), 2) for f in inside],
        "drift_model": drift_metrics,
        "mutual_check": mutual_metrics,
        "joint_icp": joint_metrics,
    }
    return poses, metrics


@dataclass
class _Level:
    """How one frame is levelled: its points (thinned, until its planes are found), the depth noise it
    shows (`depth_noise_scale`), its floor's up and camera height when it sees the floor
    (`level_frame`; else the capture's median height), the planes it sees (`frame_planes`), and its up
    direction from them (`level_by_planes`) with how that was fixed and how well."""

    points: NDArray[np.float32]
    noise_m_at_1m: float
    up: NDArray[np.float64] | None = None
    height: float | None = None
    planes: list[FramePlane] = field(default_factory=list)
    source: str = ""
    sd_deg: float = float("inf")


def _levelling_metrics(levels: dict[int, _Level]) -> dict[str, Any]:
    """How the frames were levelled: frames per source, and per frame (id) its source, the planes it saw and
    the standard deviation (degrees) of its up in the least pinned direction from its planes alone."""
    by: dict[str, int] = {}
    for v in levels.values():
        by[v.source] = by.get(v.source, 0) + 1
    noise = [v.noise_m_at_1m for v in levels.values() if v.noise_m_at_1m > 0]
    return {
        "by": dict(sorted(by.items())),
        "frames": {
            str(f): [v.source, len(v.planes), round(v.sd_deg, 2) if np.isfinite(v.sd_deg) else None]
            for f, v in sorted(levels.items())
        },
        "depth_noise_m_at_1m": round(float(np.median(noise)), 5) if noise else None,
    }


def _level_frames(
    frames: Iterable[tuple[int, int, NDArray[np.floating]]],
    calibration: Calibration,
    cfg: RegisterConfig,
    use_plan: bool,
    radial_k: float = 0.0,
) -> tuple[
    dict[int, _Level],
    dict[int, int],
    dict[int, NDArray[np.float64]],
    dict[int, tuple[NDArray[np.float32], NDArray[np.float32]]],
]:
    """One pass over the frames: each one's floor height and planes for the levelling,
    its time, when the plan is used its thinned (N, 3) depth-camera points for the wall-line work, and
    its thinned points with normals (camera frame, within the depth range) for the joint ICP."""
    levels: dict[int, _Level] = {}
    times: dict[int, int] = {}
    # wall-line work needs each frame's points (thinned) once more after all frames are levelled
    line_cfg = RegisterConfig(**{**cfg.__dict__, "pixel_stride": max(cfg.pixel_stride, 3)})
    cam_points: dict[int, NDArray[np.float64]] = {}
    views: dict[int, tuple[NDArray[np.float32], NDArray[np.float32]]] = {}
    for frame_id, t_ns, depth in frames:
        fid = int(frame_id)
        normals = depth_normals(depth, calibration.ir)  # shared by the floor's and the ceiling's fit
        lv = level_frame(depth, calibration.ir, cfg, normals)
        pts = _thin(_in_range(normals[0], calibration, cfg, radial_k), cfg).astype(np.float32)
        noise = depth_noise_scale(depth, max(1, round(depth.shape[1] / 160)))
        levels[fid] = _Level(pts, noise, *(lv[:2] if lv is not None else (None, None)))
        times[fid] = int(t_ns)
        if use_plan:
            cam_points[fid] = frame_points(depth, calibration, line_cfg).astype(np.float32)
        if use_plan and cfg.track_joint_icp:
            views[fid] = _joint_view(normals, calibration, cfg, radial_k)
    # the planes' inlier band from the capture's depth noise (a frame's own estimate is noisy)
    noise = [v.noise_m_at_1m for v in levels.values() if v.noise_m_at_1m > 0]
    s = float(np.median(noise)) if noise else 0.0
    for v in levels.values():
        v.planes, v.points = frame_planes(v.points, s, cfg), np.zeros((0, 3))
    return levels, times, cam_points, views


def _joint_view(
    normals: tuple[NDArray, NDArray], calibration: Calibration, cfg: RegisterConfig, radial_k: float
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """A frame's points and normals (`depth_normals`) within the depth range, thinned, with the radial
    inverse-depth error taken out (1/z' = 1/z - k rho: every point slides along its ray), for the joint ICP."""
    pts, nrm = normals
    keep = (pts[:, 2] >= cfg.min_depth_m) & (pts[:, 2] <= cfg.max_depth_m)
    pts, nrm = thin_view(pts[keep], nrm[keep], JointIcpSettings.max_points)
    if radial_k and len(pts):
        p = pts.astype(np.float64)
        denom = 1.0 - radial_k * radial_position(p, calibration.ir) * p[:, 2]
        ok = denom > 0.5
        pts, nrm = (p[ok] / denom[ok, None]).astype(np.float32), nrm[ok]
    return pts, nrm


def _in_range(
    pts: NDArray[np.floating], calibration: Calibration, cfg: RegisterConfig, radial_k: float
) -> NDArray[np.float64]:
    """A frame's (N, 3) points within the depth range, the radial inverse-depth error taken out (as
    `_joint_view`), for `frame_planes`: the error bends a far wall seen near the image's corners."""
    p = np.asarray(pts, dtype=np.float64)
    p = p[(p[:, 2] >= cfg.min_depth_m) & (p[:, 2] <= cfg.max_depth_m)]
    if radial_k and len(p):
        denom = 1.0 - radial_k * radial_position(p, calibration.ir) * p[:, 2]
        ok = denom > 0.5
        p = p[ok] / denom[ok, None]
    return p


class _TrackStart:
    """Where the track puts a frame (eq 3.17-3.18), levelled by its planes (`level_by_planes`) at its own
    floor's height or the capture's median one."""

    def __init__(
        self,
        track: NDArray[np.float64],
        times: dict[int, int],
        levels: dict[int, _Level],
        default_up: NDArray[np.float64],
        default_h: float,
        cfg: RegisterConfig,
    ) -> None:
        self.track, self.times, self.levels = track, times, levels
        self.default_up, self.default_h, self.cfg = default_up, default_h, cfg

    def position(self, fid: int) -> NDArray[np.float64]:
        """(2,) the track's position at the frame's time."""
        return _interp_track(self.track, self.times[fid])

    def pose(self, fid: int, offset: NDArray[np.float64], dyaw: float = 0.0) -> NDArray[np.float64]:
        """(4, 4) depth camera → plan at the track position + `offset`, turned by `dyaw` from eq 3.17."""
        lv = self.levels[fid]
        up = self.default_up if lv.up is None else lv.up
        h = self.default_h if lv.height is None else lv.height
        yaw = track_heading(self.track, self.times[fid], self.cfg.track_min_step_m) + dyaw
        return track_pose(up, h, yaw, self.position(fid) + offset)


class _PlanPlacement:
    """The frames' fits to the plan walls (3.2.2.6) and the passes that improve them: restarts from the
    neighbours' track drift, other start headings, and the capture's drift model with an ICP refit."""

    def __init__(
        self,
        start: _TrackStart,
        cam_points: dict[int, NDArray[np.float64]],
        walls: NDArray[np.float64],
        inside: list[int],
        poses: dict[int, NDArray[np.float64]],
    ) -> None:
        self.start, self.cam_points, self.walls, self.cfg = start, cam_points, walls, start.cfg
        self.fit = {fid: fit_to_plan(poses[fid], cam_points[fid], walls, self.cfg) for fid in inside}
        self.starts = dict.fromkeys(inside, 0.0)
        self.order = sorted(inside, key=lambda f: start.times[f])

    def drift_of(self, f: int) -> NDArray[np.float64]:
        """(2,) the frame's plan-fitted position less the track's."""
        return self.fit[f].T[:2, 3] - self.start.position(f)

    def neighbour_drift(self, k: int) -> NDArray[np.float64] | None:
        """Median drift of the two frames either side of the k-th in time (None when there are none)."""
        order = self.order
        near = [self.drift_of(order[j]) for j in (k - 2, k - 1, k + 1, k + 2) if 0 <= j < len(order)]
        return np.median(np.array(near), axis=0) if near else None

    def merit(self, score: float, drift: NDArray[np.float64], prior: NDArray[np.float64] | None) -> float:
        """Agreement with the plan, less a penalty for leaving the drift of the neighbours: a frame that
        sees one corridor wall fits the plan as well one corridor width off."""
        return score - (
            0.0 if prior is None else self.cfg.drift_penalty_m_per_m * float(np.linalg.norm(drift - prior))
        )

    def retry(
        self, fid: int, offset: NDArray[np.float64], dyaw: float, prior: NDArray[np.float64] | None
    ) -> bool:
        """Fit the frame again from another start; kept (True) when its merit is clearly better."""
        cfg, fit = self.cfg, self.fit
        new = fit_to_plan(self.start.pose(fid, offset, dyaw), self.cam_points[fid], self.walls, cfg)
        gain = self.merit(new.score, new.T[:2, 3] - self.start.position(fid), prior)
        if gain > self.merit(fit[fid].score, self.drift_of(fid), prior) + 0.5 * cfg.line_min_length_m:
            fit[fid], self.starts[fid] = new, dyaw
            return True
        return False

    def fits_well(self, f: int) -> bool:
        return self.fit[f].score >= self.cfg.line_good_fraction * self.fit[f].length

    def restart_from_neighbours(self) -> int:
        """A frame whose wall lines lay too far from the plan for its position to be fixed starts again from
        the track drift its neighbours in time measured (the drift changes slowly); the placement whose
        lines agree better with the plan is kept. Returns how many restarts were kept."""
        order, restarted = self.order, 0
        for _sweep in range(2):
            for k, fid in enumerate(order):
                for j in (k - 1, k + 1, k - 2, k + 2):
                    if (
                        0 <= j < len(order)
                        and np.linalg.norm(self.drift_of(order[j]) - self.drift_of(fid))
                        >= self.cfg.track_restart_min_shift_m
                    ):
                        restarted += self.retry(fid, self.drift_of(order[j]), self.starts[fid], None)
        return restarted

    def search_headings(self) -> int:
        """Frames still fitting poorly may look far off the walking direction (eq 3.17): other start
        headings are tried, and kept only when the frame then fits the plan well. Returns the frames
        searched."""
        fit, starts, searched = self.fit, self.starts, 0
        for k, fid in enumerate(self.order):
            if self.fits_well(fid):
                continue
            searched += 1
            keep = (fit[fid], starts[fid])
            offset = self.drift_of(fid)
            changed = False
            for step in self.cfg.heading_search_deg:
                for sign in (1.0, -1.0):
                    changed |= self.retry(fid, offset, sign * np.radians(step), self.neighbour_drift(k))
            if changed and not self.fits_well(fid):
                fit[fid], starts[fid] = keep
        return searched

    def fit_drift_model(self) -> dict[str, Any]:
        """One drift model for the whole capture (`track_drift`): each frame pins its position only across the
        walls it sees (along a corridor it is free), so the frames that see end walls or door jambs correct
        the track's scale and heading drift for all the others. Placed by the model, every frame is fitted
        to the wall faces point by point (ICP): short wall pieces and door jambs that gave no Hough line then
        pin it along a corridor too, and the model is fitted again. Returns the model's metrics."""
        cfg, fit, order = self.cfg, self.fit, self.order
        xy = np.array([self.start.position(f) for f in order])
        t_s = np.array([self.start.times[f] for f in order], dtype=np.float64) * 1e-9
        placed = np.array([fit[f].T[:2, 3] for f in order])
        good = [self.fits_well(f) and fit[f].score >= cfg.line_min_length_m for f in order]
        info = np.array(
            [
                _pinning(fit[f].information, cfg.track_pin_length_m) if g else np.zeros((2, 2))
                for f, g in zip(order, good, strict=True)
            ]
        )
        base = dict(fit)
        faces = plan_faces(self.walls)
        reach = cfg.track_refit_max_shift_m
        drift_metrics: dict[str, Any] = {}
        for _round in range(cfg.track_drift_rounds):
            model, drift_metrics = track_drift(xy, t_s, placed, info, cfg)
            refitted = 0
            for k, (f, p) in enumerate(zip(order, model, strict=True)):
                refitted += self._refit(k, f, p, base[f], faces, reach, placed, info)
            drift_metrics["frames_refitted"] = refitted
            # a frame the walls pull far from a model that fits the others well matched a wrong wall
            spread = drift_metrics["residual_spread_m"] or reach
            reach = min(cfg.track_refit_max_shift_m, max(3 * spread, 2 * cfg.track_drift_sigma_m))
        return drift_metrics

    def _refit(
        self,
        k: int,
        f: int,
        p: NDArray[np.float64],
        base: PlanFit,
        faces: tuple[NDArray[np.float64], NDArray[np.float64]],
        reach: float,
        placed: NDArray[np.float64],
        info: NDArray[np.float64],
    ) -> bool:
        """The k-th frame (id f) put at the drift model's position p and fitted to the wall faces by ICP;
        kept (True) when it moves at most `reach`. Updates its fit and its row of `placed` and `info`."""
        cfg = self.cfg
        T0 = base.T.copy()
        T0[:2, 3] = p
        T1, H, n, total = icp_to_plan(T0, self.cam_points[f], faces, cfg, reach)
        if n < cfg.line_good_fraction * total:
            # placed well, a frame fitting the walls poorly looks elsewhere than its start heading
            # says (eq 3.17 follows the walk): all headings are tried
            for dyaw in np.radians(np.arange(30.0, 360.0, 30.0)):
                T2, H2, n2, _ = icp_to_plan(_turn(T0, dyaw), self.cam_points[f], faces, cfg, reach)
                if n2 > max(n, cfg.line_good_fraction * total):
                    T1, H, n = T2, H2, n2
        shift = float(np.linalg.norm(T1[:2, 3] - p))
        if n >= 10 and shift <= reach:
            turned = T1[:3, :3] @ base.T[:3, :3].T
            self.fit[f] = base._replace(T=T1, angle=base.angle + np.arctan2(turned[1, 0], turned[0, 0]))
            placed[k], info[k] = T1[:2, 3], _pinning(H, cfg.track_pin_length_m / cfg.line_cell_m)
            return True
        self.fit[f] = base._replace(T=T0)
        placed[k], info[k] = p, 0.0
        return False

    def wall_xy(self, f: int, T: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """(N, 2) the frame's wall-band points placed by T (default: its fit), one per `line_cell_m` cell."""
        return wall_band_xy(self.fit[f].T if T is None else T, self.cam_points[f], self.cfg)

    def parallel_to_plan(self, f: int, T: NDArray[np.float64]) -> bool:
        """Whether the frame placed by T has most of its wall lines (`line_good_fraction` of their length)
        within 2 degrees of a plan wall's direction (3.2.2.6: the heading is that of the plan's walls; a
        frame seeing a corner close up fits the other frames' points turned by some degrees as well)."""
        lines = wall_lines(transform_points(T, np.asarray(self.cam_points[f], dtype=np.float64)), self.cfg)
        if len(lines) == 0:
            return False
        turn = angle_difference(angles(lines)[:, None], angles(self.walls[:, :4])[None])
        along = (np.abs(turn) <= np.radians(2.0)).any(axis=1)
        length = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
        return bool(length[along].sum() >= self.cfg.line_good_fraction * length.sum())

    def check_with_neighbours(self) -> dict[str, Any]:
        """Beyond the thesis: each frame's placement checked against the other frames' depth, not the plan.
        A frame whose wall points land on the walls the other frames saw (`agreement`) for less than half
        the share the capture's frames do as a rule matched the coarse plan with a wrong heading (a corner or
        a corridor's end fits the plan as well turned by a quarter). It is turned about its camera in steps
        of 30 degrees and each start fitted to the others' points (`icp_to_points`); the placement most of
        its points agree on is taken when no distinct placement agrees almost as well (a frame seeing one
        corner close up fits every corner) and its wall lines run along the plan's walls. A frame that then
        still agrees with under a quarter of that share is left unplaced: its points would stand in the cloud
        as walls nobody else saw, placed by the coarse plan alone. So is one that a distinct placement
        (`_distinct`) refutes, agreeing at least twice as well and with half the typical share, when that
        placement cannot be taken (a frame too far from its walls to show a wall line cannot be checked
        against the plan's directions). Returns metrics: the capture's median agreement, each frame's
        before and after, the frames turned (degrees), those refuted and those left unplaced."""
        cfg, order = self.cfg, self.order
        tol = cfg.track_mutual_tol_m
        clouds = {f: self.wall_xy(f) for f in order}
        share = {f: agreement(clouds[f], _others(clouds, f), tol) for f in order}
        before = [round(share[f], 2) for f in order]
        typical = float(np.median(list(share.values()))) if share else 0.0
        turned: dict[int, float] = {}
        suspect = {f for f in order if share[f] < 0.5 * typical}
        refuted: set[int] = set()
        for _sweep in range(2):  # the second with the frames the first turned among the reference
            reference = {f: c for f, c in clouds.items() if f not in suspect}
            for f in sorted(suspect, key=lambda g: -share[g]):
                others = _others(reference, f)
                if len(others) < 10:
                    continue
                share[f] = agreement(clouds[f], others, tol)
                tried = []
                for k in range(12):
                    T1 = icp_to_points(
                        _turn(self.fit[f].T, np.radians(30.0 * k)), self.cam_points[f], others, cfg
                    )
                    tried.append((agreement(self.wall_xy(f, T1), others, tol), T1))
                got, best = max(tried, key=lambda c: c[0])
                rivals = [T for g, T in tried if g >= got - 0.1 and _distinct(T, best)]
                if got < max(share[f] + 0.1, 0.5 * typical) or rivals or not self.parallel_to_plan(f, best):
                    # another placement, turned or shifted well away, agreeing twice as well refutes this
                    # one even when it cannot be confirmed itself (a frame too far from its walls to show
                    # a wall line): the frame is left unplaced
                    if got >= max(2.0 * share[f], 0.5 * typical) and _distinct(best, self.fit[f].T):
                        refuted.add(f)
                    continue
                refuted.discard(f)
                rel = best[:3, :3] @ self.fit[f].T[:3, :3].T
                turn = float(np.arctan2(rel[1, 0], rel[0, 0]))
                turned[f] = round(float(np.degrees(turn)) + turned.get(f, 0.0), 1)
                self.fit[f] = self.fit[f]._replace(T=best, angle=self.fit[f].angle + turn)
                clouds[f] = reference[f] = self.wall_xy(f)
                share[f] = got
            suspect = {f for f in suspect if share[f] < 0.5 * typical}
        refuted &= suspect  # those still below half the typical share
        dropped = [f for f in order if share[f] < 0.25 * typical or f in refuted]
        return {
            "median_agreement": round(typical, 3),
            "agreement_before": before,
            "agreement_after": [round(share[f], 2) for f in order],
            "turned_deg": {str(f): v for f, v in turned.items()},
            "refuted": sorted(refuted),
            "unplaced": dropped,
        }


def _distinct(A: NDArray[np.float64], B: NDArray[np.float64]) -> bool:
    """Two placements of one frame differ by more than 10 degrees or 0.2 m."""
    rel = A[:3, :3] @ B[:3, :3].T
    return bool(
        abs(np.arctan2(rel[1, 0], rel[0, 0])) > np.radians(10.0) or np.linalg.norm(A[:2, 3] - B[:2, 3]) > 0.2
    )


def wall_band_xy(T: NDArray[np.float64], points_cam: NDArray, cfg: RegisterConfig) -> NDArray[np.float64]:
    """(N, 2) plan xy of a frame's wall-band points (camera points placed by T), one per `line_cell_m` cell."""
    lo, hi = cfg.wall_band_m
    pts = transform_points(T, np.asarray(points_cam, dtype=np.float64))
    pts = pts[(pts[:, 2] > lo) & (pts[:, 2] < hi), :2]
    if len(pts) == 0:
        return np.zeros((0, 2))
    _, first = np.unique(np.floor(pts / cfg.line_cell_m).astype(np.int64), axis=0, return_index=True)
    return pts[np.sort(first)]


def _others(clouds: dict[int, NDArray[np.float64]], f: int) -> NDArray[np.float64]:
    rest = [c for g, c in clouds.items() if g != f and len(c)]
    return np.vstack(rest) if rest else np.zeros((0, 2))


def agreement(xy: NDArray[np.float64], others: NDArray[np.float64], tol_m: float) -> float:
    """Share of (N, 2) points within `tol_m` of some point of (M, 2) `others` (0 when either is empty)."""
    if len(xy) == 0 or len(others) == 0:
        return 0.0
    d, _ = cKDTree(others).query(xy, distance_upper_bound=tol_m)
    return float(np.isfinite(d).mean())


def icp_to_points(
    T: NDArray[np.float64], points_cam: NDArray, others: NDArray[np.float64], cfg: RegisterConfig
) -> NDArray[np.float64]:
    """2D point-to-point ICP (heading about the camera and position, robust Cauchy weights) of one frame's
    wall-band points onto (M, 2) other frames' wall points, the correspondence distance shrinking from
    `track_refit_max_shift_m` to `track_mutual_tol_m`. Returns the corrected T (depth camera → plan)."""
    p = wall_band_xy(T, points_cam, cfg)
    if len(p) < 10 or len(others) < 10:
        return T
    tree = cKDTree(others)
    c = T[:2, 3].copy()
    R, t = np.eye(2), np.zeros(2)
    for max_d in np.geomspace(cfg.track_refit_max_shift_m, cfg.track_mutual_tol_m, 8):
        q = (p - c) @ R.T + c + t
        d, idx = tree.query(q, distance_upper_bound=float(max_d))
        ok = np.isfinite(d)
        if ok.sum() < 10:
            break
        a, b = q[ok], others[idx[ok]]
        w = 1.0 / (1.0 + (d[ok] / (0.5 * max_d)) ** 2)
        ca, cb = (w[:, None] * a).sum(0) / w.sum(), (w[:, None] * b).sum(0) / w.sum()
        H = ((a - ca) * w[:, None]).T @ (b - cb)
        U, _, Vt = np.linalg.svd(H)
        dR = Vt.T @ U.T
        if np.linalg.det(dR) < 0:
            Vt[1] *= -1
            dR = Vt.T @ U.T
        # q -> dR (q - ca) + cb, expressed as a turn about the camera and a shift
        R = dR @ R
        t = dR @ (c + t - ca) + cb - c
    D = np.eye(4)
    D[:2, :2] = R
    D[:2, 3] = c + t - R @ c
    return D @ T


def _turn(T: NDArray[np.float64], yaw_rad: float) -> NDArray[np.float64]:
    """T (camera → plan) turned by `yaw_rad` about the vertical through the camera."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    D = np.eye(4)
    D[:2, :2] = [[c, -s], [s, c]]
    D[:2, 3] = T[:2, 3] - D[:2, :2] @ T[:2, 3]
    return D @ T


def _pinning(information: NDArray[np.float64], saturation: float) -> NDArray[np.float64]:
    """(2, 2) information (sum of n n^T over lines (by length) or points) → pinning in [0, 1] per direction:
    its eigenvalues divided by `saturation` and capped at 1 (a frame seeing much of one wall is not
    surer of its position than one seeing enough of it: the plan is coarse)."""
    vals, vecs = np.linalg.eigh(np.asarray(information, dtype=np.float64))
    return (vecs * np.clip(vals / saturation, 0.0, 1.0)) @ vecs.T


def track_drift(
    track_xy: NDArray[np.float64],
    t_s: NDArray[np.float64],
    placed_xy: NDArray[np.float64],
    information: NDArray[np.float64],
    cfg: RegisterConfig,
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The track's drift over one capture (beyond the thesis). A foot-mounted IMU's position error over a
    capture comes from its stride-scale error and its heading error, which grows with the gyro bias:
    true increments ≈ s R(ψ0 + ψ1 τ) (track increments), τ the time from the capture's middle. To first
    order in ψ1 that is linear: true_i ≈ c + t + s R(ψ0) (track_i − c) + ψ1 g_i, with
    g_i = R(ψ0) J Σ_{j<i} τ_j Δtrack_j (J: a quarter turn; c: the track's centroid).

    The frames (N, in time order; track positions and times (N,) s) are fitted by iteratively reweighted
    least squares to their plan-fitted positions (N, 2), each counting only in the directions its walls
    pin (`information`, (N, 2, 2) pinning in [0, 1], see `_pinning`; zeros for frames that did not fit),
    with a weak prior at the track itself so that what no frame pins stays as the track has it.
    Returns (the model's positions (N, 2), metrics)."""
    track_xy = np.asarray(track_xy, dtype=np.float64)
    n = len(track_xy)
    c = track_xy.mean(axis=0)
    u = track_xy - c
    tau = np.asarray(t_s, dtype=np.float64) - 0.5 * (np.min(t_s) + np.max(t_s))
    steps = np.diff(track_xy, axis=0) * (0.5 * (tau[1:] + tau[:-1]))[:, None]
    swept = np.vstack([np.zeros(2), np.cumsum(steps, axis=0)])
    swept = np.column_stack([-swept[:, 1], swept[:, 0]])  # J applied
    rows = np.zeros((n, 2, 5))
    rows[:, 0, :4] = np.column_stack([u[:, 0], -u[:, 1], np.ones(n), np.zeros(n)])
    rows[:, 1, :4] = np.column_stack([u[:, 1], u[:, 0], np.zeros(n), np.ones(n)])
    d = np.asarray(placed_xy, dtype=np.float64) - track_xy
    H = np.asarray(information, dtype=np.float64)
    used = np.trace(H, axis1=1, axis2=2) > 0
    sig_r, sig_t = cfg.track_drift_prior
    sig_rate = np.radians(cfg.track_heading_rate_prior_deg_s)
    prior = np.diag([1 / sig_r**2, 1 / sig_r**2, 1 / sig_t**2, 1 / sig_t**2, 1 / sig_rate**2])
    line_var = cfg.track_drift_sigma_m**2
    locked = prior.copy()
    locked[4, 4] = 1e12

    def normal_equations(theta: NDArray, w: NDArray, rate: bool) -> tuple[NDArray, NDArray]:
        psi0 = np.arctan2(theta[1], 1 + theta[0])
        rot = np.array([[np.cos(psi0), -np.sin(psi0)], [np.sin(psi0), np.cos(psi0)]])
        rows[:, :, 4] = swept @ rot.T
        A = (prior if rate else locked) + np.einsum("n,nji,njk,nkl->il", w / line_var, rows, H, rows)
        b = np.einsum("n,nji,njk,nk->i", w / line_var, rows, H, d)
        # the scale s = |(1 + a, b)| near 1, linearized along the current rotation ψ0: the rotation
        # itself is held only by the weak prior above
        radial = np.array([np.cos(psi0), np.sin(psi0)])
        A[:2, :2] += np.outer(radial, radial) / cfg.track_scale_prior**2
        b[:2] += radial * (1.0 - radial[0]) / cfg.track_scale_prior**2
        return A, b

    w = np.ones(n)
    theta = np.zeros(5)
    # the similarity first (its rate locked), then with the heading drift: from the track alone the drift
    # rate is the weakest term and would otherwise absorb the first passes' outliers
    for i, robust_m in enumerate(np.geomspace(16 * cfg.track_drift_sigma_m, 2 * cfg.track_drift_sigma_m, 20)):
        A, b = normal_equations(theta, w, rate=i >= 10)
        theta = np.linalg.solve(A, b)
        r = _pinned_residuals(rows, theta, d, H)
        w = 1.0 / (1.0 + (r / robust_m) ** 2)  # Cauchy, annealed: frames fitted to a wrong wall lose weight
    # A frame that alone pins what the others leave to the priors (the one frame seeing a jamb along a
    # corridor) keeps its Cauchy weight however wrong it is: the model bends to it. Such a frame is
    # tested against the model of all the others (a deletion residual) and dropped when they and the
    # priors put it more than `track_pin_outlier_z` standard deviations from its fitted position.
    rejected: list[int] = []
    for _ in range(n):
        z = _deletion_z(A, b, rows, H, d, w, line_var)
        k = int(np.argmax(z))
        if z[k] <= cfg.track_pin_outlier_z:
            break
        w[k] = 0.0
        rejected.append(k)
        A, b = normal_equations(theta, w, rate=True)
        theta = np.linalg.solve(A, b)
    r = _pinned_residuals(rows, theta, d, H)
    model = track_xy + np.einsum("nij,j->ni", rows, theta)

    eig = np.linalg.eigvalsh(H[used].sum(axis=0)) if used.any() else np.zeros(2)
    metrics = {
        "scale": round(float(np.hypot(1 + theta[0], theta[1])), 5),
        "angle_deg": round(float(np.degrees(np.arctan2(theta[1], 1 + theta[0]))), 3),
        "heading_rate_deg_s": round(float(np.degrees(theta[4])), 4),
        "shift_m": [round(float(v), 4) for v in theta[2:4]],
        "frames_used": int(used.sum()),
        "residual_spread_m": round(float(1.4826 * np.median(r[used])), 4) if used.any() else None,
        "frames_pinned_both_ways": int((np.linalg.eigvalsh(H)[:, 0] > 0.5).sum()),
        "pinning_eigenvalues": [round(float(v), 2) for v in eig],
        "frames_rejected": sorted(rejected),
    }
    return model, metrics


def _pinned_residuals(rows: NDArray, theta: NDArray, d: NDArray, H: NDArray) -> NDArray[np.float64]:
    """(N,) each frame's misfit to the drift model in the directions it pins (m)."""
    e = np.einsum("nij,j->ni", rows, theta) - d
    return np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", e, H, e), 0.0))


def _deletion_z(
    A: NDArray, b: NDArray, rows: NDArray, H: NDArray, d: NDArray, w: NDArray, line_var: float
) -> NDArray[np.float64]:
    """(N,) for each frame with weight, its misfit to the drift model fitted without it, in standard
    deviations (its own position's, `line_var` over its pinning, plus the model's prediction's), in the
    direction it pins worst; 0 for frames without weight or pinning."""
    z = np.zeros(len(d))
    for i in np.flatnonzero((w > 0) & (np.trace(H, axis1=1, axis2=2) > 0)):
        own = w[i] / line_var
        Ai = A - own * rows[i].T @ H[i] @ rows[i]
        bi = b - own * rows[i].T @ H[i] @ d[i]
        cov = np.linalg.inv(Ai)
        e = rows[i] @ (cov @ bi) - d[i]
        lam, vec = np.linalg.eigh(H[i])
        for lv, v in zip(lam, vec.T, strict=True):
            if lv > 0.2:
                var = line_var / lv + v @ rows[i] @ cov @ rows[i].T @ v
                z[i] = max(z[i], abs(float(v @ e)) / np.sqrt(var))
    return z
