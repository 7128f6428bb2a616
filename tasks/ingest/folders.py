"""Frame folders on disk: TUM RGB-D benchmark folders and Microsoft 7-Scenes sequences."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.ingest.errors import IngestError
from tasks.ingest.frames import Frame, FrameReader, encode_depth, pair_nearest


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
        for (t_ns, depth_path), rgb_path, _ in pair_nearest(
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
            frame = Frame(t_ns, encode_depth(depth), "mm", 1000.0)
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
