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
    plan_frame_gate_m: float = 0.5
    """A room already registered in the plan frame (the IMU-track fallback) is refined from there, its
    correspondences gated at this from the first iteration (walls seen through doors stay out)."""
    max_iterations: int = 30
    """Iterations of the rotation + Gauss-Newton translation loop (eq 7.4, 7.9, 7.10)."""
    rotation_outlier_deg: float = 0.5
    """The rotation (eq 7.4) is the mean over the walls whose orientation difference to their face lies
    within this of the weighted median: a plan face vectorized from a raster is good to about 0.3 degrees
    over 4 m (a pixel); one a degree off (a slanted wall) is left out."""
    converge_m: float = 1e-4
    """Convergence: translation update below this (m) ..."""
    converge_deg: float = 1e-3
    """... and rotation update below this (degrees)."""
    max_residual_m: float = 0.10
    """Once converging, a correspondence whose wall lies farther than this from its face is dropped (a
    changed wall, a plan face drawn off)."""
    consensus_tol_m: float = 0.20
    """Each iteration's translation is fitted to the largest set of walls that one translation puts within
    this of their faces (tasks.fuse.register2d.consensus): twice the residual gate, so a room model a
    percent long keeps both end walls, while furniture modelled as a wall half a metre before its plan
    face (a wardrobe) does not drag the room."""
    fit_tol_m: float = 0.05
    """Fit score: the share of the shell's length lying within this of a plan face of the same
    orientation after registration; also the distance within which a wall takes part in the fine
    registration's translation (`register2d.consensus`)."""
    min_fit_score: float = 0.5
    """A room whose best fit score is below this is not placed (reported with its score)."""
    door_weight: float = 1.0
    """Weight per metre of door width of the constraint that a door seen in the model coincides with the
    plan's door (thesis 7.1.2), relative to a metre of wall."""
    door_match_m: float = 0.5
    """A model door and a plan door coincide when their centres are this close along the wall."""
    plan_simplify_m: float = 0.02
    """Plan room outlines are simplified by this (the raster's pixel jitter) before their edges become faces."""
    thickness_method: Literal["both_sides", "model_lines", "residuals"] = "both_sides"
    """Per-wall thickness: the distance between the facing inner faces of the two rooms on either side,
    each where its room's cloud shows it (both_sides), or between the rooms' straight model lines
    (model_lines), or the thesis' one value per room from the registration residuals (residuals)."""
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
    door_through_share: float = 0.25
    """An opening in a wall's face is a door when the capture saw beyond the face (the floor running
    through, the jambs, the next room) in at least this share of its columns (tasks.fuse.openings)."""
    closed_door_share: float = 0.9
    """A plan door gap is closed in the capture when the model wall's face shows across at least this
    share of it (tasks.fuse.openings.span_state) and nothing was seen through it."""
    top_band_m: tuple[float, float] = (0.30, 0.08)
    """What reaches the ceiling: points from this far (first) to this far (second) below it, in 5 cm cells
    (tasks.fuse.openings.tops). Above a 2.2 m wardrobe in a 2.5 m room, clear of the ceiling's own points
    (a few centimetres of depth noise)."""
    furniture_top_share: float = 0.5
    """A shell wall with no plan face after registration, reaching up to just below the ceiling
    (top_band_m) along less than this share of its length, is no wall of the room (a wardrobe's front) and
    leaves the room model (tasks.fuse.floor.furniture_walls); only in a crisp capture whose matched walls
    reach it along at least this share (length-weighted)."""
    crisp_face_m: float = 0.03
    """A capture tells a closed stretch of wall from an opening only where its wall face is crisp: the
    interquartile range of the face's points' offsets within this (about 1 cm when the frames agree; a
    corridor registered by the IMU track smears its faces over 4-6 cm, and an opening fills with them)."""
