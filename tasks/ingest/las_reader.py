"""LAS and LAZ files (ASPRS LAS 1.0-1.4, LAZ through the lazrs backend), read chunk by chunk with laspy.

Coordinates are the stored integers times the header's scale plus its offset; the offset is handed on
as the chunk's base, so that a national-grid offset never meets float rounding. The reference system
comes from the OGC WKT record or the GeoTIFF keys (projected, else geographic EPSG code), read without
pyproj. Colour (point formats 2, 3, 5, 7, 8, 10) and intensity are kept; colours are 16-bit by the
standard, but files whose colours never exceed 255 are taken as 8-bit.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tasks.ingest.errors import IngestError, one_line
from tasks.ingest.scanners import ScanChunk, ScannerReader, crs_record

PROJECTED_CRS_KEY = 3072
"""GeoTIFF ProjectedCSTypeGeoKey: an EPSG projected CRS code."""
GEOGRAPHIC_CRS_KEY = 2048
"""GeoTIFF GeographicTypeGeoKey: an EPSG geographic CRS code."""


class LasReader(ScannerReader):
    """One LAS or LAZ file."""

    def __init__(self, path: Path) -> None:
        import laspy

        super().__init__(path)
        self.format = self.path.suffix.lower().lstrip(".")
        # LAS 1.4 LAZ (formats 6-10) can skip the fields a room cloud does not use
        wanted = laspy.DecompressionSelection.base().decompress_z().decompress_intensity().decompress_rgb()
        try:
            self._las = laspy.open(str(self.path), decompression_selection=wanted)
        except laspy.errors.PointFormatNotSupported as exc:
            raise IngestError(
                f"{self.path}: wrong LAS point format {exc} (LAS knows formats 0 to 10; is the file damaged?)"
            ) from exc
        except Exception as exc:
            message = one_line(exc)
            if "point size" in message.lower():
                raise IngestError(f"{self.path}: wrong LAS point format ({message})") from exc
            raise IngestError(f"{self.path}: not a readable LAS/LAZ file ({message})") from exc
        header = self._las.header
        if header.are_points_compressed and not laspy.LazBackend.detect_available():
            self._las.close()
            raise IngestError(
                f"{self.path}: LAZ points need a decompression backend and none is installed (the lazrs package)"
            )
        names = set(header.point_format.dimension_names)
        self.has_colour = {"red", "green", "blue"} <= names
        self.has_intensity = "intensity" in names

    def close(self) -> None:
        self._las.close()

    def crs(self) -> dict[str, Any] | None:
        from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

        header = self._las.header
        records = list(header.vlrs) + list(header.evlrs or [])
        wkt = next((r.string for r in records if isinstance(r, WktCoordinateSystemVlr) and r.string), None)
        epsg = None
        for record in records:
            if isinstance(record, GeoKeyDirectoryVlr):
                codes = {
                    key.id: key.value_offset
                    for key in record.geo_keys
                    if key.tiff_tag_location == 0 and 1024 <= key.value_offset <= 32766
                }
                epsg = codes.get(PROJECTED_CRS_KEY, codes.get(GEOGRAPHIC_CRS_KEY))
        return crs_record(wkt, epsg)

    def colour_scale(self, largest: float) -> float:
        return 255.0 / 65535.0 if largest > 255.0 else 1.0

    def chunks(self, size: int) -> Iterator[ScanChunk]:
        header = self._las.header
        scales = np.asarray(header.scales, dtype=np.float64)
        base = np.asarray(header.offsets, dtype=np.float64)
        expected = int(header.point_count)
        read = 0
        records = self._las.chunk_iterator(size)
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as exc:
                raise IngestError(
                    f"{self.path}: truncated or corrupt LAS point data after {read} of {expected} points "
                    f"({one_line(exc)})"
                ) from exc
            n = len(record)
            if n == 0:
                break
            xyz = np.empty((n, 3))
            for axis, name in enumerate("XYZ"):
                np.multiply(getattr(record, name), scales[axis], out=xyz[:, axis])
            chunk = ScanChunk(base, xyz)
            if self.has_colour:
                chunk.colours = np.column_stack([record.red, record.green, record.blue]).astype(np.float32)
            if self.has_intensity:
                chunk.intensity = np.asarray(record.intensity, dtype=np.float32)
            read += n
            del record, xyz  # hold no chunk while the next is decompressed
            yield chunk
            del chunk
        if read < expected:
            raise IngestError(f"{self.path}: truncated LAS point data ({read} of {expected} points)")
