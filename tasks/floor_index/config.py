"""The floor_index stage's settings."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FloorIndexConfig:
    """outputs/rooms.parquet: one row per survey room."""

    include_failed: bool = True
    """List rooms that have no result (with the one-line reason) besides those that finished."""
