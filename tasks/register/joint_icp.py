"""Joint ICP of the fallback's frames (beyond the thesis, issue #15): the track fallback places each frame on
its own (its floor, the track, the coarse plan's wall faces), so two frames seeing one wall may put it a few
centimetres apart, e.g. where the coarse plan's face is off or a frame levelled without a floor got the
capture's median height. Here every frame is moved (6 degrees of freedom, about its camera centre) so that
the surfaces frames share coincide (point-to-plane residuals between every overlapping pair, robustly
weighted), held near its own placement only by a weak prior: what the frames do not pin among themselves
(the capture as a whole, a corridor's length) stays where the fallback put it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class JointIcpSettings:
    """The joint ICP's settings (see `RegisterConfig.track_joint_*`)."""

    iterations: int = 10
    max_dist_m: tuple[float, float] = (0.15, 0.04)
    """Correspondence distance of the first and the last iteration (geometric steps between)."""
    max_normal_angle_deg: float = 30.0
    min_pair_matches: int = 100
    prior_xy_m: float = 0.05
    prior_yaw_deg: float = 2.0
    prior_z_m: tuple[float, float] = (0.02, 0.2)
    """Prior on the height change of a frame levelled by its own floor, and of one levelled otherwise."""
    prior_tilt_deg: tuple[float, float] = (0.5, 5.0)
    """Prior on the tilt change of a frame levelled by its own floor, and of one levelled otherwise."""
    max_points: int = 3000
    planar: bool = True
    """Only walls (normals within 30 degrees of the horizontal) and only x, y and heading: each frame keeps
    its levelling and height."""


