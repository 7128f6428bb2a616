"""The fuse stage's configuration (computation-free: stdlib imports only)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class FuseConfig:
    """Registration of each room model into the plan (eq 7.1-7.10), wall thickness and gap filling."""

    shell_tol_m: float = 0.10
    """A model wall belongs to the outer shell when both its ends lie within this of the convex hull's
    boundary (thesis), or when one of its sides looks out of the model (a non-convex room's notch)."""
    approx_angle_tol_deg: float = 50.0
    """Correspondence window of the first iteration: plan faces within this orientation of a model wall
    (the approximate registration is trusted within +-45 degrees)."""
    angle_tol_deg: float = 10.0
    """Correspondence window once the first rotation update has been applied."""
    start_shift_m: float = 0.5
    """The fine fit also starts this far off the approximate position along both principal directions
    (the approximate registration is trusted within +-1 m)."""
    max_iterations: int = 30
    """Iterations of the rotation + Gauss-Newton translation loop (eq 7.4, 7.9, 7.10)."""
    converge_m: float = 1e-4
    """Convergence: translation update below this (m) ..."""
    converge_deg: float = 1e-3
    """... and rotation update below this (degrees)."""
    max_residual_m: float = 0.10
    """Once converging, a correspondence whose wall lies farther than this from its face is dropped (a
    changed wall, a plan face drawn off)."""
    fit_tol_m: float = 0.05
    """Fit score: the share of the shell's length lying within this of a plan face of the same
    orientation after registration."""
    min_fit_score: float = 0.5
    """A room whose best fit score is below this is not placed (reported with its score)."""
    door_weight: float = 1.0
    """Weight per metre of door width of the constraint that a door seen in the model coincides with the
    plan's door (thesis 7.1.2), relative to a metre of wall."""
    door_match_m: float = 0.5
    """A model door and a plan door coincide when their centres are this close along the wall."""
    plan_simplify_m: float = 0.02
    """Plan room outlines are simplified by this (the raster's pixel jitter) before their edges become faces."""
    thickness_method: Literal["both_sides", "residuals"] = "both_sides"
    """Per-wall thickness: the distance between the facing inner faces of the two rooms on either side
    (both_sides), or the thesis' one value per room from the registration residuals (residuals)."""
    thickness_range_m: tuple[float, float] = (0.05, 0.60)
    """Plausible wall thickness: measurements outside it are not taken."""
    default_thickness_m: float = 0.15
    """Thickness of a wall for which neither a measurement nor the plan gives one."""
    gap_end_tol_m: float = 0.30
    """A free wall end within this of the shell is the end of a gap (farther in: a free-standing partition)."""
    door_min_m: float = 0.6
    """Narrowest opening in a model wall taken for a door."""
    door_max_m: float = 1.6
    """Widest opening in a model wall taken for a door."""
    closed_door_share: float = 0.9
    """A plan door gap is closed in the capture when the model wall's face across it is seen low down at
    least this densely relative to the face beside it (an open door: about 0; a capture whose frames
    disagree by centimetres still smears some points into an opening, up to about 0.7)."""
    door_band_m: tuple[float, float] = (0.15, 0.75)
    """Height band above the floor where a door is open and a window's parapet is not."""
