"""The changes stage's configuration (computation-free: stdlib imports only)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ChangesConfig:
    """Change detection between the fused room models and the plan (thesis 7.2)."""

    buffer_margin_m: float = 0.10
    """A model wall farther than half the plan wall's thickness plus this from every plan wall is added."""
    min_length_m: float = 0.30
    """Added or removed pieces shorter than this are not reported."""
    support_tol_m: float = 0.10
    """A plan wall is supported where a model wall passes within half its thickness plus this of its
    centreline (inside the drawn wall or just beyond its face)."""
    coverage_cell_m: float = 0.10
    """Cell of the coverage grid (floor and ceiling points seen by the capture)."""
    coverage_reach_m: float = 0.30
    """A face sample counts as seen when coverage lies within this of it, on its room's side."""
    room_change_share: float = 0.10
    """A room whose model leaves its plan room by more than this share of its area is a room-level change."""
