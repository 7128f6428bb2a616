"""The wall modelling stage's settings (thesis 5.2, table 6.3): plain data, importable without the stage's
computation."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from tasks.lines_config import LinesConfig


@dataclass(frozen=True)
class WallsConfig:
    """Settings of the wall modelling stage (thesis 5.2, table 6.3)."""

    grid_size_m: float = 0.01
    """Finest projection image pixel size = voxel size of the occupancy count (m). The grid used is the
    larger of this and `grid_spacing_ratio` times the slice's point spacing (table 6.3: the grid from
    the cloud): on a 1 cm grid the points of a sparse (3-5 cm) handheld scan are isolated dots that no
    closing joins into a wall band."""
    grid_spacing_ratio: float = 0.5
    """Grid = this times the slice's median nearest-neighbour spacing, when that is above `grid_size_m`
    (two cells per point spacing: the 3x3 closing bridges the one empty cell between points)."""
    grid_noise_ratio: float = 0.0
    """When the slice's points spread about the walls found (1.4826 x the median distance of those within
    `noise_band_m`: a Gaussian's sigma) by more than this times the grid, the walls stage makes the model again
    on a grid of that spread (table 6.3: the grid from the cloud's noise): a real handheld cloud's walls,
    smeared over centimetres by registration, fall apart into dots on a grid finer than that. 0 (the default)
    switches it off: measured, the coarser grid cost more accuracy than it gave (a 70-degree wall 8.7 -> 14.3
    mm, degraded rooms' correctness 0.99 -> 0.79, the 7-Scenes kitchen's walls cut at 1.5 m agreeing 0.976
    instead of 1.000 with the full cloud's); the spread is measured and recorded all the same."""
    noise_band_m: float = 0.1
    """...the points within this distance of a wall count for its spread."""
    sparse_grid_ratio: float = 4.0
    """Walls seen too sparsely for the grid (a stretch the camera passed quickly: points centimetres apart,
    at most one voxel per cell) are looked for on a grid this many times coarser, where their points gather
    into tall, full cells. Only when no α closes the room on the fine grid, and kept only when that closes
    it: its wall cells within a wall's offset tolerance
    (at least one coarse cell) of the line of a wall found, and further than two coarse cells from every
    fine wall cell (`image.sparse_cells`: a band beside a densely seen wall would pull its line), are added
    as bands and the steps made again. A stretch continues a wall: a wall seen sparsely along its whole
    length, or clutter off the walls' lines, is not taken. Under 2 switches that off."""
    gray_levels: int = 255
    """G in eq 5.3 / 5.5."""
    binarization: Literal["alpha", "gaussian"] = "alpha"
    """"alpha": eq 5.5 with α = H_noise / H_filter; "gaussian": eq 5.4 (μ - 1.65σ of the occupied cells)."""
    alpha: float | None = None
    """Fixed α for eq 5.5; None chooses it automatically among `alpha_candidates`."""
    alpha_candidates: tuple[float, ...] = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5)
    """α values tried by the automatic choice, ascending."""
    top_reach_m: float | None = 0.25
    """Data within this distance below the top of the slice reaches the top (walls reach the ceiling,
    furniture does not; judged per merged line with `min_top_share`); None switches the test off."""
    top_max_gap_m: float = 0.1
    """A cell's data near the slice top counts only when the cell holds more data at most this far below it
    (a lone voxel up there is a flying pixel)."""
    top_clear_m: float = 0.1
    """When the slice reaches within this of the ceiling, the top-reach test looks for data from
    `top_reach_m` below the top up to this distance below the ceiling (a ceiling's stray points fall into
    every column above that)."""
    min_top_share: float = 0.25
    """A merged line is a wall when at least this share of its length lies on cells with data near the
    slice top (`top_reach_m`); the rest of it may stop lower (the sensor's view cut it off there)."""
    top_share_tol_m: float = 0.03
    """A point of a line counts as reaching the top when such a cell lies within this distance."""
    thin_wall_max_m: float = 0.3
    """A line below the slice top is still a wall when it is the other face of a free-standing wall at most
    this thick whose first face reaches the top (`thin_wall_faces`); 0 switches that off."""
    through_gap_share: float = 0.5
    """A line wholly more than `thin_wall_max_m` behind another, longer line of the room (on its side away
    from the room), with at least this share of its length straight behind that line's data, was seen through
    a gap in it (a door): a wall of the room beyond, dropped before the walls are connected
    (`evidence.seen_through_gaps`); 0 switches that off."""
    thin_wall_min_m: float = 0.06
    """A partition's second face taken from sparse data (`below_slice_sparse_ratio`, `end_cap_min_height_m`)
    lies at least this far from its first (the thinnest stud partition is 7.5 cm thick): nearer, sparse
    points are the first face's own noise (a degraded handheld scan's 3-5 cm spacing spreads a wall over
    centimetres)."""
    thin_wall_end_tol_m: float = 0.15
    """The two faces of such a wall end within this distance of each other, at the wall's free end."""
    thin_wall_clear_m: float = 0.3
    """...where no wall runs on beside the end, outward of either face, this far (a corner's wall would)."""
    furniture_max_length_m: float = 1.8
    """In a slice with nothing seen above it (no ceiling: the top-reach test cannot tell furniture from
    walls), a line at most this long standing `furniture_min_depth_m` to `furniture_max_depth_m` in front of a
    longer parallel wall that runs along the whole of it is a furniture's front, and a line of that depth
    from the wall into the room with a free end its side (`evidence.furniture_in_front`): wardrobes,
    shelves, plants; 0 switches that off. With a ceiling, a line up to this long that stops below the slice
    top is shadowed (`unshadowed_lines`) also by a top-reaching wall's line extended by `lines.extend_m`
    behind it at that depth: a wardrobe in a corner hides the wall behind it from a scanner at every
    height."""
    furniture_min_depth_m: float = 0.2
    """...deeper than a jog or a thin partition's faces."""
    furniture_max_depth_m: float = 0.75
    """...and no deeper than furniture is (wardrobes and kitchen units 0.6 m)."""
    furniture_lone_direction_m: float = 0.5
    """In a slice with nothing seen above it, a line whose direction the slice's lines show over less than
    this in all is a rounded or faceted furniture face (a plant's pot: 0.2 m facets, two per direction;
    `evidence.lone_directions`); 0 switches that off."""
    round_radius_m: tuple[float, float] = (0.15, 0.6)
    """A circle of a radius in this range whose points cover an arc of at least `round_min_arc_deg`, and which
    explains at least `round_margin` more of the points near it than three straight lines do, is a round thing
    (a plant's pot, a bin, a round column; `round.round_objects`): its points go before the walls are looked
    for. A radius of 0 switches that off."""
    round_min_arc_deg: float = 90.0
    """...the arc its points must cover (a pot by a wall, passed once by a handheld camera, shows the room a
    quarter to a third of its round)."""
    round_margin: float = 0.0
    """...and how much more of the points within three grid cells of it the circle must explain (within a cell)
    than the three lines that explain most of them (0: at least as many). A line whose points span less than
    the circle's radius explains none: a facet of a many-sided pot, not a box's face."""
    beyond_room_min_depth_m: float = 0.75
    """In a slice with nothing seen above it, a line wholly this far behind the line of a wall of the room that
    bounds it, running along that wall, along which the room's lines run and between which and that wall
    nothing of the room lies, was seen through a door whose own wall the capture barely saw
    (`beyond.beyond_the_room`): a wall of the next room; 0 switches that off."""
    below_slice_min_share: float = 0.5
    """A partition stub (a wall with a free end standing on another at a T) whose second face the slice does
    not hold takes it from the levelled cloud under the slice (`evidence.faces_below_slice`: a face seen only
    from close range, below the camera's view of the slice) when that face's points cover at least this
    share of the stub's length; 0 switches that off."""
    low_top_min_m: float = 1.0
    """Without a ceiling, a wall whose data stop this high above the floor or higher, but under the slice's
    top (a handheld capture sees each wall up to its own height), has its columns draped into the slice
    (`lowtop.low_topped_walls`: a filled column whose top is an edge, not a furniture top surface); 0
    switches that off. The issue's real handheld rooms saw their walls up to 1.2-2.7 m; the data of a wall
    seen to 1.2 m stop a few cm under it, and tables, desks, counters and sofa backs stay under 1 m."""
    below_slice_min_z_m: float = 0.3
    """...looking from this height above the floor (skirting boards and what lies on the floor stay out)."""
    below_slice_sparse_ratio: float = 0.5
    """...and also when the slice holds that face, but at under this share of the stub's first face's points
    per 10 cm (a face seen at a grazing angle or from close range: the binarization's α drops it; issue 14,
    0.06-0.3 on the dev rooms' stubs). Such a face is stood up at the first face's density (its slice points
    moved onto it), not as full columns that would outweigh the room's sparse walls; 0 switches that off."""
    end_cap_min_height_m: float = 0.5
    """A stub with no second face beside it in the cloud (the camera never saw that side) whose free end's own
    face shows the wall's thickness (`evidence._end_cap`: a run of points from the stub's face out to at most
    `thin_wall_max_m`, nothing beyond it, spanning this height) gets its second face at that thickness, at
    the first face's density (a partition's faces are parallel); not when a wall of the model stands in line
    with it a door's width on (`evidence._door_beyond`: a door's jamb, the wall's other face in the next
    room); 0 switches that off."""
    shadow_m: float = 1.0
    """A line below the slice top is still a wall when it is at least `open_min_length_m` long and data
    reaching the top lies within this distance beside it (further than `shadow_gap_m`) along less than half
    its length (`unshadowed_lines`): furniture stands in front of a wall that is seen above it, while a
    corridor seen from close range holds no data near the top anywhere (a cabinet's depth is under this,
    a corridor's width over it). 0 switches that off."""
    shadow_gap_m: float = 0.05
    """Top-reaching data nearer than this beside a line is the line's own (its noisy band)."""
    open_min_length_m: float = 0.75
    """...and longer than furniture is deep (wardrobes and kitchen units 0.6 m): a cabinet's side stands on
    the wall behind, which is not parallel to it."""
    min_column_height_m: float = 0.1
    """A wall cell's data must span at least this height (flat things: table tops, ceiling patches, stray
    points are not walls, however the counts compare)."""
    closing_kernel_px: int = 3
    """Morphological closing kernel (thesis: 3×3)."""
    hough_votes_m: float = 0.15
    """β1: minimum votes of a Hough line, as a length of skeleton (m)."""
    hough_min_length_m: float = 0.15
    """β2: minimum Hough segment length (m)."""
    hough_max_gap_m: float = 0.2
    """β3: maximum gap between points of one Hough segment (m)."""
    hough_min_px: int = 8
    """Floor under β1 and β2 in pixels: on a coarse grid a few pixels of a staircase skeleton are not a
    line (at 1 cm the metre values are larger and rule)."""
    hough_theta_deg: float = 0.5
    """Angular resolution of the Hough accumulator (degrees)."""
    lines: LinesConfig = field(default_factory=lambda: LinesConfig(trim_m=0.3, split_min_length_m=1.0))
    """Clustering, regularization and topology thresholds (metres; `tasks.lines`). Trimming cuts only
    overshoot (a data band's width past a corner), never observed wall back to a partition standing on
    it, hence `trim_m` below `extend_m`; a direction a few degrees off a cluster's needs a Hough segment
    of 1 m (a plant's facets, a cabinet's side drawn some degrees off, are shorter)."""
    refine_band_m: float = 0.06
    """Slice points within this distance of a wall refine its offset (median); 0 switches it off."""
    support_tol_m: float = 0.05
    """A point of a wall counts as backed by data when a wall pixel lies within this distance."""
    end_tol_m: float = 0.02
    """A line's end is moved out along it while wall data lies within this distance of it (the Hough
    segments stop short of the data's end; `extend_to_data`)."""
    end_gap_m: float = 0.05
    """Gaps in that data up to this length do not stop the end (m)."""
    bridge_gaps_m: tuple[float, ...] = (1.2, 1.6, 2.0)
    """When the walls do not enclose the room, collinear pieces are joined across these larger gaps, and
    ends are extended to intersections this far, in turn (a wall hidden behind a partition or furniture, a
    corner the capture did not see in the slice), keeping the first that closes it; a bridged span between
    two junctions still needs data (the mouth of an alcove stays open), and so does a wall made only by
    extension that is longer than `lines.extend_m`."""
    bridge_seen_ratio: float = 0.02
    """When the walls still do not enclose the room (an unseen corner), two collinear observed walls are
    joined across a longer gap all the same where the slice points back it (`evidence.backed_bridges`): at
    least `lines.min_overlap` of its 10 cm bins hold this share of the median bin along the room's own
    observed walls (a stretch the camera passed quickly holds a few points a bin; a door, none)."""
    close_unseen_spans: bool = True
    """When no corner is pinned by data either, the spans nothing was seen on are closed where the walls'
    lines say how (`topology.pinned_corners` with `across_unseen`): a corner both walls point at, each
    running on unseen for no more than twice its line is seen over, with no other wall in the corner's
    parallelogram nor behind the added pieces; or a collinear gap with no other wall behind it."""
    stable_tol_m: float = 0.05
    """Two candidate models (automatic α) are equal when their walls lie within this of each other."""
    min_wall_length_m: float = 0.2
    """Dangling walls (one end free) shorter than this are dropped: skeleton spurs, not partitions (short
    walls joined at both ends, such as a reveal or a column face, stay)."""
    min_points: int = 100
    """Fewer slice points than this is a degenerate input."""
    min_slice_height_m: float = 0.2
    """A slice thinner than this (a single horizontal plane) is a degenerate input."""
    max_image_px: int = 36_000_000
    """Largest projection image (pixels); a larger extent is a degenerate input."""
