"""Fusion (thesis 3.1.3): every placed frame's depth points (eq 3.13) are moved by their pose and streamed
into a voxel grid that keeps per-voxel sums, so memory depends on the room's size, not on the number of
frames. Colours come from `colour_points` (eq 3.14-3.15); a voxel no frame could colour is flagged, never
given a made-up colour. The depth camera's radial error is estimated on the capture and taken out first."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from tasks.camera import Calibration, CameraModel, colour_points, depth_to_points
from tasks.cloud import Cloud, DegenerateInputError, apply_transform
from tasks.register.config import RegisterConfig
from tasks.threads import imap_ordered


@dataclass(frozen=True)
class FusedCloud(Cloud):
    """A fused room cloud: one point per voxel, with the voxel's support."""

    coloured: NDArray[np.bool_] | None = None
    """(N,) whether any frame coloured the voxel; uncoloured voxels carry colour (0, 0, 0) and False here."""
    counts: NDArray[np.int64] | None = None
    """(N,) depth points fused into each voxel."""


class _Voxels:
    """Per-voxel sums, sorted by packed key."""

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)
        self.sums = np.zeros((0, 3))
        self.counts = np.zeros(0, np.int64)
        self.colour_sums = np.zeros((0, 3))
        self.colour_counts = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return len(self.keys)

    def find(self, keys: NDArray[np.int64]) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
        """Where sorted unique `keys` are (or would go), and which are held."""
        pos = np.searchsorted(self.keys, keys)
        held = pos < len(self.keys)
        held[held] = self.keys[pos[held]] == keys[held]
        return pos, held

    def add_at(self, pos: NDArray[np.intp], sums: NDArray, counts: NDArray, csums: Any, ccounts: Any) -> None:
        # pos holds no index twice (a frame's keys are unique): plain fancy-index adds
        self.sums[pos] += sums
        self.counts[pos] += counts
        if csums is not None:
            self.colour_sums[pos] += csums
            self.colour_counts[pos] += ccounts

    def insert(self, other: _Voxels) -> None:
        """Take in the voxels of `other`, none of which is held here (no sum is touched)."""
        if not len(other):
            return
        at = np.searchsorted(self.keys, other.keys)
        self.keys = np.insert(self.keys, at, other.keys)
        self.sums = np.insert(self.sums, at, other.sums, axis=0)
        self.counts = np.insert(self.counts, at, other.counts)
        self.colour_sums = np.insert(self.colour_sums, at, other.colour_sums, axis=0)
        self.colour_counts = np.insert(self.colour_counts, at, other.colour_counts)


