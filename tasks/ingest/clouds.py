"""Registered room clouds: the check that a cloud is in metres before anything is computed on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError


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
