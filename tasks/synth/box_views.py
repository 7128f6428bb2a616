"""An analytic textured box room seen by a pinhole camera: exact depth and feature-rich colour from any pose,
for the scale, SfM and register tests and the register benchmark, and a frames.parquet writer for such
frames (ingest's schema), so that the register stage can be run on them without an ingest.

The survey generator (`tasks.synth.survey`) renders whole buildings through a mesh and the sensor models;
this box is its closed-form counterpart: every pixel's depth is the exact distance to a box face.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from tasks.artefacts import FRAMES_SCHEMA, encode_png
from tasks.camera import CameraModel

BOX = (np.array([-2.0, -1.5, 0.0]), np.array([2.5, 2.0, 2.6]))
"""A room 4.5 x 3.5 x 2.6 m, floor at z = 0 (world frame, z up): (min corner, max corner)."""


def look_pose(position: NDArray, yaw_rad: float, pitch_rad: float = -0.15) -> NDArray[np.float64]:
    """Camera → world (4, 4) for an OpenCV camera at `position` looking along `yaw_rad` (from +x, CCW),
    tilted down by -pitch."""
    fwd = np.array(
        [np.cos(yaw_rad) * np.cos(pitch_rad), np.sin(yaw_rad) * np.cos(pitch_rad), np.sin(pitch_rad)]
    )
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    T = np.eye(4)
    T[:3, :3] = np.stack([right, down, fwd], axis=1)
    T[:3, 3] = position
    return T


def box_hits(camera: CameraModel, world_from_cam: NDArray, box=BOX) -> tuple[NDArray, NDArray]:
    """Ray cast of the inside of the box: ((H, W) depth z in the camera frame, (H, W, 3) world points)."""
    w, h = camera.size
    rays = camera.pixel_rays()
    d_cam = np.concatenate([rays, np.ones((h, w, 1))], axis=2)
    R, o = world_from_cam[:3, :3], world_from_cam[:3, 3]
    d = d_cam @ R.T
    lo, hi = box
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    t = np.where(t1 > 0, t1, np.inf)
    t = np.minimum(t, np.where(t2 > 0, t2, np.inf)).min(axis=2)
    pts = o + d * t[..., None]
    return t, pts  # d_cam has z = 1, so the ray parameter is the depth z


def texture(pts: NDArray) -> NDArray[np.uint8]:
    """A deterministic, feature-rich colour for world points: blobs of value noise on every wall."""
    p = pts * 7.0
    v = (
        np.sin(p[..., 0] * 1.7 + np.cos(p[..., 1] * 2.3)) * np.cos(p[..., 2] * 2.1 + np.sin(p[..., 0] * 1.3))
        + 0.5 * np.sin(p[..., 1] * 5.1 + p[..., 2] * 3.7) * np.cos(p[..., 0] * 4.3 - p[..., 2] * 1.9)
        + 0.3 * np.sin((p[..., 0] + p[..., 1] + p[..., 2]) * 9.7)
    )
    g = np.clip(128 + 80 * v, 0, 255)
    return np.stack([g, np.clip(255 - g * 0.7, 0, 255), np.clip(g * 0.5 + 60, 0, 255)], axis=-1).astype(
        np.uint8
    )


def render(camera: CameraModel, world_from_cam: NDArray, box=BOX) -> tuple[NDArray, NDArray]:
    """((H, W) depth in metres, (H, W, 3) RGB) of the textured box from one camera."""
    z, pts = box_hits(camera, world_from_cam, box)
    return z, texture(pts)


def write_rendered_frames(path: Path, frames: list[tuple[int, NDArray, NDArray | None]]) -> Path:
    """frames.parquet (ingest's schema) from (t_ns, (H, W) depth in metres, (H, W, 3) RGB or None);
    depth is stored in millimetres, 0 where it is not finite."""
    rows: dict[str, list] = {name: [] for name in FRAMES_SCHEMA.names}
    for k, (t, depth, rgb) in enumerate(frames):
        mm = np.where(np.isfinite(depth), np.round(depth * 1000), 0).clip(0, 65534).astype(np.uint16)
        rows["frame_id"].append(k)
        rows["t_ns"].append(int(t))
        rows["rgb_t_ns"].append(int(t) if rgb is not None else -1)
        rows["rgb"].append(encode_png(rgb) if rgb is not None else b"")
        rows["rgb_format"].append("png" if rgb is not None else "")
        rows["depth"].append(encode_png(mm))
        rows["depth_kind"].append("mm")
        rows["depth_units_per_m"].append(1000.0)
    pq.write_table(pa.table(rows, schema=FRAMES_SCHEMA), path)
    return path