class VoxelAccumulator:
    """Per-voxel sums of points and colours, keyed by the packed voxel index: memory grows with the occupied
    volume, not with the number of frames added.

    A frame is reduced to its own voxels first (per-voxel sums in point order) and added to the voxels
    held: the work per frame grows with the frame's voxels, not with the room's. Voxels the room has not
    held yet gather in a small pending set, merged into the sorted main set (a copy of it) only when
    that set has grown by a quarter. Every voxel's sum is the same float sequence as adding the frames one
    after the other, so the cloud does not depend on how the frames were batched."""

    OFFSET = 1 << 20
    """Voxel indices are offset into 21 bits per axis (±1 M voxels: ±20 km at 2 cm)."""
    MERGE_AT = 65536
    """Pending voxels merged into the main set once there are this many (or a quarter of the main set)."""

    def __init__(self, voxel_size_m: float) -> None:
        if voxel_size_m <= 0:
            raise ValueError(f"voxel size must be positive, got {voxel_size_m}")
        self.voxel = float(voxel_size_m)
        self._main = _Voxels()
        self._pending = _Voxels()

    @property
    def keys(self) -> NDArray[np.int64]:
        """The packed keys of the voxels held, sorted."""
        self._merge()
        return self._main.keys

    def _merge(self) -> None:
        self._main.insert(self._pending)
        self._pending = _Voxels()

    def _pack(self, points: NDArray[np.float64]) -> NDArray[np.int64]:
        idx = np.floor(points / self.voxel).astype(np.int64) + self.OFFSET
        if (idx < 0).any() or (idx >= 2 * self.OFFSET).any():
            raise DegenerateInputError("points lie too far from the room origin for the voxel grid")
        return (idx[:, 0] << 42) | (idx[:, 1] << 21) | idx[:, 2]

    def add(
        self,
        points: NDArray[np.float64],
        colors: NDArray[np.uint8] | None = None,
        coloured: NDArray[np.bool_] | None = None,
    ) -> None:
        """Add (N, 3) points (metres) with optional (N, 3) colours and their (N,) valid flags."""
        if len(points) == 0:
            return
        keys, inv = np.unique(self._pack(points), return_inverse=True)
        inv = inv.ravel()
        m = len(keys)
        sums = np.stack([np.bincount(inv, weights=points[:, a], minlength=m) for a in range(3)], axis=1)
        counts = np.bincount(inv, minlength=m).astype(np.int64)
        csums = ccounts = None
        if colors is not None:
            ok = np.ones(len(points), bool) if coloured is None else np.asarray(coloured, bool)
            sel = inv[ok]
            csums = np.stack(
                [np.bincount(sel, weights=colors[ok, a].astype(np.float64), minlength=m) for a in range(3)],
                axis=1,
            )
            ccounts = np.bincount(sel, minlength=m).astype(np.int64)
        pos, held = self._main.find(keys)
        pick = lambda v, w: None if v is None else v[w]  # noqa: E731
        self._main.add_at(pos[held], sums[held], counts[held], pick(csums, held), pick(ccounts, held))
        rest = ~held
        if not rest.any():
            return
        keys, sums, counts = keys[rest], sums[rest], counts[rest]
        csums, ccounts = pick(csums, rest), pick(ccounts, rest)
        pos, held = self._pending.find(keys)
        self._pending.add_at(pos[held], sums[held], counts[held], pick(csums, held), pick(ccounts, held))
        new = ~held
        if new.any():
            fresh = _Voxels()
            fresh.keys, fresh.sums, fresh.counts = keys[new], sums[new], counts[new]
            if csums is not None and ccounts is not None:
                fresh.colour_sums, fresh.colour_counts = csums[new], ccounts[new]
            else:
                fresh.colour_sums = np.zeros((int(new.sum()), 3))
                fresh.colour_counts = np.zeros(int(new.sum()), np.int64)
            self._pending.insert(fresh)
        if len(self._pending) >= max(self.MERGE_AT, len(self._main) // 4):
            self._merge()

    def cloud(self, min_points: int = 1) -> FusedCloud:
        """The mean point (and mean colour) of every voxel with at least `min_points` points."""
        self._merge()
        v = self._main
        keep = v.counts >= max(min_points, 1)
        pts = v.sums[keep] / v.counts[keep, None]
        cc = v.colour_counts[keep]
        coloured = cc > 0
        colors = np.zeros((int(keep.sum()), 3), np.uint8)
        colors[coloured] = np.clip(
            np.rint(v.colour_sums[keep][coloured] / cc[coloured, None]), 0, 255
        ).astype(np.uint8)
        return FusedCloud(np.ascontiguousarray(pts), colors, coloured, v.counts[keep].copy())


FrameData = tuple[int, NDArray[np.floating], NDArray[np.uint8] | None]
"""(frame_id, (H, W) depth in metres of the depth camera (0/NaN = none), (H, W, 3) RGB or None)."""


def frame_points(
    depth_m: NDArray[np.floating], calib: Calibration, cfg: RegisterConfig, radial_k: float = 0.0
) -> NDArray[np.float64]:
    """(N, 3) depth-camera points of one frame (eq 3.13) within the depth range, every `pixel_stride`-th
    pixel, with the radial inverse-depth error `radial_k` (1/m at the image corner, see
    `RadialDepthError`) taken out."""
    d = np.asarray(depth_m, dtype=np.float64)
    s = max(int(cfg.pixel_stride), 1)
    if s > 1:
        mask = np.zeros(d.shape, bool)
        mask[::s, ::s] = True
        d = np.where(mask, d, np.nan)
    d = np.where((d >= cfg.min_depth_m) & (d <= cfg.max_depth_m), d, np.nan)
    pts, _ = depth_to_points(d, "m", calib.ir)
    if radial_k and len(pts):
        # 1/z' = 1/z - k rho: every point slides along its ray
        denom = 1.0 - radial_k * radial_position(pts, calib.ir) * pts[:, 2]
        ok = denom > 0.5
        pts = pts[ok] / denom[ok, None]
    return pts


def radial_position(pts: NDArray[np.float64], camera: CameraModel) -> NDArray[np.float64]:
    """(N,) squared distance of each camera-frame point's image from the image centre, in normalized image
    coordinates, 1 at the corners."""
    K = np.asarray(camera.K, dtype=np.float64)
    w, h = camera.size
    cx, cy = ((w - 1) / 2.0 - K[0, 2]) / K[0, 0], ((h - 1) / 2.0 - K[1, 2]) / K[1, 1]
    corner = ((w - 1) / 2.0 / K[0, 0]) ** 2 + ((h - 1) / 2.0 / K[1, 1]) ** 2
    return ((pts[:, 0] / pts[:, 2] - cx) ** 2 + (pts[:, 1] / pts[:, 2] - cy) ** 2) / corner


@dataclass(frozen=True)
class RadialDepthError:
    """The systematic radial error of a depth camera (thesis 6.1.2: it grows towards the image corners and
    with the square of the range, as a disparity error does): measured inverse depth = true inverse depth +
    k·ρ, ρ the squared image radius (1 at the corners). A Kinect v1's pulls the walls seen near the image
    corners towards the camera, by about 1 cm at 3 m.

    Estimated from the capture itself: in each sampled frame the dominant plane (a wall, the floor) is
    found by RANSAC in (x/z, y/z, 1/z), where a plane is linear and disparity noise is even, keeping the points
    whose local normal agrees with it; k is fitted with the plane by robust least squares, and the capture's
    k is the median of its frames'. It is applied only when clearly above its standard error."""

    k_inv_m: float
    """Inverse-depth error at the image corners (1/m); 0 when not applied."""
    estimate_inv_m: float
    """The fitted value, applied or not."""
    stderr_inv_m: float
    frames: int
    points: int
    applied: bool


def estimate_radial_depth_error(
    frames: Iterable[FrameData], calib: Calibration, cfg: RegisterConfig
) -> RadialDepthError:
    """Fit `RadialDepthError` on the frames given (a sample of the capture; see its docstring)."""
    rng = np.random.default_rng(0)
    blocks: list[tuple[NDArray, NDArray, NDArray]] = []
    cos_tol = math.cos(math.radians(cfg.radial_normal_tol_deg))
    for _fid, depth, _rgb in frames:
        pts, normals = _organized_points(depth, calib, cfg)
        if len(pts) < cfg.radial_min_points:
            continue
        A = np.column_stack([pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2], np.ones(len(pts))])
        w = 1.0 / pts[:, 2]
        inl, p = _dominant_plane(A, w, rng, cfg.radial_plane_tol_inv_m)
        # w = p·(x/z, y/z, 1) is the plane p·X = 1: points of another surface within the band (the next
        # wall at a room corner, always nearer the camera and off the image centre) have other normals
        inl &= np.abs(normals @ (p / max(float(np.linalg.norm(p)), 1e-12))) >= cos_tol
        if inl.sum() >= cfg.radial_min_points:
            blocks.append((A[inl], w[inl], radial_position(pts[inl], calib.ir)))
    n_pts = sum(len(b[1]) for b in blocks)
    if len(blocks) < cfg.radial_min_frames:
        return RadialDepthError(0.0, 0.0, 0.0, len(blocks), n_pts, False)
    per_frame = np.array([_plane_and_radial_fit(*b) for b in blocks])
    # a frame whose plane band also holds a parallel surface (a cabinet's front before a far wall) is an
    # outlier: the median of the frames, with the standard error of a median
    k = float(np.median(per_frame))
    stderr = float(1.2533 * 1.4826 * np.median(np.abs(per_frame - k)) / np.sqrt(len(per_frame)))
    applied = abs(k) > cfg.radial_min_significance * stderr
    return RadialDepthError(k if applied else 0.0, k, stderr, len(blocks), n_pts, bool(applied))


