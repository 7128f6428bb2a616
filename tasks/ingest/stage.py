"""The ingest stage's entry point: read the room's capture into the folder the artefact store commits."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tasks.artefacts import read_json, write_json
from tasks.context import StageContext
from tasks.ingest.capture import ingest_capture
from tasks.ingest.config import IngestConfig


def run(ctx: StageContext, cfg: IngestConfig, out: Path) -> dict[str, Any]:
    """Ingest `ctx.raw_inputs["capture"]` into `out`; the metrics say what was read (frames or points)."""
    metrics = ingest_capture(Path(ctx.raw_inputs["capture"]), out, ctx.profile, cfg, ctx.progress)
    if cfg.intrinsics_px is not None and (out / "camera_info.json").is_file():
        write_json(
            out / "camera_info.json", with_intrinsics(read_json(out / "camera_info.json"), cfg.intrinsics_px)
        )
    return {"metrics": metrics}


def with_intrinsics(
    camera_info: dict[str, Any], intrinsics: tuple[float, float, float, float]
) -> dict[str, Any]:
    """camera_info with both streams' intrinsics replaced by the pinhole fx, fy, cx, cy given (pixels)."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    for stream in ("depth", "rgb"):
        if stream in camera_info:
            camera_info[stream] = {
                **camera_info[stream],
                "K": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
                "dist": [0.0] * 5,
                "source": "config",
            }
    return camera_info
