"""E57 files (ASTM E2807), as terrestrial laser scanners and their survey software export them: one scan
per scanner setup, each with its points in the setup's own frame and the setup's pose in the file.

Scans are read chunk by chunk through libE57 (pye57), moved by their pose into the file's frame and
merged; colour and intensity are kept when every scan has them. Points a scan flags invalid (no return)
are dropped.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.ingest.errors import IngestError
from tasks.ingest.scanners import ScanChunk, ScannerReader, crs_record

CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
COLOURS = ("colorRed", "colorGreen", "colorBlue")


class E57Reader(ScannerReader):
    """The scans of one E57 file, merged in the file's frame."""

    format = "e57"

    def __init__(self, path: Path) -> None:
        import pye57

        super().__init__(path)
        try:
            self._e57 = pye57.E57(str(self.path))
            self._scans = [self._e57.get_header(i) for i in range(self._e57.scan_count)]
        except Exception as exc:
            raise IngestError(_open_error(self.path, exc)) from exc
        if not self._scans:
            self._e57.close()
            raise IngestError(f"{self.path}: the E57 file holds no scans (no points)")
        fields = [set(scan.point_fields) for scan in self._scans]
        for scan, names in zip(self._scans, fields, strict=True):
            if not (set(CARTESIAN) <= names or set(SPHERICAL) <= names):
                raise IngestError(
                    f"{self.path}: scan {_name(scan)!r} has neither cartesian nor spherical coordinates"
                )
        self.has_colour = all(set(COLOURS) <= names for names in fields)
        self.has_intensity = all("intensity" in names for names in fields)

    def close(self) -> None:
        self._e57.close()

    def crs(self) -> dict[str, Any] | None:
        root = self._e57.root
        text = root["coordinateMetadata"].value() if root.isDefined("coordinateMetadata") else ""
        return crs_record(text, None)

    def setups(self) -> list[dict[str, Any]]:
        return [
            {
                "name": _name(scan, i),
                "position_m": [float(v) for v in scan.translation],
                "rotation_wxyz": [float(v) for v in _unit_quaternion(scan)],
                "points": int(scan.point_count),
            }
            for i, scan in enumerate(self._scans)
        ]

    def chunks(self, size: int) -> Iterator[ScanChunk]:
        for index, scan in enumerate(self._scans):
            yield from self._scan_chunks(index, scan, size)

    def _scan_chunks(self, index: int, scan: Any, size: int) -> Iterator[ScanChunk]:
        """One scan's valid points moved into the file's frame, `size` records at a time."""
        from pye57 import libe57
        from scipy.spatial.transform import Rotation

        names = set(scan.point_fields)
        coords = CARTESIAN if set(CARTESIAN) <= names else SPHERICAL
        state = "cartesianInvalidState" if coords == CARTESIAN else "sphericalInvalidState"
        wanted: dict[str, type] = {name: np.float64 for name in coords}
        if state in names:
            wanted[state] = np.int8
        if self.has_intensity:
            wanted["intensity"] = np.float32
        if self.has_colour:
            wanted.update({name: np.float32 for name in COLOURS})
        arrays = {name: np.empty(size, dtype) for name, dtype in wanted.items()}
        buffers = libe57.VectorSourceDestBuffer()
        for name, array in arrays.items():
            buffers.append(libe57.SourceDestBuffer(self._e57.image_file, name, array, size, True, True))
        w, x, y, z = _unit_quaternion(scan)
        rotation = Rotation.from_quat([x, y, z, w]).as_matrix()
        base = np.asarray(scan.translation, dtype=np.float64)
        colour_lo, colour_hi = _colour_limits(scan) if self.has_colour else (0.0, 255.0)
        try:
            reader = scan.points.reader(buffers)
        except Exception as exc:
            raise IngestError(
                f"{self.path}: corrupt E57 scan {_name(scan, index)!r} ({_first_line(exc)})"
            ) from exc
        try:
            while True:
                try:
                    n = reader.read()
                except Exception as exc:
                    raise IngestError(
                        f"{self.path}: corrupt E57 data in scan {_name(scan, index)!r} ({_first_line(exc)})"
                    ) from exc
                if n == 0:
                    break
                valid = arrays[state][:n] == 0 if state in arrays else np.ones(n, bool)
                local = np.column_stack([arrays[name][:n][valid] for name in coords])
                if coords == SPHERICAL:
                    local = _spherical_to_cartesian(local)
                chunk = ScanChunk(base, local @ rotation.T)
                if self.has_colour:
                    rgb = np.column_stack([arrays[name][:n][valid] for name in COLOURS])
                    chunk.colours = ((rgb - colour_lo) * (255.0 / max(colour_hi - colour_lo, 1e-9))).astype(
                        np.float32
                    )
                if self.has_intensity:
                    chunk.intensity = arrays["intensity"][:n][valid].copy()
                del local
                yield chunk
                del chunk
        finally:
            reader.close()


def _name(scan: Any, index: int = 0) -> str:
    node = scan.node
    return str(node["name"].value()) if node.isDefined("name") else f"scan {index}"


def _unit_quaternion(scan: Any) -> NDArray[np.float64]:
    """(4,) the setup's rotation w x y z, normalised (identity when the scan has no pose)."""
    q = np.asarray(scan.rotation, dtype=np.float64)
    norm = float(np.linalg.norm(q))
    return q / norm if norm > 0 else np.array([1.0, 0.0, 0.0, 0.0])


def _colour_limits(scan: Any) -> tuple[float, float]:
    """The scan's colour range (colorLimits, red channel), 0-255 when the file does not say."""
    node = scan.node
    if not node.isDefined("colorLimits"):
        return 0.0, 255.0
    limits = node["colorLimits"]
    return float(limits["colorRedMinimum"].value()), float(limits["colorRedMaximum"].value())


def _spherical_to_cartesian(rae: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) x y z of (N, 3) range, azimuth, elevation (E57: radians, elevation from the x-y plane)."""
    r, az, el = rae[:, 0], rae[:, 1], rae[:, 2]
    return np.column_stack([r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)])


def _first_line(exc: BaseException) -> str:
    """libE57's message without its debug dump."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return lines[0][:200] if lines else type(exc).__name__


def _open_error(path: Path, exc: BaseException) -> str:
    """One line for a file libE57 cannot open: truncated (shorter than its header says), or not E57."""
    text = str(exc)
    if "ErrorBadFileLength" in text:
        said = re.search(r"filePhysicalLength=(\d+)", text)
        size = path.stat().st_size if path.is_file() else 0
        expected = f"; its header says {said.group(1)}" if said else ""
        return f"{path}: truncated E57 file ({size} bytes{expected})"
    return f"{path}: not a readable E57 file ({_first_line(exc)})"
