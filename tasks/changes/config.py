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
    added_face_share: float = 0.5
    """An added piece must show in its room's cloud: something standing from 0.15 to 1.9 m within
    face_margin_m of it along at least this share of its length (a wall the model found in its slice
    near the ceiling may be a lamp or a beam)."""
    added_top_share: float = 0.5
    """An added piece must reach the ceiling: the room's cloud shows points just below it (fuse's
    top_band_m) within top_margin_m along at least this share of its length. Furniture the wall model
    took for a wall (a wardrobe's front, 2.1 m high under a 3 m ceiling) does not: it is no added wall."""
    top_margin_m: float = 0.10
    """How far from an added piece the points below the ceiling count: a bent SfM map puts a wall's top
    up to 10 cm off the piece the wall model drew (a wardrobe's top is no nearer than its depth)."""
    own_reach_m: float = 0.30
    """A room claims added walls within this of its own polygon (its plan room's, when it did not close):
    a closed door gap lies a wall's thickness out of it; a wall a corridor saw through a door lies in the
    next room."""
    face_margin_m: float = 0.05
    """How far from an added piece the cloud's standing points count."""
    room_change_share: float = 0.10
    """A room whose model leaves its plan room by more than this share of its area is a room-level change."""
