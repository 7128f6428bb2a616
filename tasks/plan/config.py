"""The plan stage's settings and the plan's scale: plain data, importable without the stage's
computation."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any

from tasks import lines_config as lines


@dataclass(frozen=True)
class PlanConfig:
    """Parameters of plan parsing. Lengths in metres are converted to pixels with the plan scale."""

    max_side_px: int = 5000
    """Images with a longer side are reduced by an integer factor with min-pooling (keeps 1 px lines)."""
    white_balance_percentile: float = 95.0
    """White-patch balance: this percentile of every channel is mapped to white (paper colour)."""
    clahe_clip: float = 2.0
    """CLAHE clip limit on the lightness channel (local contrast, the role of the Wallis filter)."""
    clahe_tile_m: float = 4.0
    """CLAHE tile size in metres of plan."""
    ink_threshold_bounds: tuple[int, int] = (60, 200)
    """Otsu threshold on darkness (255 - min(R, G, B)) is clamped to this range."""
    symbol_min_saturation: int = 90
    """HSV saturation (0-255) above which a pixel can be a coloured symbol."""
    symbol_min_value: int = 70
    """HSV value (0-255) above which a pixel can be a coloured symbol (darker is black ink)."""
    green_hue_deg: tuple[float, float] = (70.0, 170.0)
    """Hue range (degrees, 0-360) of green symbols (escape routes, exits)."""
    red_hue_deg: tuple[float, float] = (330.0, 25.0)
    """Hue range (degrees, wrapping) of red symbols (fire equipment)."""
    blue_hue_deg: tuple[float, float] = (200.0, 260.0)
    """Hue range (degrees) of blue symbols (mandatory / information signs). Cyan (180°) is not a symbol."""
    symbol_min_width_m: float = 0.06
    """Coloured ink is a symbol only where it is at least this wide (filled signs, arrows, swatches):
    thinner coloured strokes are the line work of a drawing whose layers are coloured (CAD) and stay ink."""
    layer_min_saturation: int = 40
    """HSV saturation (0-255) from which ink belongs to a coloured drawing layer (pale rims included)."""
    layer_min_share: float = 0.01
    """Share of the ink a colour layer must hold to be considered as a wall layer."""
    wall_layer_share: float = 0.8
    """Colour layers with at least this share of the best layer's wall evidence are wall layers."""
    wall_face_min_m: float = 0.5
    """Straight lines at least this long can be wall faces when colour layers are scored."""
    wall_layer_grid_m: float = 0.03
    """Cell size (metres) of the coarse grid on which colour layers are scored."""
    symbol_solid_share: float = 0.8
    """A connected piece of a symbol colour with at least this share of solid core is a symbol whole."""
    symbol_grow_m: float = 0.06
    """Symbol masks are grown by this to swallow their anti-aliased rims."""
    pen_colour_share: float = 0.5
    """A symbol colour covering more than this share of all dark pixels is the drawing's line colour
    (one-colour CAD renderings) and is kept."""
    symbol_hole_m: float = 0.12
    """White details narrower than this inside a symbol (pictograms) are part of the symbol."""
    max_outline_width_m: float = 0.5
    """Ink lines closer than this are the two faces of an outline-drawn wall and the space between them is
    filled (a closing); also the largest wall thickness measured."""
    min_wall_thickness_m: float = 0.08
    """Ink thinner than this (text strokes, hatching, furniture, dimension lines) is removed by opening."""
    text_max_size_m: float = 0.35
    """Connected components whose bounding box is smaller than this (letters, dots) are text."""
    drop_outside_shell: bool = False
    """Drop wall-like strokes outside the bounding box of the largest wall component (legend, title)."""
    legend_frame_min_m: float = 1.0
    """Thin-line rectangles at least this wide and high that do not hold the building are legend or title
    frames: the walls inside them (scale bars, legend symbols) are dropped. 0 disables."""
    legend_frame_cover: float = 0.9
    """Share of each side of a thin component's bounding box that its ink must cover to be a frame."""
    heavy_walls_share: float = 0.6
    """When the strokes drawn in a heavy pen (heavy_pen_m) span this share of the grid cells the whole
    drawing's walls span, only they are walls (filled between faces): furniture, stairs and fixtures are
    drawn in thin lines."""
    thin_ink_min_share: float = 0.05
    """Walls are read from the heavy pen only when at least this share of the ink is thin line work
    (furniture, fixtures, dimensions): an evacuation plan's few thin lines are windows and text."""
    heavy_pen_m: float = 0.06
    """Line weight (metres of plan) from which a line is drawn in a heavy pen (cut walls, 0.5 mm at 1:100)."""
    heavy_core_share: float = 0.6
    """A heavy-pen stroke's core (its darkness after a grey erosion as wide as the heavy pen) is at least
    this share of the way from the ink threshold to the darkest ink within two pen widths: two thin lines
    blurred into one wide stroke (furniture drawn double) have a grey core. 0 takes every wide stroke."""
    region_join_m: float = 1.2
    """Wall strokes closer than this (across a door) belong to one network when the plan is looked for."""
    region_min_share: float = 0.3
    """In a drawing whose walls are drawn in a heavy pen, wall networks at least this share as large as
    the largest one and spanning both directions are part of the plan (other wings); smaller ones
    outside their box (legend panels, scale bars, title blocks) are not. In other drawings every network
    is."""
    region_min_width_ratio: float = 0.5
    """Such another network is plan only when its strokes' median width is at least this share of the
    largest network's (the walls' pen): a legend panel's frame joined to the sheet's edge spans as much,
    drawn thin. 0 disables."""
    free_wall_min_m: float = 2.5
    """In a drawing whose walls are drawn in a heavy pen, a piece of wall not joined to the largest one is
    at least this long (or a column); shorter pieces are furniture drawn in double lines."""
    bridge_max_m: float = 2.0
    """Longest wall stretch hidden under a symbol that is bridged (only across symbol pixels)."""
    end_follow_max_m: float = 1.5
    """A free wall end is moved along its line to where its ink ends (or into the wall the ink runs into),
    at most this far: the skeleton stops short of a wall's end, and Hough can miss a short wall's ends."""
    hough_min_length_m: float = 0.15
    """Minimum skeleton segment length for the probabilistic Hough transform."""
    hough_max_gap_m: float = 0.05
    """Gap closed along a skeleton line by the Hough transform."""
    lines: lines.LinesConfig = field(
        default_factory=lambda: lines.LinesConfig(
            explained_variance=0.9995,
            angle_tol_deg=2.0,
            offset_tol_m=0.06,
            max_gap_m=0.3,
            extend_m=0.2,
            min_overlap=0.5,
        )
    )
    """Shared line clustering / regularization / connection settings (metres; scaled to pixels)."""
    min_wall_length_ratio: float = 0.5
    """Walls shorter than this times their thickness are skeleton spurs at wall ends and corners."""
    short_wall_length_ratio: float = 1.2
    """Walls shorter than this times their thickness are kept only as the straight continuation of
    another wall beyond a junction (a jamb beside a door); turned ones are skeleton spurs at corners."""
    door_min_m: float = 0.5
    """Smallest wall gap taken for a door."""
    door_max_m: float = 2.2
    """Largest wall gap taken for a door."""
    window_ink_share: float = 0.9
    """A wall gap whose length is covered by thin ink at least this much is a window (a thin line in the
    wall) and becomes part of the wall; above 1 keeps every gap a door."""
    door_swing_share: float = 0.7
    """In a drawing whose walls are drawn in a heavy pen (architects draw every door's swing), a wall gap
    is a door only when thin ink draws this share of its swing's quarter circle; 0 takes every gap."""
    seal_heavy_pen_outline: bool = True
    """In a drawing whose walls are drawn in a heavy pen, the outside is what stays joined to the image's
    border when every gap between wall ends a door could fill (door_min_m to door_max_m) is closed, and
    narrower ones by a door_min_m square: a window or a bay left as a gap in an outer wall does not open
    its room to the outside, and an acute corner between two outer walls stays outside."""
    face_lines_min_share: float = 0.25
    """Rooms reach past their free space by half the wall faces' line width (a wall drawn by its faces'
    lines has its face at the line's centre) when walls measured with two face lines apart make up at
    least this share of the wall length (an architect's double or hatched walls: 0.6 to 0.8; an
    evacuation plan's solid walls: under 0.01)."""
    min_room_area_m2: float = 1.0
    """Free-space regions smaller than this are not rooms (shafts, wall interiors)."""
    min_extent_m: float = 2.0
    """Smallest plausible plan extent; a smaller one means the scale is wrong."""
    max_extent_m: float = 400.0
    """Largest plausible plan extent; a larger one means the scale is wrong."""
    max_dark_share: float = 0.35
    """An image more than this share dark is a photo or a dark surface, not a line drawing."""
    sheet_aspect: float = 1.41421356
    """Side ratio (long / short) of the paper sheet: when no scale is given and a photo shows the sheet's
    border, the sheet is rectified to it (ISO 216: A4, A3, ...). 0 disables."""
    rectify_directions: bool = True
    """When no scale is given and no sheet border shows, a photo's perspective is taken out from the
    plan's two dominant orthogonal directions (their vanishing points; thesis 4.2.3)."""
    sheet_min_area_share: float = 0.2
    """The sheet found in a photo covers at least this share of it."""
    flat_field_share: float = 0.04
    """A photographed sheet's light is evened out over windows this share of its short side (glare)."""
    sheet_edge_share: float = 0.02
    """A band this share of the rectified sheet's short side is blanked along its edges (the sheet's edge,
    what shows around it, the drawing's frame)."""
    min_walls: int = 3
    """Fewer walls than this means the image holds no floor plan."""
    min_wall_length_diagonals: float = 0.5
    """The walls must add up to at least this many image diagonals, else it is no plan."""
    coverage_wall_length_ratio: float = 1.2
    """Only walls at least this many times their thickness long count in the wall coverage figure:
    texture and noise also yield short straight pieces."""


