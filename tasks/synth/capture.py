"""Write synthetic RGB-D frames as an MCAP recording with ROS 2 messages (no ROS install needed).

Colour goes out as sensor_msgs/CompressedImage (JPEG at a fixed quality), depth as sensor_msgs/Image
16UC1 millimetres, each stream's sensor_msgs/CameraInfo once, optionally sensor_msgs/Imu; topic names
come from the sensor profile. The output bytes depend only on the inputs (no wall-clock metadata).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer
from numpy.typing import NDArray

from tasks import rosmsgs
from tasks.synth.sensor import CameraModel, camera_model


@dataclass(frozen=True)
class CaptureConfig:
    """Encoding of the capture recording."""

    jpeg_quality: int = 88
    """JPEG quality of the colour frames (fixed, so output bytes are deterministic)."""
    chunk_size_bytes: int = 4 * 1024 * 1024
    """MCAP chunk size before zstd compression (bytes)."""
    rgb_frame_id: str = "camera_rgb_optical_frame"
    """Header frame_id of colour images and their CameraInfo."""
    depth_frame_id: str = "camera_depth_optical_frame"
    """Header frame_id of depth images and their CameraInfo."""
    imu_frame_id: str = "imu_link"
    """Header frame_id of IMU messages."""


def camera_info_msg(cam: CameraModel, t_ns: int, frame_id: str) -> dict:
    """A sensor_msgs/CameraInfo dict: K, plumb_bob d (k1 k2 p1 p2 k3), identity R, P = [K | 0]."""
    K = np.asarray(cam.K, dtype=np.float64)
    P = np.concatenate([K, np.zeros((3, 1))], axis=1)
    return {
        "header": rosmsgs.header(int(t_ns), frame_id),
        "height": int(cam.height),
        "width": int(cam.width),
        "distortion_model": "plumb_bob",
        "d": [float(x) for x in cam.dist],
        "k": [float(x) for x in K.ravel()],
        "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        "p": [float(x) for x in P.ravel()],
        "binning_x": 0,
        "binning_y": 0,
        "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0, "do_rectify": False},
    }


def encode_jpeg(rgb: NDArray[np.uint8], quality: int) -> bytes:
    """JPEG bytes of an RGB image (H, W, 3) uint8."""
    ok, buf = cv2.imencode(
        ".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    )
    if not ok:
        raise ValueError("JPEG encoding of a colour frame failed")
    return buf.tobytes()


def write_capture_mcap(
    path: str | Path,
    frames: Iterable[tuple[int, NDArray[np.uint8], NDArray[np.uint16]]],
    profile: dict,
    size: str,
    imu: Iterable[tuple[int, NDArray[np.float64], NDArray[np.float64]]] | None = None,
    cfg: CaptureConfig = CaptureConfig(),
) -> None:
    """Stream frames (t_ns, rgb (H, W, 3) uint8, depth_mm (H', W') uint16) into an MCAP file at `path`.

    Frames are consumed one at a time (never all in memory) and must have increasing timestamps and the
    profile's image sizes at `size`. imu, if given: (t_ns, angular_velocity (3,) rad/s,
    linear_acceleration (3,) m/s^2) samples, written on the profile's imu topic after the frames."""
    topics = profile.get("topics") or {}
    for key in ("rgb_compressed", "depth", "rgb_info", "depth_info"):
        if not topics.get(key):
            raise ValueError(f"sensor profile {profile.get('name')!r} has no topics.{key}")
    rgb_cam = camera_model(profile, "rgb", size)
    ir_cam = camera_model(profile, "ir", size)
    path = Path(path)
    with open(path, "wb") as f:
        writer = Writer(f, chunk_size=cfg.chunk_size_bytes, compression=CompressionType.ZSTD)
        schemas = {
            name: writer.register_msgdef(name, rosmsgs.definition(name))
            for name in (rosmsgs.COMPRESSED_IMAGE, rosmsgs.IMAGE, rosmsgs.CAMERA_INFO)
        }
        last_t = None
        for t_ns, rgb, depth_mm in frames:
            t_ns = int(t_ns)
            if last_t is not None and t_ns <= last_t:
                raise ValueError(f"frame timestamps must increase: {t_ns} after {last_t}")
            rgb = np.asarray(rgb)
            depth_mm = np.asarray(depth_mm)
            if rgb.shape != (rgb_cam.height, rgb_cam.width, 3) or rgb.dtype != np.uint8:
                raise ValueError(
                    f"colour frame at {t_ns} is {rgb.shape} {rgb.dtype}, expected "
                    f"({rgb_cam.height}, {rgb_cam.width}, 3) uint8"
                )
            if depth_mm.shape != (ir_cam.height, ir_cam.width) or depth_mm.dtype != np.uint16:
                raise ValueError(
                    f"depth frame at {t_ns} is {depth_mm.shape} {depth_mm.dtype}, expected "
                    f"({ir_cam.height}, {ir_cam.width}) uint16"
                )
            if last_t is None:
                writer.write_message(
                    topics["rgb_info"],
                    schemas[rosmsgs.CAMERA_INFO],
                    camera_info_msg(rgb_cam, t_ns, cfg.rgb_frame_id),
                    log_time=t_ns,
                    publish_time=t_ns,
                )
                writer.write_message(
                    topics["depth_info"],
                    schemas[rosmsgs.CAMERA_INFO],
                    camera_info_msg(ir_cam, t_ns, cfg.depth_frame_id),
                    log_time=t_ns,
                    publish_time=t_ns,
                )
            writer.write_message(
                topics["rgb_compressed"],
                schemas[rosmsgs.COMPRESSED_IMAGE],
                {
                    "header": rosmsgs.header(t_ns, cfg.rgb_frame_id),
                    "format": "jpeg",
                    "data": encode_jpeg(rgb, cfg.jpeg_quality),
                },
                log_time=t_ns,
                publish_time=t_ns,
            )
            depth_le = depth_mm.astype("<u2", copy=False)
            writer.write_message(
                topics["depth"],
                schemas[rosmsgs.IMAGE],
                {
                    "header": rosmsgs.header(t_ns, cfg.depth_frame_id),
                    "height": int(depth_mm.shape[0]),
                    "width": int(depth_mm.shape[1]),
                    "encoding": "16UC1",
                    "is_bigendian": 0,
                    "step": int(depth_mm.shape[1] * 2),
                    "data": depth_le.tobytes(),
                },
                log_time=t_ns,
                publish_time=t_ns,
            )
            last_t = t_ns
        if last_t is None:
            raise ValueError(f"no frames to write to {path}")
        if imu is not None:
            if not topics.get("imu"):
                raise ValueError(f"sensor profile {profile.get('name')!r} has no topics.imu")
            imu_schema = writer.register_msgdef(rosmsgs.IMU, rosmsgs.definition(rosmsgs.IMU))
            unknown = [-1.0] + [0.0] * 8  # orientation not provided (REP 145)
            for t_ns, gyro, accel in imu:
                g = [float(x) for x in np.asarray(gyro, dtype=np.float64).reshape(3)]
                a = [float(x) for x in np.asarray(accel, dtype=np.float64).reshape(3)]
                writer.write_message(
                    topics["imu"],
                    imu_schema,
                    {
                        "header": rosmsgs.header(int(t_ns), cfg.imu_frame_id),
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                        "orientation_covariance": unknown,
                        "angular_velocity": {"x": g[0], "y": g[1], "z": g[2]},
                        "angular_velocity_covariance": [0.0] * 9,
                        "linear_acceleration": {"x": a[0], "y": a[1], "z": a[2]},
                        "linear_acceleration_covariance": [0.0] * 9,
                    },
                    log_time=int(t_ns),
                    publish_time=int(t_ns),
                )
        writer.finish()