def _plane_and_radial_fit(A: NDArray, w: NDArray, rho: NDArray, iterations: int = 4) -> float:
    """k of w = A·p + k·rho fitted by least squares, reweighted (Cauchy, 2.5 robust σ)."""
    wt = np.ones(len(w))
    k = 0.0
    X = np.column_stack([A, rho])
    for _ in range(iterations):
        sw = np.sqrt(wt)
        coef = np.linalg.lstsq(X * sw[:, None], w * sw, rcond=None)[0]
        k = float(coef[3])
        r = w - X @ coef
        scale = 2.5 * 1.4826 * float(np.median(np.abs(r)))
        wt = 1.0 / (1.0 + (r / max(scale, 1e-12)) ** 2)
    return k


def _organized_points(
    depth_m: NDArray[np.floating], calib: Calibration, cfg: RegisterConfig, reach_px: int = 6
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Valid points (N, 3) of a frame's every `pixel_stride`-th pixel (as `frame_points`) and their unit
    normals (N, 3) from the neighbours `reach_px` pixels away on the image grid."""
    d = np.asarray(depth_m, dtype=np.float64)
    d = np.where((d >= cfg.min_depth_m) & (d <= cfg.max_depth_m), d, np.nan)
    s = max(int(cfg.pixel_stride), 1)
    rays = calib.ir.pixel_rays()[::s, ::s]
    z = d[::s, ::s]
    P = np.concatenate([rays * z[..., None], z[..., None]], axis=2)
    k = max(1, reach_px // s)
    du = np.full_like(P, np.nan)
    dv = np.full_like(P, np.nan)
    du[:, k:-k] = P[:, 2 * k :] - P[:, : -2 * k]
    dv[k:-k] = P[2 * k :] - P[: -2 * k]
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=2)
    ok = np.isfinite(z) & np.isfinite(norm) & (norm > 0)
    return P[ok], n[ok] / norm[ok, None]


def _dominant_plane(
    A: NDArray, w: NDArray, rng: np.random.Generator, tol: float, trials: int = 200
) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Inliers (within `tol` in w) of the plane w = A·p with most of them (RANSAC on a subsample, then one
    least-squares refit on the inliers), and p."""
    n = len(w)
    sub = rng.choice(n, size=min(n, 4000), replace=False)
    best, best_count = None, -1
    for _ in range(trials):
        idx = rng.choice(sub, size=3, replace=False)
        try:
            p = np.linalg.solve(A[idx], w[idx])
        except np.linalg.LinAlgError:
            continue
        count = int((np.abs(A[sub] @ p - w[sub]) <= tol).sum())
        if count > best_count:
            best, best_count = p, count
    if best is None:
        return np.zeros(n, dtype=bool), np.zeros(3)
    inl = np.abs(A @ best - w) <= tol
    p = np.linalg.lstsq(A[inl], w[inl], rcond=None)[0]
    return np.abs(A @ p - w) <= tol, p


def fuse_capture(
    frames: Callable[[set[int] | None], Iterable[FrameData]],
    poses: dict[int, NDArray[np.float64]],
    calibration: Calibration,
    cfg: RegisterConfig,
    refined: dict[int, NDArray[np.float64]] | None = None,
    radial: RadialDepthError | None = None,
) -> tuple[FusedCloud, RadialDepthError | None]:
    """`fuse_frames` after estimating the depth camera's radial error (`RadialDepthError`) on every n-th
    placed frame (`radial_frames` of them) when `cfg.radial_correction` and no `radial` estimate (made
    on the capture before, e.g. for the metric scale) is given. `frames(ids)` streams the frames whose id
    is in `ids` (None: all), so that only the sample is decoded for the estimate."""
    if radial is None and cfg.radial_correction:
        step = max(1, len(poses) // max(cfg.radial_frames, 1))
        sample = set(sorted(int(f) for f in poses)[::step])
        radial = estimate_radial_depth_error(frames(sample), calibration, cfg)
    k = radial.k_inv_m if radial is not None else 0.0
    return fuse_frames(frames(None), poses, calibration, cfg, refined, k), radial


def transform_points(T: NDArray[np.float64], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) points moved by the (4, 4) pose T (`tasks.cloud.apply_transform`: no threaded BLAS)."""
    return apply_transform(T, pts)


def fuse_frames(
    frames: Iterable[FrameData],
    poses: dict[int, NDArray[np.float64]],
    calibration: Calibration,
    cfg: RegisterConfig,
    refined: dict[int, NDArray[np.float64]] | None = None,
    radial_k: float = 0.0,
) -> FusedCloud:
    """Stream frames into the voxel grid (3.1.3): depth points (eq 3.13, without the radial error
    `radial_k`, see `frame_points`) moved by the frame's pose
    (depth camera → room, (4, 4)), coloured with `colour_points` (eq 3.14-3.15) when the frame has a colour
    image and the calibration an RGB camera. Frames without a pose are skipped. With `cfg.icp_refine` each
    frame is first refined against the previous fused frame (point-to-plane ICP); the poses used are put in
    `refined` when given. Raises DegenerateInputError when no point is fused."""
    acc = VoxelAccumulator(cfg.voxel_size_m)
    prev: NDArray[np.float64] | None = None
    can_colour = calibration.rgb is not None and calibration.ir_to_rgb is not None

    def prepare(frame: FrameData) -> tuple[int, NDArray, NDArray, NDArray | None, NDArray | None] | None:
        """A placed frame's depth points and their colours (each frame's own: made on the threads)."""
        frame_id, depth, rgb = frame
        T = poses.get(int(frame_id))
        if T is None or not np.isfinite(T).all():
            return None
        pts = frame_points(depth, calibration, cfg, radial_k)
        if len(pts) == 0:
            return None
        colors = coloured = None
        if can_colour and rgb is not None and (rgb.shape[1], rgb.shape[0]) == calibration.rgb.size:
            colors, coloured = colour_points(
                pts,
                rgb,
                calibration,
                cfg.colour_occlusion_tol_m,
                cfg.colour_occlusion_tol_rel,
                cfg.colour_zbuffer_splat_px,
            )
        return int(frame_id), T, pts, colors, coloured

    used = 0
    # the frames go into the grid in capture order, as on one thread
    for placed in imap_ordered(prepare, frames):
        if placed is None:
            continue
        frame_id, T, pts, colors, coloured = placed
        if cfg.icp_refine:
            T, prev = _icp_step(pts, T, prev, cfg)
        if refined is not None:
            refined[frame_id] = T
        acc.add(transform_points(T, pts), colors, coloured)
        used += 1
    cloud = acc.cloud(cfg.min_points_per_voxel)
    if len(cloud) == 0:
        raise DegenerateInputError(f"no depth point was fused ({used} placed frames had usable depth)")
    return cloud


def _icp_step(
    pts: NDArray[np.float64], T: NDArray[np.float64], prev: NDArray[np.float64] | None, cfg: RegisterConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Point-to-plane ICP of this frame (posed by T) onto the previous frame's room points; returns the
    refined pose and this frame's downsampled room points for the next frame."""
    import open3d as o3d

    def cloud(p: NDArray[np.float64]) -> o3d.geometry.PointCloud:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(p, dtype=np.float64)))
        return pc.voxel_down_sample(cfg.icp_voxel_m)

    src = cloud(transform_points(T, pts))
    if prev is not None and len(src.points) > 50 and len(prev) > 50:
        tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(prev))
        tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * cfg.icp_voxel_m, max_nn=30))
        res = o3d.pipelines.registration.registration_icp(
            src,
            tgt,
            cfg.icp_max_distance_m,
            np.eye(4),
            o3d.pipelines.registration.TransformationEstimationPointToPlane(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30),
        )
        delta = np.asarray(res.transformation)
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(delta[:3, :3]).as_rotvec()))
        if res.fitness > 0.3 and np.linalg.norm(delta[:3, 3]) <= cfg.icp_max_correction_m and angle <= 5.0:
            T = delta @ T
            src.transform(delta)
    return T, np.asarray(src.points)
