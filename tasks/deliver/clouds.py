"""Room clouds in the floor frame: preprocess's levelled, coloured cloud of each room moved by fuse's
placement into the plan frame, the floor at z = 0, reduced to one point per voxel.

The levelled cloud (preprocess's levelled.ply) is z up with the floor at levelling.json's floor_z_m. The
room's walls, which fuse placed, are in that frame for a registered capture and in the given cloud's own
frame for a given cloud (its levelling undone: the inverse of levelling.json's transform). A point's
plan-frame x, y is fuse's 2D placement of its x, y in the walls' frame; its z is its levelled height above
the floor. A room fuse did not place keeps its walls' frame (still the floor at z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks import artefacts as art


@dataclass(frozen=True)
class RoomCloud:
    points: NDArray[np.float64]
    colors: NDArray[np.uint8] | None
    frame: str
    """"plan" or "own (not placed: <reason>)"."""


def write_cloud(path: Path, points: NDArray[np.float64], colors: NDArray[np.uint8] | None) -> Path:
    """Binary little-endian PLY, float x y z (plan-frame metres: a float keeps 2 um at 20 m from the
    origin) and uchar colours when given: half the size of doubles."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    props = ["property float x", "property float y", "property float z"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    rec = np.empty(len(points), dtype=fields)
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    if colors is not None:
        rec["red"], rec["green"], rec["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    head = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}", *props, "end_header", ""]
    )
    return art.write_bytes(path, head.encode() + rec.tobytes())


def voxel_index(keys: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Each row's index among the distinct rows of `keys` (n x 3 voxel coordinates) sorted in
    lexicographic order, and each distinct row's count: `np.unique(keys, axis=0)`'s inverse and counts.
    The rows are packed into one int64 each (offsets from the minimum, x most significant), whose order
    is the rows' lexicographic order, so a 1-D sort does it: several times faster than sorting rows."""
    low = keys.min(axis=0)
    span = keys.max(axis=0) - low + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:  # cannot pack: sort the rows
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        return inverse.reshape(-1), counts
    shifted = keys - low
    packed = (shifted[:, 0] * span[1] + shifted[:, 1]) * span[2] + shifted[:, 2]
    _, inverse, counts = np.unique(packed, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def voxel_reduce(
    points: NDArray[np.float64], colors: NDArray[np.uint8] | None, voxel_m: float
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """One point per occupied voxel: the mean of its points (and colours), in the order of the voxels'
    integer coordinates (deterministic)."""
    if voxel_m <= 0 or len(points) == 0:
        return points, colors
    inverse, counts = voxel_index(np.floor(points / voxel_m).astype(np.int64))
    out = np.zeros((len(counts), 3))
    for k in range(3):
        out[:, k] = np.bincount(inverse, weights=points[:, k], minlength=len(counts)) / counts
    cols = None
    if colors is not None:
        cols = np.zeros((len(counts), 3))
        for k in range(3):
            cols[:, k] = np.bincount(inverse, weights=colors[:, k].astype(np.float64), minlength=len(counts))
        cols = np.clip(np.rint(cols / counts[:, None]), 0, 255).astype(np.uint8)
    return out, cols


def room_cloud(
    levelled: Path, levelling: dict[str, Any], placement: NDArray[np.float64] | None, reason: str = ""
) -> RoomCloud:
    """A room's levelled cloud in the plan frame (module doc); `placement` is fuse's 3x3 matrix (None
    when the room was not placed)."""
    cloud = art.read_cloud(levelled)
    pts = cloud.points
    transform = np.asarray(levelling.get("transform", np.eye(4)), dtype=np.float64)
    floor_z = float(levelling["floor_z_m"])
    walls_frame = pts
    if levelling.get("source") != "register":  # walls went back into the given cloud's frame
        back = np.linalg.inv(transform)
        walls_frame = pts @ back[:3, :3].T + back[:3, 3]
    xy = walls_frame[:, :2]
    if placement is not None:
        m = np.asarray(placement, dtype=np.float64)
        xy = xy @ m[:2, :2].T + m[:2, 2]
    out = np.column_stack([xy, pts[:, 2] - floor_z])
    frame = "plan" if placement is not None else f"own (not placed: {reason or 'no placement'})"
    return RoomCloud(out, cloud.colors, frame)
