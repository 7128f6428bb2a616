"""What laser scanners export (E57; LAS and LAZ) read into the room cloud, in bounded memory.

A scanner reader yields chunks of points in the file's own coordinates, split as a large `base` (a LAS
file's offset, an E57 setup's position) plus small offsets, so that moving them to a local origin loses
nothing to float rounding. The chunks are voxel-reduced as they arrive (`cloud_voxel_m`), so a file of
50 M points never holds 50 M points in memory.

Beside cloud.ply (the artefact every cloud capture gives) the stage writes:
- `georef.json`: the local origin the cloud was moved to (file coordinates = cloud coordinates +
  `local_origin_m`), the file's coordinate reference system (WKT and EPSG code, when it has one), and for
  E57 each scanner setup (name, position in the cloud's frame, rotation quaternion w x y z);
- `intensity.npy`: (N,) float32 mean intensity per cloud.ply vertex, in the file's units, when the file
  has intensities (cloud.ply holds x y z and colour only, as for every other capture).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.artefacts import write_json
from tasks.context import ProgressFn
from tasks.ingest.clouds import check_cloud_units, write_cloud_slices
from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError
from tasks.ingest.voxels import KeepAll, VoxelAccumulator, VoxelRangeError

SCANNER_SUFFIXES = (".e57", ".las", ".laz")

CHUNK_POINTS = 250_000
"""Points read at a time: some 30 MB of working arrays, whatever the file's size (larger chunks are no
faster: the per-chunk work is numpy's)."""

EARLY_UNIT_MARGIN = 3.0
"""The first chunk fails the unit check only when it spreads this many times wider than a room in
metres may (a file in millimetres, centimetres or inches does by far more)."""

WRITE_SLICE = 1 << 18
"""Points converted to PLY records at a time."""

UNIT_SAMPLE = 2_000_000
"""The unit check looks at up to this many of the kept points (all of them in a room-sized cloud)."""


@dataclass
class ScanChunk:
    """Points read from a scanner file: file coordinates are `base + xyz`."""

    base: NDArray[np.float64]
    """(3,) a large offset in the file's coordinates (metres)."""
    xyz: NDArray[np.float64]
    """(N, 3) the points relative to `base` (metres)."""
    colours: NDArray[np.float32] | None = None
    """(N, 3) colours in the reader's units (see `ScannerReader.colour_scale`), or None."""
    intensity: NDArray[np.float32] | None = None
    """(N,) intensities in the file's units, or None."""


class ScannerReader:
    """A scanner file seen as a stream of point chunks plus what the file says about its frame."""

    format = ""
    has_colour = False
    has_intensity = False

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def chunks(self, size: int) -> Iterator[ScanChunk]:
        """The file's points, at most `size` at a time, in file order."""
        raise NotImplementedError

    def crs(self) -> dict[str, Any] | None:
        """{"wkt": str | None, "epsg": int | None}, or None when the file names no reference system."""
        return None

    def setups(self) -> list[dict[str, Any]]:
        """Scanner setups: name, position_m (file coordinates), rotation_wxyz, points."""
        return []

    def colour_scale(self, largest: float) -> float:
        """Factor from the chunks' colour units to 0-255, given the largest colour value read."""
        return 1.0

    def close(self) -> None:
        """Release the file."""


def open_scanner(path: Path) -> ScannerReader:
    """The reader for an .e57, .las or .laz file (its library loaded only when needed)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".e57":
        from tasks.ingest.e57_reader import E57Reader

        return E57Reader(path)
    from tasks.ingest.las_reader import LasReader

    return LasReader(path)


def crs_record(wkt: str | None, epsg: int | None) -> dict[str, Any] | None:
    """The reference system as georef.json holds it; the EPSG code is taken from the WKT's own
    identifier (its last ID or AUTHORITY) when not given."""
    wkt = (wkt or "").strip() or None
    if epsg is None and wkt:
        ids = re.findall(r'(?:ID|AUTHORITY)\[\s*"EPSG"\s*,\s*"?(\d+)"?\s*\]', wkt)
        epsg = int(ids[-1]) if ids else None
    if wkt is None and epsg is None:
        return None
    return {"wkt": wkt, "epsg": epsg}


def local_origin(first: NDArray[np.float64], beyond_m: float) -> NDArray[np.float64]:
    """(3,) the local origin for a cloud whose first point is `first` (file coordinates): along each
    axis where it lies farther than `beyond_m` from zero, the point rounded down to whole metres."""
    return np.array([math.floor(v) if abs(v) > beyond_m else 0.0 for v in first], dtype=np.float64)


def ingest_scanner_cloud(
    path: Path,
    out_dir: Path,
    cfg: IngestConfig,
    progress: ProgressFn | None = None,
    chunk_points: int = CHUNK_POINTS,
) -> dict[str, Any]:
    """Read an E57, LAS or LAZ file into `out_dir` (cloud.ply, georef.json, intensity.npy when the file
    has intensities), voxel-reduced while read. Returns the stage's metrics."""
    path = Path(path)
    started = time.perf_counter()
    reader = open_scanner(path)
    try:
        acc, origin, read, colour_max = _accumulate(reader, cfg, progress, chunk_points)
        crs, setups = reader.crs(), reader.setups()
    finally:
        reader.close()
    if read == 0 or len(acc) == 0:
        raise IngestError(f"{path}: the {reader.format.upper()} file holds no points")
    check_cloud_units(_unit_sample(acc), path, cfg)
    scale = reader.colour_scale(colour_max)
    intensity = acc.mean_intensity() if reader.has_intensity else None
    if intensity is not None and not np.any(intensity):
        intensity = None  # a LAS intensity field that was never filled
    _write(acc, out_dir, reader.has_colour, scale, intensity)
    for setup in setups:
        setup["position_m"] = [float(v) for v in np.asarray(setup["position_m"]) - origin]
    georef = {
        "format": reader.format,
        "local_origin_m": [float(v) for v in origin],
        "crs": crs,
        "setups": setups,
        "voxel_m": cfg.cloud_voxel_m,
        "points_read": read,
        "points": len(acc),
        "intensity": "intensity.npy" if intensity is not None else None,
    }
    write_json(out_dir / "georef.json", georef)
    return {
        "points": len(acc),
        "points_read": read,
        "coloured": reader.has_colour,
        "intensity": intensity is not None,
        "local_origin_m": georef["local_origin_m"],
        "crs": _crs_label(crs),
        "setups": setups,
        "voxel_m": cfg.cloud_voxel_m,
        "points_per_second": round(read / max(time.perf_counter() - started, 1e-9)),
    }


