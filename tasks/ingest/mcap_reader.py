"""ROS 2 MCAP recordings: depth, colour, camera info, IMU and device poses, decoded without a ROS install."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks import rosmsgs
from tasks.artefacts import encode_png
from tasks.ingest.errors import IngestError, one_line
from tasks.ingest.frames import Frame, FrameReader, encode_depth, pair_nearest


class McapReader(FrameReader):
    """ROS 2 MCAP recordings, decoded with mcap-ros2-support (no ROS install)."""

    def _topic(self, override: str, *profile_keys: str) -> str:
        if override:
            return override
        topics = self.profile.get("topics") or {}
        for key in profile_keys:
            if topics.get(key):
                return topics[key]
        return ""

    def _open_reader(self, fh: Any) -> Any:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        return make_reader(fh, decoder_factories=[DecoderFactory()])

    def _channels(self) -> dict[str, str]:
        """topic -> schema name, from the summary; a truncated file (no summary) is scanned instead."""
        with open(self.path, "rb") as fh:
            try:
                reader = self._open_reader(fh)
                summary = reader.get_summary()
            except Exception as exc:
                raise IngestError(f"{self.path}: truncated or corrupt MCAP file ({one_line(exc)})") from exc
            if summary is None:
                raise IngestError(f"{self.path}: truncated MCAP (no summary section; was the recording cut?)")
            return {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}

    def frames(self) -> Iterator[Frame]:
        channels = self._channels()
        cfg = self.cfg
        rgb_topic = ""
        candidates = [cfg.rgb_topic] if cfg.rgb_topic else []
        candidates += [self._topic("", "rgb_compressed"), self._topic("", "rgb")]
        for cand in candidates:
            if cand and cand in channels:
                rgb_topic = cand
                break
        depth_topic = self._topic(cfg.depth_topic, "depth")
        disparity_topic = self._topic(cfg.disparity_topic, "disparity")
        if depth_topic in channels:
            self.depth_source = depth_topic
        elif disparity_topic and disparity_topic in channels:
            self.depth_source = disparity_topic
        else:
            wanted = " or ".join(t for t in (depth_topic, disparity_topic) if t) or "(none configured)"
            raise IngestError(
                f"{self.path}: no depth topic {wanted}; topics present: {', '.join(sorted(channels)) or 'none'}"
            )
        info_topics = {
            self._topic("", "depth_info"): "depth",
            self._topic("", "rgb_info"): "rgb",
        }
        imu_topic = self._topic(cfg.imu_topic, "imu")
        pose_topic = self._topic(cfg.pose_topic, "pose")
        topics = [
            t for t in (rgb_topic, self.depth_source, imu_topic, pose_topic, *info_topics) if t in channels
        ]
        depth_kind = (
            "disparity" if self.depth_source == disparity_topic and depth_topic not in channels else ""
        )

        def stream() -> Iterator[tuple[str, int, Any]]:
            with open(self.path, "rb") as fh:
                reader = self._open_reader(fh)
                try:
                    for _schema, channel, message, msg in reader.iter_decoded_messages(
                        topics=topics, log_time_order=True
                    ):
                        topic = channel.topic
                        t_ns = rosmsgs.stamp_ns(msg.header) if hasattr(msg, "header") else message.log_time
                        if t_ns == 0:
                            t_ns = message.log_time
                        if topic == self.depth_source:
                            yield "depth", t_ns, msg
                        elif topic == rgb_topic:
                            yield "rgb", t_ns, msg
                        elif topic in info_topics and info_topics[topic] not in self._camera_info:
                            self._camera_info[info_topics[topic]] = _camera_info_dict(msg)
                        elif topic == imu_topic:
                            self.imu.append(_imu_row(t_ns, msg))
                        elif topic == pose_topic:
                            self.poses.append(_pose_row(t_ns, msg))
                except IngestError:
                    raise
                except Exception as exc:
                    raise IngestError(f"{self.path}: corrupt MCAP data ({one_line(exc)})") from exc

        max_gap = int(cfg.max_sync_gap_ms * 1e6)
        for depth_msg, rgb_msg, rgb_t in pair_nearest(stream(), max_gap):
            depth, kind, units = _depth_from_msg(depth_msg, depth_kind, self.path)
            frame = Frame(rosmsgs.stamp_ns(depth_msg.header), encode_depth(depth), kind, units)
            frame.depth_size, frame.depth_valid = (
                (depth.shape[1], depth.shape[0]),
                int(np.count_nonzero(depth)),
            )
            if rgb_msg is not None:
                frame.rgb, frame.rgb_format, frame.rgb_size = _rgb_from_msg(rgb_msg, self.path)
                frame.rgb_t_ns = rgb_t
            yield frame


def _depth_from_msg(msg: Any, forced_kind: str, path: Path) -> tuple[NDArray[np.uint16], str, float]:
    """A depth Image as uint16 and its kind: 16UC1/mono16 millimetres (or raw disparity on the disparity
    topic), 32FC1 metres converted to millimetres."""
    enc = msg.encoding.lower()
    h, w = int(msg.height), int(msg.width)
    data = bytes(msg.data)
    stamp = rosmsgs.stamp_ns(msg.header)
    if enc not in {"16uc1", "mono16", "32fc1"}:
        raise IngestError(f"{path}: unsupported depth encoding {msg.encoding!r} (16UC1, mono16 or 32FC1)")
    if h < 1 or w < 1:
        raise IngestError(f"{path}: depth image at t = {stamp} ns is {w}x{h} pixels")
    item = 4 if enc == "32fc1" else 2
    step = int(getattr(msg, "step", 0) or w * item)
    if step < w * item or len(data) != h * step:
        raise IngestError(
            f"{path}: depth image at t = {stamp} ns holds {len(data)} bytes (row step {step}), but "
            f"{w}x{h} {msg.encoding} needs {h * w * item}: wrong encoding or damaged message"
        )
    if step != w * item:  # rows padded to `step` bytes
        data = np.frombuffer(data, np.uint8).reshape(h, step)[:, : w * item].tobytes()
    if enc in {"16uc1", "mono16"}:
        dtype = ">u2" if msg.is_bigendian else "<u2"
        arr = np.frombuffer(data, dtype=dtype, count=h * w).reshape(h, w).astype(np.uint16)
        if forced_kind == "disparity":
            return arr, "disparity", 0.0
        return arr, "mm", 1000.0
    if enc == "32fc1":
        dtype = ">f4" if msg.is_bigendian else "<f4"
        metres = np.frombuffer(data, dtype=dtype, count=h * w).reshape(h, w)
        mm = np.where(np.isfinite(metres) & (metres > 0), np.round(metres * 1000.0), 0)
        return np.clip(mm, 0, 65535).astype(np.uint16), "mm", 1000.0
    raise AssertionError(enc)


def _rgb_from_msg(msg: Any, path: Path) -> tuple[bytes, str, tuple[int, int] | None]:
    """Colour as encoded bytes and the image's size: CompressedImage bytes as they are (size None: ingest
    decodes them to check), raw Images encoded as PNG."""
    if hasattr(msg, "format"):  # CompressedImage
        fmt = "png" if "png" in msg.format.lower() else "jpeg"
        return bytes(msg.data), fmt, None
    enc = msg.encoding.lower()
    h, w = int(msg.height), int(msg.width)
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4}.get(enc)
    if channels is None:
        raise IngestError(f"{path}: unsupported colour encoding {msg.encoding!r}")
    data = bytes(msg.data)
    step = int(getattr(msg, "step", 0) or w * channels)
    if h < 1 or w < 1 or step < w * channels or len(data) != h * step:
        raise IngestError(
            f"{path}: colour image at t = {rosmsgs.stamp_ns(msg.header)} ns holds {len(data)} bytes, "
            f"{w}x{h} {msg.encoding} needs {h * w * channels}"
        )
    if step != w * channels:  # rows padded to `step` bytes
        data = np.frombuffer(data, np.uint8).reshape(h, step)[:, : w * channels].tobytes()
    arr = np.frombuffer(data, np.uint8, count=h * w * channels).reshape(h, w, channels)
    if enc.startswith("bgr"):
        arr = arr[:, :, 2::-1]
    elif channels == 1:
        arr = np.repeat(arr, 3, axis=2)
    return encode_png(np.ascontiguousarray(arr[:, :, :3])), "png", (w, h)


def _camera_info_dict(msg: Any) -> dict[str, Any]:
    return {
        "K": np.asarray(msg.k, dtype=np.float64).reshape(3, 3).tolist(),
        "dist": [float(v) for v in msg.d][:5] + [0.0] * max(0, 5 - len(msg.d)),
        "size": [int(msg.width), int(msg.height)],
        "distortion_model": msg.distortion_model,
        "source": "camera_info",
    }


def _imu_row(t_ns: int, msg: Any) -> dict[str, Any]:
    av, la = msg.angular_velocity, msg.linear_acceleration
    return {"t_ns": t_ns, "wx": av.x, "wy": av.y, "wz": av.z, "ax": la.x, "ay": la.y, "az": la.z}


def _pose_row(t_ns: int, msg: Any) -> dict[str, Any]:
    p, q = msg.pose.position, msg.pose.orientation
    return {"t_ns": t_ns, "qw": q.w, "qx": q.x, "qy": q.y, "qz": q.z, "tx": p.x, "ty": p.y, "tz": p.z}
