"""Builders shared by the scale, SfM and register tests: a small test camera, rendered views of the textured
box room (tasks/synth/box_views.py) with their true poses, and the trajectory error after the best
similarity (an independent Umeyama fit, not the stage's own Horn solver)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tasks.camera import CameraModel
from tasks.synth.box_views import look_pose, render


def small_camera(w: int = 160, h: int = 120, f: float = 140.0) -> CameraModel:
    return CameraModel(np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]), np.zeros(5), (w, h))


def rendered_views(n: int) -> tuple[list[tuple[str, NDArray[np.uint8]]], list[NDArray], CameraModel]:
    """`n` 320x240 colour views of the box room along a short sideways walk: ((name, RGB) per view,
    camera → world poses (4, 4), the camera)."""
    w, h, f = 320, 240, 260.0
    cam = CameraModel(np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]), np.zeros(5), (w, h))
    poses, images = [], []
    for k in range(n):
        a = 0.5 + 0.12 * k
        T = look_pose(np.array([0.2 + 0.15 * k, -0.3, 1.3]), a, pitch_rad=-0.2)
        poses.append(T)
        images.append((f"view{k:02d}.png", render(cam, T)[1]))
    return images, poses, cam


def umeyama(X: NDArray, Y: NDArray) -> tuple[float, NDArray, NDArray]:
    """The similarity (s, R, t) with Y ≈ s R X + t in the least-squares sense (Umeyama 1991)."""
    mx, my = X.mean(0), Y.mean(0)
    Xc, Yc = X - mx, Y - my
    U, S, Vt = np.linalg.svd(Yc.T @ Xc / len(X))
    D = np.eye(3)
    if np.linalg.det(U @ Vt) < 0:
        D[2, 2] = -1
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / Xc.var(0).sum()
    return s, R, my - s * R @ mx


def ate_after_similarity(est: NDArray, truth: NDArray) -> tuple[float, float]:
    """(ATE RMSE after the best similarity mapping est (N, 3) onto truth (N, 3), that similarity's scale)."""
    s, R, t = umeyama(est, truth)
    e = np.linalg.norm(s * est @ R.T + t - truth, axis=1)
    return float(np.sqrt((e**2).mean())), float(s)


def wall_points(
    a: NDArray | tuple,
    b: NDArray | tuple,
    z0: float,
    z1: float,
    rng: np.random.Generator,
    step: float = 0.01,
    noise: float = 0.0,
) -> NDArray[np.float64]:
    """A vertical wall face from a to b, z0..z1, one point per step^2, optional normal noise."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    L = float(np.hypot(*(b - a)))
    s, z = np.meshgrid(np.arange(0, L, step) + step / 2, np.arange(z0, z1, step) + step / 2)
    u = (b - a) / L
    n = np.array([-u[1], u[0]])
    xy = (
        a + s.reshape(-1, 1) * u + rng.normal(0, noise, (s.size, 1)) * n
        if noise
        else a + s.reshape(-1, 1) * u
    )
    return np.column_stack([xy, z.reshape(-1)])