def _accumulate(
    reader: ScannerReader, cfg: IngestConfig, progress: ProgressFn | None, chunk_points: int
) -> tuple[VoxelAccumulator | KeepAll, NDArray[np.float64], int, float]:
    """Stream the reader's chunks into a voxel accumulator; returns it, the local origin, the number of
    points read and the largest colour value seen (for the colour scale)."""
    if cfg.cloud_voxel_m > 0:
        acc: VoxelAccumulator | KeepAll = VoxelAccumulator(
            cfg.cloud_voxel_m, reader.has_colour, reader.has_intensity
        )
    else:
        acc = KeepAll(reader.has_colour, reader.has_intensity)
    origin: NDArray[np.float64] | None = None
    read = 0
    colour_max = 0.0
    for chunk in reader.chunks(chunk_points):
        if len(chunk.xyz) == 0:
            continue
        if origin is None:
            origin = local_origin(chunk.base + chunk.xyz[0], cfg.local_origin_beyond_m)
        local = chunk.xyz
        local += chunk.base - origin  # in place: the chunk's array is the reader's to give away
        if read == 0:
            check_cloud_units(local, reader.path, cfg, margin=EARLY_UNIT_MARGIN)
        try:
            acc.add(local, chunk.colours, chunk.intensity)
        except VoxelRangeError as exc:
            raise IngestError(f"{reader.path}: {exc}; is the cloud in metres?") from exc
        if chunk.colours is not None and len(chunk.colours):
            colour_max = max(colour_max, float(chunk.colours.max()))
        read += len(local)
        del chunk, local  # hold no chunk while the reader makes the next
        if progress:
            progress(f"{read} points read")
    return acc, origin if origin is not None else np.zeros(3), read, colour_max


def _unit_sample(acc: VoxelAccumulator | KeepAll) -> NDArray[np.float64]:
    """(<= UNIT_SAMPLE, 3) the kept points, every n-th in key order, for the unit check: its
    percentiles need all points at once, and a sample of millions gives the same spread."""
    count = len(acc)
    step = max(1, -(-count // UNIT_SAMPLE))
    parts = []
    for start in range(0, count, WRITE_SLICE):
        first = -(-start // step) * step  # the first sampled index in this slice
        parts.append(acc.points(start, min(start + WRITE_SLICE, count))[first - start :: step])
    return np.concatenate(parts)


def _write(
    acc: VoxelAccumulator | KeepAll,
    out_dir: Path,
    coloured: bool,
    colour_scale: float,
    intensity: NDArray[np.float32] | None,
) -> None:
    """cloud.ply from the accumulator, slice by slice, and intensity.npy beside it."""
    count = len(acc)

    def slices() -> Iterator[tuple[NDArray[np.float64], NDArray[np.uint8] | None]]:
        for start in range(0, count, WRITE_SLICE):
            stop = min(start + WRITE_SLICE, count)
            colours = acc.mean_colours(start, stop) if coloured else None
            if colours is not None:
                colours = np.clip(np.rint(colours * colour_scale), 0, 255).astype(np.uint8)
            yield acc.points(start, stop), colours

    write_cloud_slices(out_dir / "cloud.ply", count, slices(), coloured)
    if intensity is not None:
        np.save(out_dir / "intensity.npy", intensity)


def _crs_label(crs: dict[str, Any] | None) -> str | None:
    """The reference system in one string for the metrics: EPSG:n when known, else the WKT."""
    if crs is None:
        return None
    return f"EPSG:{crs['epsg']}" if crs.get("epsg") else crs.get("wkt")