@dataclass(frozen=True)
class PlanScale:
    """How pixels become metres: at most one of `m_per_px`, `known_distance`, `outline_length_m`,
    `outline_size_m`; with none, the printed scale bar is read, else the dimension lines."""

    m_per_px: float | None = None
    """Metres per pixel of the (rectified) image."""
    known_distance: tuple[float, float, float, float, float] | None = None
    """x0, y0, x1, y1 (pixels) and the distance between them in metres."""
    outline_length_m: float | None = None
    """Perimeter of the building outline in metres."""
    outline_size_m: tuple[float, float] | None = None
    """Width and height (metres) of the outline rectangle whose corners are `corners_px`: fixes the
    rectified aspect ratio (four corners alone cannot) and the scale."""
    corners_px: tuple[tuple[float, float], ...] | None = None
    """Four outline corners (pixels, clockwise from top-left) for perspective rectification; the
    rectified image keeps the mean side lengths, so the other scale inputs refer to it."""

    def __post_init__(self) -> None:
        given = [
            v is not None
            for v in (self.m_per_px, self.known_distance, self.outline_length_m, self.outline_size_m)
        ]
        if sum(given) > 1:
            raise ValueError(
                "PlanScale takes at most one of m_per_px, known_distance, outline_length_m, outline_size_m"
            )
        if self.outline_size_m is not None and (self.corners_px is None or min(self.outline_size_m) <= 0):
            raise ValueError("outline_size_m needs corners_px and two positive lengths")
        if self.m_per_px is not None and not (math.isfinite(self.m_per_px) and self.m_per_px > 0):
            raise ValueError(f"m_per_px must be a positive number, got {self.m_per_px}")
        if self.known_distance is not None:
            x0, y0, x1, y1, d = self.known_distance
            if not (d > 0 and math.hypot(x1 - x0, y1 - y0) > 0):
                raise ValueError(
                    f"known_distance needs two distinct points and a positive distance, got {self.known_distance}"
                )
        if self.outline_length_m is not None and not self.outline_length_m > 0:
            raise ValueError(f"outline_length_m must be positive, got {self.outline_length_m}")
        if self.corners_px is not None and not _four_pairs(self.corners_px):
            raise ValueError("corners_px must be four (x, y) pixel pairs")


def _four_pairs(corners: Any) -> bool:
    """Whether `corners` is four (x, y) pairs of numbers, the (4, 2) shape rectification needs (checked in
    plain Python: this module holds no computation and imports none)."""
    try:
        return len(corners) == 4 and all(
            len(c) == 2 and all(isinstance(v, numbers.Real) for v in c) for c in corners
        )
    except TypeError:
        return False
