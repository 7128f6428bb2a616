"""The stage table: for each stage, what it reads, which config section it owns and how its outputs are
loaded and saved. Each `run_*` here is the thin shell around a pure stage function: load the inputs from
the artefact store, call, write the outputs into the folder the store commits. Orchestration (Prefect)
lives in flows/; formats live in tasks/artefacts.py; the computation lives in each stage's module.
"""

from __future__ import annotations

import hashlib
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tasks import artefacts as art
from tasks.artefacts import StageResult

ProgressFn = Callable[[str], None]


@dataclass(frozen=True)
class StageContext:
    """What a stage run gets besides its config: its upstream results, raw input files, the survey's
    sensor profile, and a progress callback."""

    room: str
    upstream: dict[str, StageResult]
    raw_inputs: dict[str, str]
    """Name -> path of raw survey files this stage reads (their content hashes are in the key)."""
    profile: dict[str, Any]
    progress: ProgressFn


@dataclass(frozen=True)
class Stage:
    name: str
    section: str
    """Config section the stage owns (its only config in the cache key)."""
    module: str
    """The module holding the stage's computation (its source is part of the code version)."""
    run: Callable[[StageContext, Any, Path], dict[str, Any]]
    """(context, config section, output folder) -> metrics; writes its files into the folder."""

    def code_version(self) -> str:
        """Hash of the computation's module source and of this stage's shell, so editing either
        invalidates the stage (and, through content hashes, what depends on it)."""
        module = sys.modules.get(self.module) or __import__(self.module, fromlist=["_"])
        digest = hashlib.sha256(Path(inspect.getfile(module)).read_bytes())
        digest.update(inspect.getsource(self.run).encode())
        return digest.hexdigest()[:16]


# ------------------------------------------------------------------------------------------------ shells


def run_ingest(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.ingest import ingest_capture

    return ingest_capture(Path(ctx.raw_inputs["capture"]), out, ctx.profile, cfg, ctx.progress)


def room_cloud(ctx: StageContext) -> art.Cloud:
    """The room's registered cloud: from register when the capture had frames, else from ingest."""
    for stage in ("register", "ingest"):
        result = ctx.upstream.get(stage)
        if result is not None and result.has("cloud.ply"):
            return art.read_cloud(result.file("cloud.ply"))
    raise art.ArtefactError(f"room {ctx.room}: no registered cloud to preprocess (capture has frames only)")


def run_preprocess(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.preprocess import preprocess

    result = preprocess(room_cloud(ctx), cfg)
    art.write_cloud(out / "levelled.ply", result.cloud)
    art.write_cloud(out / "slice.ply", result.slice)
    art.write_png(out / "height_histogram.png", result.histogram_png)
    edges, counts = result.histogram
    art.write_table(
        out / "height_histogram.parquet", {"z_low_m": edges[:-1], "z_high_m": edges[1:], "count": counts}
    )
    art.write_json(
        out / "levelling.json",
        {
            "transform": np.asarray(result.levelling).tolist(),
            "floor_z_m": result.floor_z_m,
            "ceiling_z_m": result.ceiling_z_m,
            "height_m": result.height_m,
        },
    )
    return {"metrics": result.metrics}


STAGES: dict[str, Stage] = {
    stage.name: stage
    for stage in (
        Stage("ingest", "ingest", "tasks.ingest", run_ingest),
        Stage("preprocess", "preprocess", "tasks.preprocess", run_preprocess),
    )
}
