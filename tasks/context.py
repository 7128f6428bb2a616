"""What a stage's `run(ctx, cfg, out)` is given besides its config section: its upstream results, the raw
survey files it reads, the sensor profile, survey-given values and a progress callback. A stage module
imports this (small, computation-free) module, never the stage table or the flows.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from tasks.artefacts import StageResult

ProgressFn = Callable[[str], None]


@dataclass(frozen=True)
class StageContext:
    """Everything a stage run reads besides its own config section."""

    room: str
    """The room id, or `tasks.artefacts.BUILDING` for a building stage."""
    upstream: dict[str, StageResult]
    """Upstream stage name -> its result (for a room stage: the room's own or the building's)."""
    raw_inputs: dict[str, str]
    """Name -> path of raw survey files this stage reads (their content hashes are in the key)."""
    profile: dict[str, Any]
    progress: ProgressFn
    extra_config: dict[str, Any] = field(default_factory=dict)
    """Section name -> config of the stage's further sections (register reads sfm and scale)."""
    params: dict[str, Any] = field(default_factory=dict)
    """Survey-given values (the plan's scale; for a building-after stage, the rooms' survey entries)."""
    rooms: dict[str, dict[str, StageResult]] = field(default_factory=dict)
    """Building-after stages only: room id -> {stage name -> result} for every room that finished the
    stages this one reads."""
    failed_rooms: dict[str, str] = field(default_factory=dict)
    """Building-after stages only: room id -> one line saying why the room has no result."""


StageRun = Callable[[StageContext, Any, Any], dict[str, Any]]
"""(context, config section, output folder) -> manifest entries ({"metrics": {...}, ...}); the function
writes its files into the folder, which the artefact store renames into place when it returns."""
