"""Joint ICP of the track fallback's frames (beyond the thesis, issue #15). The fallback places each frame on
its own (its floor, the track, the coarse plan's wall faces), so two frames seeing one wall may put it
centimetres apart: a coarse plan's face is off by a few centimetres along part of a wall, and the frames
pulled onto it disagree with their neighbours. Here the frames are moved in the plan (x, y and heading, about
each camera centre; the levelling and height stay) so that the walls neighbouring frames share coincide.

Each overlapping pair of frames is matched point to plane on the walls (normals within 30 degrees of the
horizontal) and gives the relative motion that would align it, trusted only in the directions its matches pin
(like the drift model's `_pinning`: a pair seeing two corridor walls pins across the corridor and the
heading, not along it). Every frame is held near its own placement by a prior, so what no pair pins (a
corridor's length, the capture as a whole) stays where the fallback's plan fit put it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class JointIcpSettings:
    """The joint ICP's settings (`RegisterConfig.track_joint_*` hold the ones a survey may change)."""

    iterations: int = 10
    max_dist_m: tuple[float, float] = (0.15, 0.04)
    """Correspondence distance of the first and the last iteration (geometric steps between)."""
    max_normal_angle_deg: float = 30.0
    """Matched points' normals must agree within this."""
    min_pair_matches: int = 100
    """A pair of frames with fewer wall matches gives no constraint."""
    pin_points: float = 200.0
    """Wall matches (weighted) facing one direction at which a pair pins its relative motion fully in it;
    fewer pin it in proportion (a door jamb's few points along a corridor pin little)."""
    pair_sigma_m: float = 0.01
    """Standard deviation of a fully pinned pair's relative placement."""
    prior_m: float = 0.03
    """Standard deviation of a frame's move from the fallback's placement, in x and y."""
    prior_deg: float = 2.0
    """...and in heading."""
    lever_m: float = 1.0
    """Length turning a heading change into a comparable shift when a pair's pinning is judged."""
    max_points: int = 3000
    """Points kept per frame (`thin_view`)."""


