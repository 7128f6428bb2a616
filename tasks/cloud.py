"""The point-cloud value passed between stages: plain numpy arrays, so it hashes, pickles and crosses
process boundaries (open3d objects do neither)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


class DegenerateInputError(ValueError):
    """An input that no stage can make sense of (empty, all NaN, a single plane...). The message is one
    line and names what is wrong; callers add the file name."""


@dataclass(frozen=True)
class Cloud:
    """A point cloud in metres."""

    points: NDArray[np.float64]
    """(N, 3) x y z in metres."""
    colors: NDArray[np.uint8] | None = None
    """(N, 3) RGB, or None for an uncoloured cloud."""

    def __post_init__(self) -> None:
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise DegenerateInputError(f"points must be (N, 3), got {self.points.shape}")
        if self.colors is not None and self.colors.shape != self.points.shape:
            raise DegenerateInputError(f"colors {self.colors.shape} do not match points {self.points.shape}")

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, keep: NDArray[np.bool_] | NDArray[np.intp]) -> Cloud:
        """The points selected by a boolean mask or an index array, colours carried along."""
        colors = None if self.colors is None else self.colors[keep]
        return Cloud(np.ascontiguousarray(self.points[keep]), colors)

    def transformed(self, transform: NDArray[np.float64]) -> Cloud:
        """The cloud moved by a 4x4 rigid (or similarity) transform."""
        return Cloud(apply_transform(transform, self.points), self.colors)


def apply_transform(transform: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) points moved by a 4x4 (or 3x4) transform: R · p + t, one column at a time. An (N, 3) @ (3, 3)
    product goes to the threaded BLAS, whose threads spin for CPU on a loaded machine: 76.8 k points cost
    20 ms of CPU (250 ms wall at load 20) there, against 1.2 ms so."""
    R = np.asarray(transform, dtype=np.float64)[:3]
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty((len(p), 3))
    for i in range(3):
        out[:, i] = p[:, 0] * R[i, 0] + p[:, 1] * R[i, 1] + p[:, 2] * R[i, 2] + R[i, 3]
    return out


def require_finite(cloud: Cloud, min_points: int = 1) -> Cloud:
    """The cloud itself if all points are finite and there are at least `min_points`; else a clear error."""
    bad = ~np.isfinite(cloud.points).all(axis=1)
    if bad.any():
        raise DegenerateInputError(f"{int(bad.sum())} of {len(cloud)} points are NaN or infinite")
    if len(cloud) < min_points:
        raise DegenerateInputError(f"cloud has {len(cloud)} points, at least {min_points} needed")
    return cloud