def _skew_rotation(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation matrix of the rotation vector w (Rodrigues)."""
    a = float(np.linalg.norm(w))
    if a < 1e-12:
        return np.eye(3)
    k = w / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _rotation_vector(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vector of the rotation matrix R (inverse of `_skew_rotation`, angles below pi)."""
    c = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    a = float(np.arccos(c))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return v * (0.5 if a < 1e-9 else a / (2 * np.sin(a)))


def thin_view(
    pts: NDArray[np.floating], nrm: NDArray[np.floating], max_points: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Every k-th of a frame's (N, 3) points and unit normals (camera frame), at most `max_points`."""
    step = max(1, int(np.ceil(len(pts) / max(max_points, 1))))
    return np.asarray(pts[::step], np.float32), np.asarray(nrm[::step], np.float32)


def joint_icp(
    views: dict[int, tuple[NDArray[np.float32], NDArray[np.float32]]],
    poses: dict[int, NDArray[np.float64]],
    floor_levelled: set[int],
    s: JointIcpSettings,
) -> tuple[dict[int, NDArray[np.float64]], dict[str, Any]]:
    """Frames (id -> ((N, 3) points, (N, 3) unit normals facing the camera, camera frame)) placed by `poses`
    (id -> (4, 4) camera → world) moved so that the surfaces they share coincide. `floor_levelled`: frames
    whose tilt and height come from their own floor (held more firmly in those). Returns (id -> refined
    (4, 4), metrics: pairs and matches used, the residual spread before and after, the largest move)."""
    ids = sorted(f for f in views if f in poses and len(views[f][0]) >= s.min_pair_matches)
    index = {f: k for k, f in enumerate(ids)}
    start = {f: np.asarray(poses[f], dtype=np.float64) for f in ids}
    cur = {f: start[f].copy() for f in ids}
    pts = {f: views[f][0].astype(np.float64) for f in ids}
    nrm = {f: views[f][1].astype(np.float64) for f in ids}
    trees = {f: cKDTree(pts[f]) for f in ids}
    n = len(ids)
    metrics: dict[str, Any] = {"frames": n, "pairs": 0, "matches": 0}
    if n < 2:
        return dict(poses), metrics
    prior = np.zeros((n, 6))
    for f in ids:
        k = 0 if f in floor_levelled else 1
        tilt, z = np.radians(s.prior_tilt_deg[k]), s.prior_z_m[k]
        sig = [tilt, tilt, np.radians(s.prior_yaw_deg), s.prior_xy_m, s.prior_xy_m, z]
        prior[index[f]] = 1.0 / np.square(sig)
        if s.planar:
            prior[index[f], [0, 1, 5]] = 1e12  # tilt and height locked
    cos_max = np.cos(np.radians(s.max_normal_angle_deg))
    spreads: list[float] = []
    for dist in np.geomspace(s.max_dist_m[0], s.max_dist_m[1], max(s.iterations, 1)):
        world = {f: pts[f] @ cur[f][:3, :3].T + cur[f][:3, 3] for f in ids}
        lo = {f: world[f].min(axis=0) - dist for f in ids}
        hi = {f: world[f].max(axis=0) + dist for f in ids}
        H = np.zeros((6 * n, 6 * n))
        g = np.zeros(6 * n)
        rows = []
        for a in range(n):
            i = ids[a]
            inv = np.linalg.inv(cur[i])
            for j in ids[a + 1 :]:
                if np.any(lo[j] > hi[i]) or np.any(lo[i] > hi[j]):
                    continue
                M = inv @ cur[j]
                q = pts[j] @ M[:3, :3].T + M[:3, 3]
                d, idx = trees[i].query(q, distance_upper_bound=dist)
                ok = np.isfinite(d)
                if ok.sum() < s.min_pair_matches:
                    continue
                qn = nrm[j][ok] @ M[:3, :3].T
                p_idx = idx[ok]
                agree = (qn * nrm[i][p_idx]).sum(axis=1) > cos_max
                if agree.sum() < s.min_pair_matches:
                    continue
                sel = np.flatnonzero(ok)[agree]
                R_i, t_i = cur[i][:3, :3], cur[i][:3, 3]
                nw = nrm[i][idx[sel]] @ R_i.T
                if s.planar:
                    sel, nw = sel[np.abs(nw[:, 2]) < 0.5], nw[np.abs(nw[:, 2]) < 0.5]
                    if len(sel) < s.min_pair_matches:
                        continue
                pw = pts[i][idx[sel]] @ R_i.T + t_i
                qw = world[j][sel]
                # a depth camera's noise grows with the square of the range: 1 at 1 m
                z2 = np.maximum(pts[i][idx[sel], 2], 1.0) ** 4 + np.maximum(pts[j][sel, 2], 1.0) ** 4
                rows.append((index[i], index[j], pw, nw, qw, ((qw - pw) * nw).sum(axis=1), 2.0 / z2))
        if not rows:
            break
        r_all = np.concatenate([r[5] for r in rows])
        sigma = max(1.4826 * float(np.median(np.abs(r_all))), 0.002)
        spreads.append(sigma)
        pairs = matches = 0
        for a, b, pw, nw, qw, r, zw in rows:
            w = zw / (1.0 + (r / (2.0 * sigma)) ** 2)  # Cauchy: a wrongly matched surface loses weight
            Jb = np.hstack([np.cross(qw - cur[ids[b]][:3, 3], nw), nw])
            Ja = -np.hstack([np.cross(pw - cur[ids[a]][:3, 3], nw), nw])
            for u, Ju in ((a, Ja), (b, Jb)):
                g[6 * u : 6 * u + 6] += Ju.T @ (w * r)
                for v, Jv in ((a, Ja), (b, Jb)):
                    H[6 * u : 6 * u + 6, 6 * v : 6 * v + 6] += (Ju * w[:, None]).T @ Jv
            pairs += 1
            matches += len(r)
        H /= sigma**2
        g /= sigma**2
        for f in ids:
            k = index[f]
            moved = np.concatenate(
                [_rotation_vector(cur[f][:3, :3] @ start[f][:3, :3].T), cur[f][:3, 3] - start[f][:3, 3]]
            )
            H[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] += np.diag(prior[k])
            g[6 * k : 6 * k + 6] += prior[k] * moved
        step = -np.linalg.solve(H, g)
        for f in ids:
            k = index[f]
            T = cur[f].copy()
            T[:3, :3] = _skew_rotation(step[6 * k : 6 * k + 3]) @ T[:3, :3]
            T[:3, 3] += step[6 * k + 3 : 6 * k + 6]
            cur[f] = T
        metrics.update(pairs=pairs, matches=matches)
    out = dict(poses)
    out.update(cur)
    shifts = [float(np.linalg.norm(cur[f][:3, 3] - start[f][:3, 3])) for f in ids]
    turns = [
        float(np.degrees(np.linalg.norm(_rotation_vector(cur[f][:3, :3] @ start[f][:3, :3].T)))) for f in ids
    ]
    metrics.update(
        residual_spread_first_m=round(spreads[0], 4) if spreads else None,
        residual_spread_last_m=round(spreads[-1], 4) if spreads else None,
        max_shift_m=round(max(shifts), 4),
        max_turn_deg=round(max(turns), 3),
    )
    return out, metrics