def thin_view(
    pts: NDArray[np.floating], nrm: NDArray[np.floating], max_points: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Every k-th of a frame's (N, 3) points and unit normals (camera frame), at most `max_points`."""
    step = max(1, int(np.ceil(len(pts) / max(max_points, 1))))
    return np.asarray(pts[::step], np.float32), np.asarray(nrm[::step], np.float32)


def _yaw(R: NDArray[np.float64]) -> float:
    return float(np.arctan2(R[1, 0], R[0, 0]))


def _turn_z(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _pair_constraint(
    J: NDArray[np.float64], w0: NDArray[np.float64], r: NDArray[np.float64], s: JointIcpSettings
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """One pair's matches (rows J (M, 3) of d residual / d (heading, x, y) of the later frame's relative
    motion, prior weights w0, residuals r) → (its information (3, 3) on that motion, kept only in the
    directions the matches pin, each in proportion up to `pin_points`; the motion e* that would align the
    pair; the robust spread of its residuals after it). The pair's own fit is robust (Cauchy, reweighted on
    the residuals left after its motion, so that a misplaced pair's matches are not taken for outliers)."""
    scale = np.array([s.lever_m, 1.0, 1.0])  # heading as the shift it makes at the lever's length
    Js = J / scale
    w = w0
    e_s = np.zeros(3)
    sigma = 0.0
    for _ in range(3):
        A = (Js * w[:, None]).T @ Js
        vals, vecs = np.linalg.eigh(A)
        inv = np.where(vals > 1e-9 * max(vals.max(), 1e-12), 1.0 / np.maximum(vals, 1e-300), 0.0)
        e_s = -(vecs * inv) @ vecs.T @ (Js.T @ (w * r))
        left = r + Js @ e_s
        sigma = max(1.4826 * float(np.median(np.abs(left))), 0.002)
        w = w0 / (1.0 + (left / (2.0 * sigma)) ** 2)  # Cauchy: a wrongly matched surface loses weight
    A = (Js * w[:, None]).T @ Js
    vals, vecs = np.linalg.eigh(A)
    pinned = (vecs * np.clip(vals / s.pin_points, 0.0, 1.0)) @ vecs.T / s.pair_sigma_m**2
    return pinned * np.outer(scale, scale), e_s / scale, sigma


def joint_icp(
    views: dict[int, tuple[NDArray[np.float32], NDArray[np.float32]]],
    poses: dict[int, NDArray[np.float64]],
    s: JointIcpSettings,
) -> tuple[dict[int, NDArray[np.float64]], dict[str, Any]]:
    """Frames (id -> ((N, 3) points, (N, 3) unit normals facing the camera, camera frame)) placed by `poses`
    (id -> (4, 4) camera → world, z up) moved in x, y and heading so that the walls they share coincide.
    Returns (id -> refined (4, 4), metrics: frames, pairs and matches used, the wall residuals' spread
    (1.4826 MAD) between frames before and after at the last correspondence distance, the largest move)."""
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
    prior = 1.0 / np.square([np.radians(s.prior_deg), s.prior_m, s.prior_m])
    cos_max = np.cos(np.radians(s.max_normal_angle_deg))

    def matches(dist: float) -> list[tuple[int, int, NDArray, NDArray, NDArray, NDArray]]:
        """Per overlapping pair (a < b by index): (a, b, later frame's world points, normals, residuals,
        range weights) of its wall matches within `dist`."""
        world = {f: pts[f] @ cur[f][:3, :3].T + cur[f][:3, 3] for f in ids}
        lo = {f: world[f].min(axis=0) - dist for f in ids}
        hi = {f: world[f].max(axis=0) + dist for f in ids}
        out = []
        for a, i in enumerate(ids):
            inv = np.linalg.inv(cur[i])
            for j in ids[a + 1 :]:
                if np.any(lo[j] > hi[i]) or np.any(lo[i] > hi[j]):
                    continue
                M = inv @ cur[j]
                d, idx = trees[i].query(pts[j] @ M[:3, :3].T + M[:3, 3], distance_upper_bound=dist)
                sel = np.flatnonzero(np.isfinite(d))
                if len(sel) < s.min_pair_matches:
                    continue
                nw = nrm[i][idx[sel]] @ cur[i][:3, :3].T
                keep = ((nrm[j][sel] @ cur[j][:3, :3].T) * nw).sum(axis=1) > cos_max
                keep &= np.abs(nw[:, 2]) < 0.5  # walls: only they pin x, y and heading
                if keep.sum() < s.min_pair_matches:
                    continue
                sel, nw = sel[keep], nw[keep]
                pw = pts[i][idx[sel]] @ cur[i][:3, :3].T + cur[i][:3, 3]
                qw = world[j][sel]
                # a depth camera's noise grows with the square of the range: nearer matches count more,
                # the pair's matches as many as they are (the mean weight is 1)
                zw = 1.0 / (pts[i][idx[sel], 2] ** 2 + pts[j][sel, 2] ** 2)
                zw /= zw.mean()
                out.append((a, index[j], qw, nw, ((qw - pw) * nw).sum(axis=1), zw))
        return out

    def spread(rows: list) -> float | None:
        return (
            round(1.4826 * float(np.median(np.abs(np.concatenate([r[4] for r in rows])))), 4)
            if rows
            else None
        )

    before = spread(matches(s.max_dist_m[1]))
    for dist in np.geomspace(s.max_dist_m[0], s.max_dist_m[1], max(s.iterations, 1)):
        rows = matches(float(dist))
        if not rows:
            break
        H = np.zeros((3 * n, 3 * n))
        g = np.zeros(3 * n)
        used = 0
        for a, b, qw, nw, r, zw in rows:
            cb, ca = cur[ids[b]][:3, 3], cur[ids[a]][:3, 3]
            lever = qw - cb
            J = np.column_stack([lever[:, 0] * nw[:, 1] - lever[:, 1] * nw[:, 0], nw[:, 0], nw[:, 1]])
            A, e_star, _ = _pair_constraint(J, zw, r, s)
            # e = δb − L δa: frame a's motion (about its centre) as a motion about frame b's centre
            L = np.eye(3)
            L[1:, 0] = [-(cb[1] - ca[1]), cb[0] - ca[0]]
            blocks = ((b, np.eye(3)), (a, -L))
            for u, Bu in blocks:
                g[3 * u : 3 * u + 3] -= Bu.T @ A @ e_star
                for v, Bv in blocks:
                    H[3 * u : 3 * u + 3, 3 * v : 3 * v + 3] += Bu.T @ A @ Bv
            used += 1
        for f in ids:
            k = index[f]
            moved = np.array([_yaw(cur[f][:3, :3] @ start[f][:3, :3].T), *(cur[f][:2, 3] - start[f][:2, 3])])
            H[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] += np.diag(prior)
            g[3 * k : 3 * k + 3] += prior * moved
        step = -np.linalg.solve(H, g)
        for f in ids:
            k = index[f]
            cur[f][:3, :3] = _turn_z(step[3 * k]) @ cur[f][:3, :3]
            cur[f][:2, 3] += step[3 * k + 1 : 3 * k + 3]
        metrics.update(pairs=used, matches=int(sum(len(r[4]) for r in rows)))
    out = dict(poses)
    out.update(cur)
    metrics.update(
        wall_residual_spread_before_m=before,
        wall_residual_spread_after_m=spread(matches(s.max_dist_m[1])),
        max_shift_m=round(max(float(np.linalg.norm(cur[f][:2, 3] - start[f][:2, 3])) for f in ids), 4),
        max_turn_deg=round(max(abs(np.degrees(_yaw(cur[f][:3, :3] @ start[f][:3, :3].T))) for f in ids), 3),
    )
    return out, metrics
