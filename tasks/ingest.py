"""Ingest (thesis 3.1): read a room capture into the pipeline's own artefacts.

Captures come in three shapes, each behind a reader:
- an MCAP recording of ROS 2 messages (sensor_msgs/Image, CompressedImage, CameraInfo, Imu and
  geometry_msgs/PoseStamped), decoded without a ROS install; topic names from the sensor profile;
- a TUM RGB-D folder (rgb.txt, depth.txt, associated by timestamp) or a 7-Scenes folder
  (frame-XXXXXX.color.jpg / .depth.png / .pose.txt);
- a registered room cloud (PLY or PCD, metres).

RGB-D captures become `frames.parquet` (one row per depth frame with its nearest colour image, depth as a
lossless 16-bit PNG) plus `camera_info.json`, and, when the capture has them, `imu.parquet` and
`device_poses.parquet`. Frames are streamed: memory does not grow with the recording's length.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from tasks import rosmsgs
from tasks.artefacts import FRAMES_SCHEMA, encode_png, read_cloud, write_cloud, write_json, write_table

CAPTURE_KINDS = ("mcap", "tum", "7scenes", "cloud")


class IngestError(ValueError):
    """A capture that cannot be read; the one-line message names the file and what is wrong."""


@dataclass(frozen=True)
class IngestConfig:
    """Reading captures. Topic names default to the sensor profile's (configs/sensors/*.yaml)."""

    rgb_topic: str = ""
    """Colour topic (Image or CompressedImage); empty = the profile's `rgb_compressed`, then `rgb`."""
    depth_topic: str = ""
    """Depth topic (Image 16UC1 mm or 32FC1 m); empty = the profile's `depth`."""
    disparity_topic: str = ""
    """Raw Kinect v1 disparity topic, used when there is no depth topic; empty = the profile's."""
    imu_topic: str = ""
    """IMU topic (optional); empty = the profile's."""
    pose_topic: str = ""
    """Device pose topic, PoseStamped (optional); empty = the profile's."""
    max_sync_gap_ms: float = 20.0
    """A depth frame is paired with the nearest colour image within this time; farther = no colour."""
    frame_stride: int = 1
    """Keep every n-th depth frame (1 = all)."""
    max_frames: int = 0
    """Stop after this many frames (0 = all)."""
    tum_depth_units_per_m: float = 5000.0
    """TUM RGB-D depth PNG units per metre."""
    max_cloud_extent_m: float = 300.0
    """A registered cloud spreading wider than this (1st to 99th percentile, x or y) is not in metres."""
    max_cloud_height_m: float = 30.0
    """...or higher than this (z roughly up: a room, a storey or a stairwell)."""


@dataclass
class Frame:
    """One depth frame and its colour image, as stored in frames.parquet."""

    t_ns: int
    depth_png: bytes
    depth_kind: str  # "mm" | "tum5000" | "disparity"
    depth_units_per_m: float
    rgb: bytes = b""
    rgb_format: str = ""
    rgb_t_ns: int = -1


ProgressFn = Callable[[str], None]


def capture_kind(path: Path) -> str:
    """What reader a capture needs, from its name and contents; a clear error when none fits."""
    path = Path(path)
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".mcap":
            return "mcap"
        if suffix in {".ply", ".pcd"}:
            return "cloud"
        if suffix in {".las", ".laz"}:
            raise IngestError(f"{path}: LAS/LAZ clouds are not supported; convert to PLY or PCD")
        raise IngestError(f"{path}: unknown capture format {suffix!r} (MCAP, PLY, PCD or a TUM folder)")
    if path.is_dir():
        if (path / "rgb.txt").is_file() and (path / "depth.txt").is_file():
            return "tum"
        if any(path.glob("frame-*.depth.png")):
            return "7scenes"
        raise IngestError(f"{path}: folder is neither a TUM RGB-D folder (rgb.txt, depth.txt) nor 7-Scenes")
    raise IngestError(f"{path}: no such capture file or folder")


