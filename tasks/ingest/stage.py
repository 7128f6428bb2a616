"""The ingest stage's entry point: read the room's capture into the folder the artefact store commits."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tasks.context import StageContext
from tasks.ingest.capture import ingest_capture
from tasks.ingest.config import IngestConfig


def run(ctx: StageContext, cfg: IngestConfig, out: Path) -> dict[str, Any]:
    """Ingest `ctx.raw_inputs["capture"]` into `out`; the metrics say what was read (frames or points)."""
    return {"metrics": ingest_capture(Path(ctx.raw_inputs["capture"]), out, ctx.profile, cfg, ctx.progress)}
