"""Which reader a capture needs, and the dispatch that reads one capture into the stage's folder."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from tasks.artefacts import read_cloud, write_cloud
from tasks.context import ProgressFn
from tasks.ingest.clouds import check_cloud_range, check_cloud_units
from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError
from tasks.ingest.folders import SevenScenesReader, TumReader
from tasks.ingest.frames import write_frames
from tasks.ingest.mcap_reader import McapReader
from tasks.ingest.scanners import SCANNER_SUFFIXES, ingest_scanner_cloud

CAPTURE_KINDS = ("mcap", "tum", "7scenes", "cloud")


def capture_kind(path: Path) -> str:
    """What reader a capture needs, from its name and contents; a clear error when none fits."""
    path = Path(path)
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".mcap":
            return "mcap"
        if suffix in {".ply", ".pcd", *SCANNER_SUFFIXES}:
            return "cloud"
        raise IngestError(
            f"{path}: unknown capture format {suffix!r} (MCAP, PLY, PCD, E57, LAS, LAZ or a TUM / 7-Scenes folder)"
        )
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
    if kind == "cloud" and Path(path).suffix.lower() in SCANNER_SUFFIXES:
        metrics: dict[str, Any] = ingest_scanner_cloud(path, out_dir, cfg, progress)
    elif kind == "cloud":
        cloud = read_cloud(path)
        check_cloud_units(cloud.points, path, cfg)
        check_cloud_range(cloud.points, path)
        write_cloud(out_dir / "cloud.ply", cloud)
        metrics = {"points": len(cloud), "coloured": cloud.colors is not None}
    else:
        reader = {"mcap": McapReader, "tum": TumReader, "7scenes": SevenScenesReader}[kind](
            path, profile, cfg
        )
        metrics = write_frames(reader, out_dir, cfg, progress)
    metrics.update(capture_kind=kind, seconds=round(time.perf_counter() - started, 3))
    return metrics
