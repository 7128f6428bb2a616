"""Registered room clouds: the check that a cloud is in metres before anything is computed on it, and
the cloud artefact written in slices (a scanner cloud can hold millions of points)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from tasks.artefacts import atomic_path
from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError


def check_cloud_units(
    points: NDArray[np.float64], path: Path, cfg: IngestConfig, margin: float = 1.0
) -> None:
    """Raise a one-line IngestError when a registered cloud's spread (1st to 99th percentile) cannot be a
    room's in metres, naming the unit it looks like (from its height against a 2.7 m storey).

    `margin` widens the limits: a scanner cloud's first chunk is checked with a margin, so that a file in
    millimetres fails before it is read whole, without a partial view failing a cloud the whole passes."""
    with np.errstate(all="ignore"):  # a damaged value of 1e308 makes the spread infinite: refused below
        lo, hi = np.percentile(points, [1, 99], axis=0)
        size = hi - lo
    if not np.isfinite(size).all():
        check_cloud_range(points, path)
    if size[:2].max() <= cfg.max_cloud_extent_m * margin and size[2] <= cfg.max_cloud_height_m * margin:
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


MAX_COORDINATE_M = 1e7
"""No coordinate of a room cloud in metres lies farther from its origin (a national grid's northing is
under 1e7 m): beyond it, or not finite, the value is damaged, and would wreck the stages' numerics."""


def check_cloud_range(points: NDArray[np.float64], path: Path) -> None:
    """Raise a one-line IngestError naming the first point that is not finite or lies beyond
    ±`MAX_COORDINATE_M` (checked after the unit check, which looks at the bulk of the cloud only)."""
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(points) <= MAX_COORDINATE_M).all(axis=1)
    if bad.any():
        first = int(np.argmax(bad))
        x, y, z = (float(v) for v in points[first])
        raise IngestError(
            f"{path}: {int(bad.sum())} of {len(points)} points lie beyond ±{MAX_COORDINATE_M:g} m or are not "
            f"finite (point {first}: {x:.4g}, {y:.4g}, {z:.4g}): a damaged value"
        )


def write_cloud_slices(
    path: Path,
    count: int,
    slices: Iterable[tuple[NDArray[np.float64], NDArray[np.uint8] | None]],
    coloured: bool,
) -> Path:
    """The cloud artefact (the binary PLY of `tasks.artefacts.write_ply_points`, byte for byte) written
    from an iterable of ((n, 3) float64 points, (n, 3) uint8 colours or None) slices holding `count`
    points in all, so that only one slice is ever converted at a time."""
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    props = ["property double x", "property double y", "property double z"]
    if coloured:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    head = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {count}", *props, "end_header", ""]
    )
    written = 0
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(head.encode())
        for points, colours in slices:
            rec = np.empty(len(points), dtype=fields)
            rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
            if coloured and colours is not None:
                rec["red"], rec["green"], rec["blue"] = colours[:, 0], colours[:, 1], colours[:, 2]
            fh.write(rec.tobytes())
            written += len(points)
        if written != count:
            raise ValueError(f"{path}: {written} points written, {count} announced")
    return Path(path)