def ingest_capture(
    path: Path,
    out_dir: Path,
    profile: dict[str, Any],
    cfg: IngestConfig,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Read one capture into `out_dir` (a fresh folder the artefact store commits). Returns metrics."""
    kind = capture_kind(path)
    started = time.perf_counter()
    if kind == "cloud":
        cloud = read_cloud(path)
        check_cloud_units(cloud.points, path, cfg)
        write_cloud(out_dir / "cloud.ply", cloud)
        metrics: dict[str, Any] = {"points": len(cloud), "coloured": cloud.colors is not None}
    else:
        reader = {"mcap": McapReader, "tum": TumReader, "7scenes": SevenScenesReader}[kind](
            path, profile, cfg
        )
        metrics = write_frames(reader, out_dir, cfg, progress)
    metrics.update(capture_kind=kind, seconds=round(time.perf_counter() - started, 3))
    return metrics


def check_cloud_units(points: NDArray[np.float64], path: Path, cfg: IngestConfig) -> None:
    """Raise a one-line IngestError when a registered cloud's spread (1st to 99th percentile) cannot be a
    room's in metres, naming the unit it looks like (from its height against a 2.7 m storey)."""
    lo, hi = np.percentile(points, [1, 99], axis=0)
    size = hi - lo
    if size[:2].max() <= cfg.max_cloud_extent_m and size[2] <= cfg.max_cloud_height_m:
        return
    ratio = size[2] / 2.7
    guess = next(
        (
            name
            for name, k in (("millimetres", 1000.0), ("centimetres", 100.0), ("inches", 39.37))
            if 0.4 < ratio / k < 2.5
        ),
        "another unit",
    )
    raise IngestError(
        f"{path}: the cloud spans {size[0]:.4g} x {size[1]:.4g} x {size[2]:.4g} units (1-99 %), too large for a "
        f"room in metres (it looks like {guess}); convert it to metres"
    )


def write_frames(
    reader: FrameReader, out_dir: Path, cfg: IngestConfig, progress: ProgressFn | None
) -> dict[str, Any]:
    """Stream a reader's frames into frames.parquet in row groups, then its side tables."""
    frames_path = out_dir / "frames.parquet"
    batch: list[Frame] = []
    count = coloured = 0
    writer = pq.ParquetWriter(frames_path, FRAMES_SCHEMA, compression="zstd")
    try:
        for index, frame in enumerate(reader.frames()):
            if index % max(cfg.frame_stride, 1):
                continue
            batch.append(frame)
            count += 1
            coloured += bool(frame.rgb)
            if len(batch) == 16:
                writer.write_table(_frames_table(batch, count - len(batch)))
                batch = []
                if progress:
                    progress(f"{count} frames")
            if cfg.max_frames and count >= cfg.max_frames:
                break
        if batch:
            writer.write_table(_frames_table(batch, count - len(batch)))
    finally:
        writer.close()
    if count == 0:
        raise IngestError(f"{reader.path}: no depth frames found ({reader.depth_source})")
    write_json(out_dir / "camera_info.json", reader.camera_info())
    if reader.imu:
        write_table(out_dir / "imu.parquet", _columns(reader.imu))
    if reader.poses:
        write_table(out_dir / "device_poses.parquet", _columns(reader.poses))
    return {
        "frames": count,
        "frames_with_colour": coloured,
        "depth_source": reader.depth_source,
        "imu_samples": len(reader.imu),
        "device_poses": len(reader.poses),
    }


def _frames_table(batch: list[Frame], first_id: int) -> pa.Table:
    return pa.table(
        {
            "frame_id": np.arange(first_id, first_id + len(batch), dtype=np.int32),
            "t_ns": [f.t_ns for f in batch],
            "rgb_t_ns": [f.rgb_t_ns for f in batch],
            "rgb": [f.rgb for f in batch],
            "rgb_format": [f.rgb_format for f in batch],
            "depth": [f.depth_png for f in batch],
            "depth_kind": [f.depth_kind for f in batch],
            "depth_units_per_m": [f.depth_units_per_m for f in batch],
        },
        schema=FRAMES_SCHEMA,
    )


def _columns(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    return {key: [row[key] for row in rows] for key in rows[0]}


# ------------------------------------------------------------------------------------------ frame access


def iter_frames(frames_path: Path, columns: list[str] | None = None) -> Iterator[dict[str, Any]]:
    """Rows of frames.parquet one at a time (row group by row group: bounded memory)."""
    pf = pq.ParquetFile(frames_path)
    for group in range(pf.num_row_groups):
        yield from pf.read_row_group(group, columns=columns).to_pylist()


def decode_depth_m(row: dict[str, Any]) -> NDArray[np.float32]:
    """A frames.parquet row's depth in metres (0 = no return). Raw disparity is not metric: use the
    calibration's disparity model for kind "disparity"."""
    import cv2

    if row["depth_kind"] == "disparity":
        raise ValueError("raw disparity needs the calibration's disparity model to become metres")
    raw = cv2.imdecode(np.frombuffer(row["depth"], np.uint8), cv2.IMREAD_UNCHANGED)
    return raw.astype(np.float32) / np.float32(row["depth_units_per_m"])


def decode_rgb(row: dict[str, Any]) -> NDArray[np.uint8] | None:
    """A frames.parquet row's colour image as (H, W, 3) RGB, or None when the frame has none."""
    import cv2

    if not row["rgb"]:
        return None
    img = cv2.imdecode(np.frombuffer(row["rgb"], np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# ----------------------------------------------------------------------------------------------- readers


class FrameReader:
    """A capture seen as a stream of frames plus camera info, IMU samples and device poses."""

    def __init__(self, path: Path, profile: dict[str, Any], cfg: IngestConfig) -> None:
        self.path = Path(path)
        self.profile = profile
        self.cfg = cfg
        self.imu: list[dict[str, Any]] = []
        self.poses: list[dict[str, Any]] = []
        self.depth_source = ""
        self._camera_info: dict[str, Any] = {}

    def frames(self) -> Iterator[Frame]:
        raise NotImplementedError

    def camera_info(self) -> dict[str, Any]:
        """Intrinsics per stream, from the capture where it has them, else the sensor profile."""
        info = dict(self._camera_info)
        for stream, key in (("depth", "ir"), ("rgb", "rgb")):
            if stream not in info and key in self.profile:
                cam = self.profile[key]
                info[stream] = {"K": cam["K"], "dist": cam["dist"], "size": cam["size"], "source": "profile"}
        info["sensor"] = self.profile.get("name", "")
        return info


def _encode_depth(depth: NDArray[Any]) -> bytes:
    return encode_png(depth)


def _pair_nearest(stream: Iterator[tuple[str, int, Any]], max_gap_ns: int) -> Iterator[tuple[Any, Any, int]]:
    """Pair each depth item with the nearest colour item in time, streaming: items arrive ordered by
    time as ("depth" | "rgb", t_ns, payload); yields (depth_payload, rgb_payload | None, rgb_t_ns)."""
    pending: list[tuple[int, Any]] = []
    last_rgb: tuple[int, Any] | None = None

    def resolve(next_rgb: tuple[int, Any] | None) -> Iterator[tuple[Any, Any, int]]:
        for t, depth in pending:
            best = None
            for cand in (last_rgb, next_rgb):
                if cand is not None and abs(cand[0] - t) <= max_gap_ns:
                    if best is None or abs(cand[0] - t) < abs(best[0] - t):
                        best = cand
            yield (depth, best[1], best[0]) if best else (depth, None, -1)
        pending.clear()

    for kind, t_ns, payload in stream:
        if kind == "depth":
            pending.append((t_ns, payload))
        else:
            yield from resolve((t_ns, payload))
            last_rgb = (t_ns, payload)
    yield from resolve(None)


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
                raise IngestError(f"{self.path}: truncated or corrupt MCAP file ({_one_line(exc)})") from exc
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
                    raise IngestError(f"{self.path}: corrupt MCAP data ({_one_line(exc)})") from exc

        max_gap = int(cfg.max_sync_gap_ms * 1e6)
        for depth_msg, rgb_msg, rgb_t in _pair_nearest(stream(), max_gap):
            depth, kind, units = _depth_from_msg(depth_msg, depth_kind, self.path)
            frame = Frame(rosmsgs.stamp_ns(depth_msg.header), _encode_depth(depth), kind, units)
            if rgb_msg is not None:
                frame.rgb, frame.rgb_format = _rgb_from_msg(rgb_msg, self.path)
                frame.rgb_t_ns = rgb_t
            yield frame


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__


def _depth_from_msg(msg: Any, forced_kind: str, path: Path) -> tuple[NDArray[np.uint16], str, float]:
    """A depth Image as uint16 and its kind: 16UC1/mono16 millimetres (or raw disparity on the disparity
    topic), 32FC1 metres converted to millimetres."""
    enc = msg.encoding.lower()
    h, w = int(msg.height), int(msg.width)
    data = bytes(msg.data)
    if enc in {"16uc1", "mono16"}:
        dtype = ">u2" if msg.is_bigendian else "<u2"
        if len(data) < h * w * 2:
            raise IngestError(f"{path}: depth image of {len(data)} bytes is too small for {w}x{h} 16-bit")
        arr = np.frombuffer(data, dtype=dtype, count=h * w).reshape(h, w).astype(np.uint16)
        if forced_kind == "disparity":
            return arr, "disparity", 0.0
        return arr, "mm", 1000.0
    if enc == "32fc1":
        dtype = ">f4" if msg.is_bigendian else "<f4"
        metres = np.frombuffer(data, dtype=dtype, count=h * w).reshape(h, w)
        mm = np.where(np.isfinite(metres) & (metres > 0), np.round(metres * 1000.0), 0)
        return np.clip(mm, 0, 65535).astype(np.uint16), "mm", 1000.0
    raise IngestError(f"{path}: unsupported depth encoding {msg.encoding!r} (16UC1, mono16 or 32FC1)")


def _rgb_from_msg(msg: Any, path: Path) -> tuple[bytes, str]:
    """Colour as encoded bytes: CompressedImage bytes as they are, raw Images encoded as PNG."""
    if hasattr(msg, "format"):  # CompressedImage
        fmt = "png" if "png" in msg.format.lower() else "jpeg"
        return bytes(msg.data), fmt
    enc = msg.encoding.lower()
    h, w = int(msg.height), int(msg.width)
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4, "bgra8": 4}.get(enc)
    if channels is None:
        raise IngestError(f"{path}: unsupported colour encoding {msg.encoding!r}")
    arr = np.frombuffer(bytes(msg.data), np.uint8, count=h * w * channels).reshape(h, w, channels)
    if enc.startswith("bgr"):
        arr = arr[:, :, 2::-1]
    elif channels == 1:
        arr = np.repeat(arr, 3, axis=2)
    return encode_png(np.ascontiguousarray(arr[:, :, :3])), "png"


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


class TumReader(FrameReader):
    """TUM RGB-D benchmark folders: rgb.txt and depth.txt ('timestamp filename' lines)."""

    def _list(self, name: str) -> list[tuple[int, Path]]:
        entries = []
        list_path = self.path / name
        for line_no, line in enumerate(list_path.read_text().splitlines(), 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            parts = line.split()
            try:
                entries.append((round(float(parts[0]) * 1e9), self.path / parts[1]))
            except (ValueError, IndexError) as exc:
                raise IngestError(f"{list_path}:{line_no}: expected 'timestamp filename'") from exc
        return entries

    def frames(self) -> Iterator[Frame]:
        self.depth_source = "depth.txt"
        depth = [("depth", t, (t, p)) for t, p in self._list("depth.txt")]
        rgb = [("rgb", t, p) for t, p in self._list("rgb.txt")]
        merged = sorted(depth + rgb, key=lambda item: (item[1], item[0] == "rgb"))
        rgb_times = {p: t for _, t, p in rgb}
        units = self.cfg.tum_depth_units_per_m
        for (t_ns, depth_path), rgb_path, _ in _pair_nearest(
            iter(merged), int(self.cfg.max_sync_gap_ms * 1e6)
        ):
            frame = Frame(t_ns, _read_png16(depth_path), "tum5000", units)
            if rgb_path is not None:
                frame.rgb, frame.rgb_format = _read_bytes(rgb_path), _image_format(rgb_path)
                frame.rgb_t_ns = rgb_times[rgb_path]
            yield frame


class SevenScenesReader(FrameReader):
    """Microsoft 7-Scenes folders: frame-XXXXXX.{color.jpg,depth.png,pose.txt}, depth in mm with 65535 as
    no return, camera-to-world poses; intrinsics from camera-intrinsics.txt when present."""

    FPS = 30.0

    def frames(self) -> Iterator[Frame]:
        import cv2

        self.depth_source = "frame-*.depth.png"
        intr = self.path / "camera-intrinsics.txt"
        if intr.is_file():
            K = np.loadtxt(intr).reshape(3, 3)
            cam = {"K": K.tolist(), "dist": [0.0] * 5, "size": [640, 480], "source": "camera-intrinsics.txt"}
            self._camera_info = {"depth": cam, "rgb": dict(cam)}
        pattern = re.compile(r"frame-(\d+)\.depth\.png$")
        for depth_path in sorted(self.path.glob("frame-*.depth.png")):
            match = pattern.search(depth_path.name)
            if not match:
                continue
            number = int(match.group(1))
            t_ns = int(number / self.FPS * 1e9)
            depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
            if depth is None or depth.dtype != np.uint16:
                raise IngestError(f"{depth_path}: not a 16-bit depth PNG")
            depth = np.where(depth == 65535, 0, depth).astype(np.uint16)
            frame = Frame(t_ns, _encode_depth(depth), "mm", 1000.0)
            color = depth_path.with_name(f"frame-{match.group(1)}.color.jpg")
            if color.is_file():
                frame.rgb, frame.rgb_format, frame.rgb_t_ns = _read_bytes(color), "jpeg", t_ns
            pose_path = depth_path.with_name(f"frame-{match.group(1)}.pose.txt")
            if pose_path.is_file():
                self.poses.append(_matrix_pose_row(t_ns, np.loadtxt(pose_path).reshape(4, 4)))
            yield frame


def _matrix_pose_row(t_ns: int, T: NDArray[np.float64]) -> dict[str, Any]:
    from scipy.spatial.transform import Rotation

    qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
    return {"t_ns": t_ns, "qw": qw, "qx": qx, "qy": qy, "qz": qz, "tx": T[0, 3], "ty": T[1, 3], "tz": T[2, 3]}


def _read_bytes(path: Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise IngestError(f"{path}: cannot read ({exc.strerror})") from exc


def _read_png16(path: Path) -> bytes:
    data = _read_bytes(path)
    if not data.startswith(b"\x89PNG"):
        raise IngestError(f"{path}: depth is not a PNG file")
    return data


def _image_format(path: Path) -> str:
    return "png" if Path(path).suffix.lower() == ".png" else "jpeg"
