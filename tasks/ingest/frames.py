"""RGB-D frames: the reader interface every frame capture implements, the streaming writer of
frames.parquet and its side tables, and row access to frames.parquet for the stages downstream."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from tasks.artefacts import FRAMES_SCHEMA, encode_png, write_json, write_table
from tasks.context import ProgressFn
from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError


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
    depth_size: tuple[int, int] | None = None
    """(width, height) of the depth image, when the reader has it decoded (else it is decoded to check)."""
    depth_valid: int | None = None
    """Pixels with a depth reading (non-zero), likewise."""
    rgb_size: tuple[int, int] | None = None
    """(width, height) of the colour image, when the reader made it (raw images it encoded itself)."""


class FrameCheck:
    """What ingest checks of every frame before it trusts a capture: depth images that decode, all of one
    size, not all empty; colour images that decode (a frame whose colour does not keeps its depth,
    uncoloured, and is counted), all of one size."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.depth_size: tuple[int, int] | None = None
        self.rgb_size: tuple[int, int] | None = None
        self.valid_pixels = 0
        self.colour_given = 0
        self.colour_undecodable = 0

    def __call__(self, frame: Frame, index: int) -> Frame:
        import cv2

        where = f"{self.path}: frame {index} (t = {frame.t_ns} ns)"
        size, valid = frame.depth_size, frame.depth_valid
        if size is None or valid is None:
            depth = cv2.imdecode(np.frombuffer(frame.depth_png, np.uint8), cv2.IMREAD_UNCHANGED)
            if depth is None or depth.ndim != 2 or depth.dtype != np.uint16:
                raise IngestError(f"{where}: the depth image is not a 16-bit single-channel image")
            size, valid = (depth.shape[1], depth.shape[0]), int(np.count_nonzero(depth))
        if size[0] < 1 or size[1] < 1:
            raise IngestError(f"{where}: the depth image is {size[0]}x{size[1]} pixels")
        if self.depth_size is None:
            self.depth_size = size
        elif size != self.depth_size:
            raise IngestError(
                f"{where}: the depth image is {size[0]}x{size[1]}, the first was "
                f"{self.depth_size[0]}x{self.depth_size[1]} (frames of mixed sizes)"
            )
        self.valid_pixels += valid
        if frame.rgb:
            self.colour_given += 1
            rgb_size = frame.rgb_size
            if rgb_size is None:
                image = cv2.imdecode(np.frombuffer(frame.rgb, np.uint8), cv2.IMREAD_COLOR)
                rgb_size = None if image is None or image.size == 0 else (image.shape[1], image.shape[0])
            if rgb_size is None:
                self.colour_undecodable += 1
                frame.rgb, frame.rgb_format, frame.rgb_t_ns = b"", "", -1
            elif self.rgb_size is None:
                self.rgb_size = rgb_size
            elif rgb_size != self.rgb_size:
                raise IngestError(
                    f"{where}: the colour image is {rgb_size[0]}x{rgb_size[1]}, the first was "
                    f"{self.rgb_size[0]}x{self.rgb_size[1]} (frames of mixed sizes)"
                )
        return frame

    def finish(self, source: str) -> None:
        if self.valid_pixels == 0:
            raise IngestError(f"{self.path}: every depth image is empty (no pixel has a depth; {source})")
        if self.colour_given and self.colour_undecodable == self.colour_given:
            raise IngestError(f"{self.path}: none of the {self.colour_given} colour images can be decoded")


def write_frames(
    reader: FrameReader, out_dir: Path, cfg: IngestConfig, progress: ProgressFn | None
) -> dict[str, Any]:
    """Stream a reader's frames into frames.parquet in row groups, then its side tables."""
    frames_path = out_dir / "frames.parquet"
    batch: list[Frame] = []
    count = coloured = 0
    check = FrameCheck(reader.path)
    writer = pq.ParquetWriter(frames_path, FRAMES_SCHEMA, compression="zstd")
    try:
        for index, frame in enumerate(reader.frames()):
            if index % max(cfg.frame_stride, 1):
                continue
            batch.append(check(frame, index))
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
    check.finish(reader.depth_source)
    if check.colour_undecodable and progress:
        progress(f"{check.colour_undecodable} of {check.colour_given} colour images cannot be decoded")
    write_json(out_dir / "camera_info.json", reader.camera_info(check.depth_size, check.rgb_size))
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
        "colour_undecodable": check.colour_undecodable,
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
    if img is None:  # ingest drops undecodable colour; an older frames.parquet may still hold some
        return None
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# ---------------------------------------------------------------------------------------- reader interface


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

    def camera_info(
        self, depth_size: tuple[int, int] | None = None, rgb_size: tuple[int, int] | None = None
    ) -> dict[str, Any]:
        """Intrinsics per stream, from the capture where it has them, else the sensor profile's, scaled to
        the frames' size when the stream runs at another resolution of the same aspect (a Kinect's
        320x240 mode); `frame_sizes` records the sizes the frames have."""
        info = dict(self._camera_info)
        sizes = {"depth": depth_size, "rgb": rgb_size}
        for stream, key in (("depth", "ir"), ("rgb", "rgb")):
            if stream not in info and key in self.profile:
                cam = self.profile[key]
                entry = {"K": cam["K"], "dist": cam["dist"], "size": cam["size"], "source": "profile"}
                info[stream] = scaled_intrinsics(entry, sizes[stream], self.path, stream)
        info["sensor"] = self.profile.get("name", "")
        info["frame_sizes"] = {k: list(v) for k, v in sizes.items() if v is not None}
        return info


def scaled_intrinsics(
    entry: dict[str, Any], size: tuple[int, int] | None, path: Path, stream: str
) -> dict[str, Any]:
    """A sensor profile's intrinsics (K, size) moved to the frames' `size`: the same camera binned or
    upsampled, pixel centres kept; a one-line IngestError when the aspect differs (another camera)."""
    w0, h0 = (int(v) for v in entry["size"])
    if size is None or (w0, h0) == tuple(size):
        return entry
    sx, sy = size[0] / w0, size[1] / h0
    if abs(sx - sy) > 1e-6:
        raise IngestError(
            f"{path}: the {stream} frames are {size[0]}x{size[1]}, the sensor profile's camera is {w0}x{h0} "
            "(another aspect): give the capture's intrinsics (CameraInfo, calibration:) or --intrinsics"
        )
    K = np.array(entry["K"], dtype=np.float64)
    K[0, 0] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return {**entry, "K": K.tolist(), "size": [int(size[0]), int(size[1])], "scaled_from": [w0, h0]}


def encode_depth(depth: NDArray[Any]) -> bytes:
    """An (H, W) uint16 depth image as the lossless PNG frames.parquet stores."""
    return encode_png(depth)


def pair_nearest(stream: Iterator[tuple[str, int, Any]], max_gap_ns: int) -> Iterator[tuple[Any, Any, int]]:
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
