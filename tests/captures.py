"""Small captures and surveys built in a test's tmp_path: an MCAP with ROS 2 RGB-D messages, a TUM folder,
a box-room cloud, and a survey folder around them. Each has a known answer."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import yaml
from mcap_ros2.writer import Writer

from tasks import rosmsgs
from tasks.artefacts import write_ply_points

TOPICS = {
    "rgb": "/camera/rgb/image_raw",
    "rgb_compressed": "/camera/rgb/image_raw/compressed",
    "depth": "/camera/depth/image_raw",
    "disparity": "/camera/depth/disparity_raw",
    "rgb_info": "/camera/rgb/camera_info",
    "depth_info": "/camera/depth/camera_info",
    "imu": "/imu",
    "pose": "/camera/pose",
}


def camera_info_msg(t_ns: int, width: int, height: int, fx: float) -> dict:
    return {
        "header": rosmsgs.header(t_ns, "camera"),
        "height": height,
        "width": width,
        "distortion_model": "plumb_bob",
        "d": [0.0] * 5,
        "k": [fx, 0.0, width / 2, 0.0, fx, height / 2, 0.0, 0.0, 1.0],
        "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
        "p": [fx, 0.0, width / 2, 0.0, 0.0, fx, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def write_rgbd_mcap(
    path: Path,
    n_frames: int = 5,
    size: tuple[int, int] = (64, 48),
    depth: bool = True,
    depth_encoding: str = "16UC1",
    rgb_offset_ns: int = 3_000_000,
    imu: bool = True,
) -> Path:
    """An MCAP with `n_frames` depth images (frame i is a flat wall at 1 + 0.1 i metres), colour images
    `rgb_offset_ns` later, camera info, IMU samples and device poses."""
    w, h = size
    with open(path, "wb") as fh:
        writer = Writer(fh)
        schemas = {
            t: writer.register_msgdef(t, rosmsgs.definition(t))
            for t in (
                rosmsgs.IMAGE,
                rosmsgs.COMPRESSED_IMAGE,
                rosmsgs.CAMERA_INFO,
                rosmsgs.IMU,
                rosmsgs.POSE_STAMPED,
            )
        }
        writer.write_message(
            TOPICS["depth_info"], schemas[rosmsgs.CAMERA_INFO], camera_info_msg(1, w, h, 60.0), 1
        )
        for i in range(n_frames):
            t = 1_000_000_000 + i * 33_333_333
            metres = 1.0 + 0.1 * i
            if depth:
                if depth_encoding == "32FC1":
                    data = np.full((h, w), metres, "<f4").tobytes()
                    step = w * 4
                else:
                    data = np.full((h, w), round(metres * 1000), "<u2").tobytes()
                    step = w * 2
                msg = {
                    "header": rosmsgs.header(t, "depth"),
                    "height": h,
                    "width": w,
                    "encoding": depth_encoding,
                    "is_bigendian": 0,
                    "step": step,
                    "data": data,
                }
                writer.write_message(TOPICS["depth"], schemas[rosmsgs.IMAGE], msg, t)
            rgb = np.zeros((h, w, 3), np.uint8)
            rgb[..., 0] = (40 * i) % 256
            ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            assert ok
            tr = t + rgb_offset_ns
            msg = {"header": rosmsgs.header(tr, "rgb"), "format": "jpeg", "data": jpeg.tobytes()}
            writer.write_message(TOPICS["rgb_compressed"], schemas[rosmsgs.COMPRESSED_IMAGE], msg, tr)
            if imu:
                imu_msg = {
                    "header": rosmsgs.header(t, "imu"),
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    "orientation_covariance": [0.0] * 9,
                    "angular_velocity": {"x": 0.0, "y": 0.0, "z": 0.1},
                    "angular_velocity_covariance": [0.0] * 9,
                    "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.81},
                    "linear_acceleration_covariance": [0.0] * 9,
                }
                writer.write_message(TOPICS["imu"], schemas[rosmsgs.IMU], imu_msg, t)
                pose = {
                    "header": rosmsgs.header(t, "map"),
                    "pose": {
                        "position": {"x": 0.1 * i, "y": 0.0, "z": 1.4},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    },
                }
                writer.write_message(TOPICS["pose"], schemas[rosmsgs.POSE_STAMPED], pose, t)
        writer.finish()
    return path


def box_room_points(
    rng: np.random.Generator,
    size_m: tuple[float, float, float] = (4.0, 3.0, 2.7),
    spacing_m: float = 0.03,
    noise_m: float = 0.003,
) -> np.ndarray:
    """Points on the six faces of an axis-aligned box room [0, sx] x [0, sy] x [0, sz], with noise."""
    sx, sy, sz = size_m
    faces = []

    def grid(a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
        u, v = np.meshgrid(np.arange(0, a, spacing_m), np.arange(0, b, spacing_m))
        return u.ravel(), v.ravel()

    u, v = grid(sx, sy)
    faces += [np.column_stack([u, v, np.zeros_like(u)]), np.column_stack([u, v, np.full_like(u, sz)])]
    u, v = grid(sx, sz)
    faces += [np.column_stack([u, np.zeros_like(u), v]), np.column_stack([u, np.full_like(u, sy), v])]
    u, v = grid(sy, sz)
    faces += [np.column_stack([np.zeros_like(u), u, v]), np.column_stack([np.full_like(u, sx), u, v])]
    pts = np.vstack(faces)
    return pts + rng.normal(0.0, noise_m, pts.shape)


def write_box_room_ply(path: Path, rng: np.random.Generator, **kwargs: object) -> Path:
    pts = box_room_points(rng, **kwargs)  # type: ignore[arg-type]
    colors = np.full((len(pts), 3), 200, np.uint8)
    return write_ply_points(path, pts, colors)


def write_survey(root: Path, rooms: dict[str, str], sensor: str = "kinect_v1", **extra: object) -> Path:
    """survey.yaml for rooms {id: capture path relative to root}."""
    root.mkdir(parents=True, exist_ok=True)
    data = {"name": root.name, "sensor": sensor, "rooms": [{"id": k, "capture": v} for k, v in rooms.items()]}
    data.update(extra)
    (root / "survey.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    return root


def tiny_survey(root: Path, rng: np.random.Generator, frames_room: bool = False) -> Path:
    """Two box-room clouds, and with `frames_room` an RGB-D recording of a flat wall (room "c": it ingests,
    but registering it must fail: one wall, no texture)."""
    rooms = {"a": "rooms/a/cloud.ply", "b": "rooms/b/cloud.ply"}
    (root / "rooms" / "a").mkdir(parents=True)
    (root / "rooms" / "b").mkdir(parents=True)
    write_box_room_ply(root / "rooms" / "a" / "cloud.ply", rng)
    write_box_room_ply(root / "rooms" / "b" / "cloud.ply", rng, size_m=(3.0, 3.0, 2.5))
    if frames_room:
        (root / "rooms" / "c").mkdir(parents=True)
        write_rgbd_mcap(root / "rooms" / "c" / "capture.mcap")
        rooms["c"] = "rooms/c/capture.mcap"
    return write_survey(root, rooms)


def rgbd_mcap(
    path: Path,
    n: int = 4,
    size: tuple[int, int] = (64, 48),
    sizes: list[tuple[int, int]] | None = None,
    encoding: str = "16UC1",
    depth_bytes: Callable[[int, int, int], bytes] | None = None,
    jpeg: Callable[[int], bytes] | None = None,
    camera_info: bool = True,
) -> Path:
    """An MCAP of `n` depth frames (a wall 1.5 m away) with colour, frame i of size `sizes[i]`;
    `depth_bytes(i, w, h)` and `jpeg(i)` replace a frame's payload."""
    with open(path, "wb") as fh:
        from mcap_ros2.writer import Writer

        writer = Writer(fh)
        schemas = {
            t: writer.register_msgdef(t, rosmsgs.definition(t))
            for t in (rosmsgs.IMAGE, rosmsgs.COMPRESSED_IMAGE, rosmsgs.CAMERA_INFO)
        }
        w0, h0 = size
        if camera_info:
            writer.write_message(
                TOPICS["depth_info"], schemas[rosmsgs.CAMERA_INFO], camera_info_msg(1, w0, h0, 60.0), 1
            )
        for i in range(n):
            w, h = sizes[i] if sizes else size
            t = 1_000_000_000 + i * 33_333_333
            if depth_bytes is not None:
                data = depth_bytes(i, w, h)
            elif encoding == "32FC1":
                data = np.full((h, w), 1.5, "<f4").tobytes()
            else:
                data = np.full((h, w), 1500, "<u2").tobytes()
            item = 4 if encoding == "32FC1" else 2
            msg = {
                "header": rosmsgs.header(t, "depth"),
                "height": h,
                "width": w,
                "encoding": encoding,
                "is_bigendian": 0,
                "step": w * item,
                "data": data,
            }
            writer.write_message(TOPICS["depth"], schemas[rosmsgs.IMAGE], msg, t)
            if jpeg is not None:
                colour = jpeg(i)
            else:
                ok, buf = cv2.imencode(".jpg", np.full((max(h, 1), max(w, 1), 3), 90, np.uint8))
                assert ok
                colour = buf.tobytes()
            tr = t + 3_000_000
            msg = {"header": rosmsgs.header(tr, "rgb"), "format": "jpeg", "data": colour}
            writer.write_message(TOPICS["rgb_compressed"], schemas[rosmsgs.COMPRESSED_IMAGE], msg, tr)
        writer.finish()
    return path
