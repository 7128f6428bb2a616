"""Furniture faces in a slice without a ceiling that the first rules let through (issue 14's degraded rooms):
a plant's short facet drawn some degrees off its wall's direction, a cabinet's front seen shorter than the
cabinet is deep and standing alone, and a cabinet beside a wall's seen end with its side at the far end
(`evidence.furniture_in_front`)."""

from __future__ import annotations

import math

import numpy as np

from tasks.walls.config import WallsConfig
from tasks.walls.evidence import FURNITURE_RULES, furniture_in_front

CFG = WallsConfig()
ROOM = [[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]]
CENTRE = np.array([3.0, 2.0])


def test_a_plant_s_short_facet_drawn_some_degrees_off_its_wall_is_a_front():
    """A plant's facet, 0.25 m long and 0.5 m in front of the south wall, drawn 8° off the wall's direction
    (a short line's ends are good to a few cm each): a front, as a side drawn so is a side, and so is one
    0.15 m long (shorter than furniture is deep: a ten-sided plant's facets are 0.19 m). A facet 30° off is
    not judged a front (`lone_directions` judges it), however short."""

    def facet(deg: float, length: float = 0.25) -> list[float]:
        d = length * np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])
        return [2.0, 0.5, 2.0 + d[0], 0.5 + d[1]]

    lines = np.array([*ROOM, facet(8.0)], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0)).tolist() == [4]
    steep = np.array([*ROOM, facet(30.0)], dtype=float)
    assert not furniture_in_front(steep, CENTRE, CFG, 3.0).any()
    short = np.array([*ROOM, facet(8.0, 0.15)], dtype=float)
    assert np.flatnonzero(furniture_in_front(short, CENTRE, CFG, 3.0)).tolist() == [4]
    short_steep = np.array([*ROOM, facet(30.0, 0.15)], dtype=float)
    assert not furniture_in_front(short_steep, CENTRE, CFG, 3.0).any()


def test_a_cabinet_front_seen_shorter_than_furniture_is_deep_standing_alone_is_furniture():
    """The west wall seen only from y = 2.2 up (the rest unseen); a cabinet's front, 0.6 m of it seen, stands
    0.5 m in front of the wall's line below that, both ends free, in line with nothing, between the room's
    corners: the wall runs on behind it. A piece of such a front 0.15 m long, drawn 11° off, is furniture
    too (a short line's direction is good to 2 `support_tol_m` over its length; degraded 331 r3 closed its
    room round such a piece). The same line past the room's corner (beyond the south wall's line) stays,
    and so does one in line with a piece of wall (a jog)."""
    room = [[0, 4, 0, 2.2], [0, 4, 6, 4], [6, 4, 6, 0], [1.0, 0, 6, 0]]
    front = np.array([*room, [0.5, 1.8, 0.5, 1.2]], dtype=float)
    assert np.flatnonzero(furniture_in_front(front, CENTRE, CFG, 3.0)).tolist() == [4]
    turn = math.radians(11.0)
    piece = [0.5, 1.6, 0.5 + 0.15 * math.sin(turn), 1.6 - 0.15 * math.cos(turn)]
    assert np.flatnonzero(furniture_in_front(np.array([*room, piece]), CENTRE, CFG, 3.0)).tolist() == [4]
    past = np.array([*room, [0.5, -0.2, 0.5, -0.8]], dtype=float)
    assert not furniture_in_front(past, CENTRE, CFG, 3.0).any()
    jog = np.array([*room, [0.5, 1.8, 0.5, 1.2], [0.5, 0.9, 0.5, 0.4]], dtype=float)
    assert not furniture_in_front(jog, CENTRE, CFG, 3.0)[4:].any()


def test_a_lone_front_s_corners_are_walls_running_into_the_room_that_carry_to_the_wall_s_line():
    """The cabinet's front standing alone as above, with a line across the west wall's line at its height
    that does not bound the wall there: a door's jamb outside the room, or a 0.2 m stub 5 m across the room
    whose direction, carried that far, is good to 2.5 m only. Neither is a corner of the room: still a
    front. The room's own south-west corner, seen only as the south wall's line from 1 m on, still bounds
    it (the same line past that corner stays)."""
    room = [[0, 4, 0, 2.2], [0, 4, 6, 4], [6, 4, 6, 0], [1.0, 0, 6, 0]]
    front = [0.5, 1.8, 0.5, 1.2]
    for other in ([0, 1.5, -0.15, 1.5], [5.0, 1.5, 5.2, 1.5]):
        lines = np.array([*room, front, other], dtype=float)
        assert furniture_in_front(lines, CENTRE, CFG, 3.0)[4], other
    past = np.array([*room, [0.5, -0.2, 0.5, -0.8], [5.0, -0.5, 5.2, -0.5]], dtype=float)
    assert not furniture_in_front(past, CENTRE, CFG, 3.0)[4]


def test_a_short_piece_of_the_room_s_wall_beside_an_alcove_is_no_front_standing_alone():
    """An alcove 0.6 m deep in the south wall, its back seen from x = 3.2 to 4.4 and its sides unseen, and
    0.4 m of the room's south wall seen west of it: that piece stands 0.6 m in front of the back's line,
    both ends free, between the room's corners, like a cabinet's front seen in part. It begins where the
    back's data begin (the alcove's side, unseen, joins them); begun 0.2 m off (the back's data frayed by
    its corner), the alcove's other side running from the back's end as deep as the piece stands, and
    stopping there, tells it; so does the room's east wall ending on the piece's line."""
    room = [[0, 4, 6, 4], [6, 4, 6, 1.0], [0, 4, 0, 1.0]]
    back = [3.2, -0.6, 4.4, -0.6]
    at_end = np.array([*room, back, [2.8, 0, 3.2, 0]], dtype=float)
    assert not furniture_in_front(at_end, CENTRE, CFG, 3.0).any()
    side = [4.45, -0.6, 4.45, 0.0]  # the alcove's east side, seen; the room's wall east of it unseen
    frayed = np.array([*room, back, [2.6, 0, 3.0, 0], side], dtype=float)
    assert not furniture_in_front(frayed, CENTRE, CFG, 3.0).any()
    corner = np.array([[0, 4, 6, 4], [6, 4, 6, 0.0], [0, 4, 0, 1.0], back, [2.6, 0, 3.0, 0]], dtype=float)
    assert not furniture_in_front(corner, CENTRE, CFG, 3.0).any()


def test_a_cabinet_past_a_wall_s_seen_end_with_its_side_at_the_far_end_is_furniture():
    """The west wall seen from the north corner down to y = 2.5, where a cabinet (0.85 m wide, 0.46 m deep)
    begins: its near side hidden (the skeleton rounds the corner 0.2 m short), its front and its far side
    seen, the wall past it unseen. The front stands at the wall's seen end and its far end is joined back to
    the wall's line by the side: a box on the wall, both dropped. A step of the outline whose far end runs
    into the room's wall (the outline jogs in there and goes on) stays."""
    room = [[0, 4, 0, 2.5], [0, 4, 6, 4], [6, 4, 6, 0], [6, 0, 1.0, 0]]
    box = [[0.46, 2.3, 0.46, 1.45], [0.08, 1.42, 0.47, 1.42]]
    lines = np.array([*room, *box], dtype=float)
    why: dict[str, int] = {}
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0, why)).tolist() == [4, 5]
    assert why == {**dict.fromkeys(FURNITURE_RULES, 0), "front_at_seen_end": 1, "side": 1}
    # the outline steps in at y = 2.3, runs down to the south wall, which meets it at its end
    step = np.array([*room[:3], [6, 0, 0.46, 0], [0.46, 2.3, 0.46, 0.1]], dtype=float)
    assert not furniture_in_front(step, CENTRE, CFG, 3.0).any()


def test_a_cabinet_wider_than_the_wall_seen_beside_it_is_furniture_when_its_far_side_is_seen():
    """The west wall seen only 0.6 m down from the north corner; a cabinet 0.9 m wide (wider than that) stands
    from there on, 0.46 m deep, its front and its far side seen. The wall seen is shorter than the front,
    but the far side joins the front back to the wall's line: a box on the wall, both dropped. The front
    alone, no side at its far end, standing free before the wall's unseen stretch, goes too; a step of the
    outline (the room's wall running on from there to the south wall) stays."""
    room = [[0, 4, 0, 3.4], [0, 4, 6, 4], [6, 4, 6, 0], [6, 0, 1.0, 0]]
    box = [[0.46, 3.25, 0.46, 2.35], [0.08, 2.33, 0.47, 2.33]]
    why: dict[str, int] = {}
    lines = np.array([*room, *box], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0, why)).tolist() == [4, 5]
    assert why == {**dict.fromkeys(FURNITURE_RULES, 0), "front_at_seen_end": 1, "side": 1}
    alone = np.array([*room, box[0]], dtype=float)
    assert np.flatnonzero(furniture_in_front(alone, CENTRE, CFG, 3.0)).tolist() == [4]
    step = np.array([*room[:3], [6, 0, 0.46, 0], [0.46, 3.25, 0.46, 0.1]], dtype=float)
    assert not furniture_in_front(step, CENTRE, CFG, 3.0).any()


def test_the_rest_of_a_front_s_band_and_a_side_drawn_across_the_wall_s_line_go_with_the_front():
    """A cabinet's front seen from afar is a band of data a decimetre deep: besides its front (1 m, 0.5 m in
    front of the south wall) the lines give a short piece across that band (23° off); it lies wholly within
    `thin_wall_end_tol_m` of the front and goes with it. The cabinet's side, drawn 8° off from its few
    points, reaches 9 cm past the wall's line into the wall's own noisy band: still the side. A wall's
    piece 0.3 m from the front stays."""
    s, c = math.sin(math.radians(8.0)), math.cos(math.radians(8.0))
    lines = np.array(
        [
            *ROOM,
            [2.0, 0.5, 3.0, 0.5],  # the front
            [2.3, 0.45, 2.6, 0.58],  # a piece across its band
            [3.0, 0.5, 3.0 + 0.6 * s, 0.5 - 0.6 * c],  # its east side, 8° off, past the wall's line
        ],
        dtype=float,
    )
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0)).tolist() == [4, 5, 6]
    apart = np.array([*ROOM, [2.0, 0.5, 3.0, 0.5], [3.3, 0.8, 3.3, 1.6]], dtype=float)
    assert np.flatnonzero(furniture_in_front(apart, CENTRE, CFG, 3.0)).tolist() == [4]


def test_a_cabinet_at_a_wall_s_seen_end_whose_free_end_holds_pieces_of_its_own_band_is_furniture():
    """The west wall seen from the north corner down to y = 2.5, where a cabinet's near side joins it; the
    cabinet's front (0.85 m, 0.5 m deep) ends free, but the front's data, a decimetre deep, gave a short line
    across its band by that end. That line is the front's own data, not a line meeting its end: the front
    stands at the wall's seen end with its other end free, and goes with its side and that piece."""
    room = [[0, 4, 0, 2.5], [0, 4, 6, 4], [6, 4, 6, 0], [6, 0, 1.0, 0]]
    box = [[0.5, 2.45, 0.5, 1.6], [0.0, 2.47, 0.5, 2.47], [0.45, 1.75, 0.55, 1.6]]
    lines = np.array([*room, *box], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0)).tolist() == [4, 5, 6]


def test_a_box_at_a_wall_s_seen_end_in_line_with_an_alcove_s_side_past_the_corner_is_furniture():
    """A room 4.6 m x 5.6 m whose east wall (x = 4.65) was seen only over its south 1.1 m; a cabinet
    0.47 m deep stands just north of that, its front seen over 0.76 m with its side back to the wall at the
    far end. The alcove's west side (x = 4.15), south of the room's south-east corner and 1.3 m past the
    front's end, lies in line with the front to within centimetres: no piece of the same wall, which would
    lie within a door's width of it. A line in line with the front within that stays (a jog)."""
    room = [
        [0, 5.6, 0, 3.0],  # west, its south part unseen
        [0, 5.6, 2.1, 5.6],  # north, in pieces
        [3.1, 5.6, 3.6, 5.6],
        [4.65, 1.1, 4.65, 0],  # east, seen over its south 1.1 m
        [4.16, 0, 4.62, 0],  # south, from the east corner to the alcove's west side
        [2.3, 0, 2.75, 0],
        [3.1, -0.67, 3.77, -0.67],  # the alcove's back
        [4.15, 0, 4.15, -0.67],  # the alcove's west side
    ]
    front = [4.18, 1.34, 4.18, 2.1]
    side = [4.2, 2.11, 4.6, 2.13]
    lines = np.array([*room, front, side], dtype=float)
    centre = np.array([2.35, 2.4])
    assert np.flatnonzero(furniture_in_front(lines, centre, CFG, 3.0)).tolist() == [8, 9]  # front and side
    jog = np.array([*room[:7], [4.18, 0.6, 4.18, 0], front, side], dtype=float)
    assert not furniture_in_front(jog, centre, CFG, 3.0)[8]


def test_a_shelf_lower_than_the_cut_with_the_wall_seen_over_it_is_furniture():
    """A room 2 m x 4 m whose north wall was seen as a line only over 0.4 m at its west end and whose east
    wall was seen up to y = 3.66; a shelf's front, 1.3 m long, 0.32 m in front of the north wall at x =
    0.45-1.75, its side at the west end. As lines, the front may be the room's own wall where the room's
    outline steps in (the east wall meets its line): it stays. The few points the capture got of the north
    wall over the shelf (every 5 cm along its line) make no line, but show the wall runs on behind the
    front: the front is furniture."""
    room = [[0, 0, 2, 0], [2, 0, 2, 3.66], [0, 4, 0, 0], [0, 4, 0.4, 4]]
    front = [0.45, 3.68, 1.75, 3.68]
    side = [0.42, 3.7, 0.42, 3.95]
    lines = np.array([*room, front, side], dtype=float)
    centre = np.array([1.0, 2.0])
    assert not furniture_in_front(lines, centre, CFG, 3.0)[4]
    x = np.arange(0.4, 2.0, 0.05)
    behind = np.column_stack([x, np.full(len(x), 4.01)])
    assert furniture_in_front(lines, centre, CFG, 3.0, occupied=behind)[4]
    # the wall's points behind a third of it only (the rest unseen) are not enough
    assert not furniture_in_front(lines, centre, CFG, 3.0, occupied=behind[:10])[4]
    # nor is the front judged so from a centre of the room that lies between it and the wall's line (an
    # L-room's lines may put it there), nor when narrower than it stands deep (a corner's data behind it)
    assert not furniture_in_front(lines, np.array([1.0, 3.8]), CFG, 3.0, occupied=behind)[4]
    narrow = np.array([*room, [0.45, 3.68, 0.75, 3.68], side], dtype=float)
    assert not furniture_in_front(narrow, centre, CFG, 3.0, occupied=behind)[4]


def test_a_cabinet_standing_in_an_alcove_whose_sides_run_on_past_it_is_furniture():
    """An alcove 1.2 m wide and 0.6 m deep in the south wall, a cabinet 0.35 m deep filling it: its front
    0.25 m behind the wall's line, the alcove's sides seen past it (above the cabinet) down to 0.55 m, the
    alcove's back unseen. The front is the cabinet's (`front_in_recess`); the sides stay. A shallow alcove
    whose sides end at its back, a piece of wall between two doors (its jambs crossing its line by the
    wall's thickness, the wall's pieces in line beyond them), and an open shelf's front with the wall seen
    behind it between its sides (left to `seen_through_fronts`) stay."""
    room = [[0, 4, 6, 4], [6, 4, 6, 0], [0, 4, 0, 0], [0, 0, 2.5, 0], [3.7, 0, 6, 0]]
    sides = [[2.5, 0, 2.5, -0.55], [3.7, 0, 3.7, -0.55]]
    front = [2.6, -0.25, 3.6, -0.25]
    why: dict[str, int] = {}
    lines = np.array([*room, *sides, front], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0, why)).tolist() == [7]
    assert why == {**dict.fromkeys(FURNITURE_RULES, 0), "front_in_recess": 1}
    behind = np.column_stack([np.arange(2.55, 3.65, 0.05), np.full(22, -0.55)])
    assert not furniture_in_front(lines, CENTRE, CFG, 3.0, occupied=behind).any()
    # the room's south wall east of the alcove seen, nothing behind the front
    aside = behind + np.array([2.0, 0.0])
    assert furniture_in_front(lines, CENTRE, CFG, 3.0, occupied=aside)[7]
    shallow = np.array([*room, [2.5, 0, 2.5, -0.25], [3.7, 0, 3.7, -0.25], front], dtype=float)
    assert not furniture_in_front(shallow, CENTRE, CFG, 3.0).any()
    # doors at x 1.5-2.5 and 3.7-4.7, jambs 0.25 m (the wall's thickness), the piece between them at y = 0
    doors = [[0, 4, 6, 4], [6, 4, 6, 0], [0, 4, 0, 0], [0, 0, 1.5, 0], [4.7, 0, 6, 0], [2.5, 0, 3.7, 0]]
    jambs = [[2.5, 0, 2.5, -0.25], [3.7, 0, 3.7, -0.25], [1.5, 0, 1.5, -0.25], [4.7, 0, 4.7, -0.25]]
    assert not furniture_in_front(np.array([*doors, *jambs], dtype=float), CENTRE, CFG, 3.0).any()


def test_a_cabinet_narrower_than_its_alcove_and_just_behind_the_wall_s_line_is_furniture():
    """Held-out 328 r4: a wardrobe 0.9 m wide against the back of an alcove 1.06 m wide and 0.55 m deep, its
    front 6 cm behind the room's wall line (within a line's offset tolerance of the wall's pieces beside the
    alcove), seen from 10.2 to 11.0 m, the alcove's sides seen past it down to the back. The front fills more
    than half the alcove's mouth and the wall's pieces in line with it run on from the alcove's sides: a
    front in a recess. A front filling less than half the mouth, or one with a piece of the wall in line
    within the alcove's mouth or a door's width beyond its side, is not judged so."""
    room = [[7.7, -8.0, 10.5, -8.0], [11.57, -9.7, 11.57, -12.42], [7.7, -8.0, 7.7, -9.15]]
    beside = [[9.4, -12.41, 9.92, -12.4], [11.25, -12.42, 11.56, -12.41]]
    sides = [[11.234, -12.435, 11.234, -12.916], [10.16, -12.864, 10.168, -12.422]]
    front = [10.207, -12.474, 11.0, -12.461]
    centre = np.array([10.07, -10.16])
    why: dict[str, int] = {}
    lines = np.array([*room, *beside, *sides, front], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, centre, CFG, 3.0, why)).tolist() == [7]
    assert why["front_in_recess"] == 1
    short = lines.copy()
    short[7, 2] = 10.6  # 0.4 m of a 1.07 m mouth
    assert not furniture_in_front(short, centre, CFG, 3.0)[7]
    far = lines.copy()
    far[3] = [8.8, -12.47, 9.5, -12.47]  # a piece in line with the front, 0.66 m short of the side: a door
    assert not furniture_in_front(far, centre, CFG, 3.0)[7]


def test_a_shelf_s_side_stopping_short_of_the_wall_s_line_is_a_side():
    """A shelf's two sides, 0.3 m long, standing on the east wall (x = 6): in a sparse capture their data near
    the wall go into the wall's noisy band, and a side's line stops 7 cm short of the wall's line (degraded
    251 r1): still a side. One stopping 0.2 m short stands off the wall, more than its data fray: it stays."""
    sides = [[5.63, 2.0, 5.93, 2.0], [5.63, 3.0, 5.95, 3.0]]
    lines = np.array([*ROOM, *sides], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0)).tolist() == [4, 5]
    off = np.array([*ROOM, [5.5, 2.0, 5.8, 2.0]], dtype=float)
    assert not furniture_in_front(off, CENTRE, CFG, 3.0).any()


def test_a_narrow_shelf_s_two_sides_beside_each_other_are_both_sides():
    """Degraded dev 122 r3: a shelf seen end on, no front seen, its two sides (0.35 m and 0.4 m long, 12 cm
    apart) standing on the east wall. Each side's inner end lies within `thin_wall_end_tol_m` of the other
    side, which runs along it and meets no end of it: both are sides. A wall across a side's inner end (the
    room's outline stepping there) still keeps it."""
    sides = [[5.65, 2.0, 6.0, 2.0], [5.6, 2.12, 6.0, 2.12]]
    lines = np.array([*ROOM, *sides], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, CENTRE, CFG, 3.0)).tolist() == [4, 5]
    # the east wall steps 0.35 m into the room at y = 2: the step's wall runs on from the side's inner end
    step = np.array(
        [[0, 0, 6, 0], [6, 0, 6, 2], [5.65, 2.0, 6.0, 2.0], [5.65, 2.0, 5.65, 4], [5.65, 4, 0, 4]]
    )
    assert not furniture_in_front(step.astype(float), CENTRE, CFG, 3.0).any()


def test_a_face_standing_free_where_the_room_goes_on_past_its_line_at_both_ends_is_furniture():
    """Degraded dev 268 r2, a room with a 70° east wall seen only near its two corners (too sparse there for a
    line): a cabinet's face 0.87 m long stands 0.5 m in front of that wall, parallel to it, both its ends
    free, and the north and south walls cross its line and run on past it to the slanted wall. The room
    goes on past its line at both its ends: furniture (`front_inside`). An L-room's inner wall seen only in
    its middle (the wing's outer wall runs on past its line at one end only) and a wall seen in its middle
    whose neighbours end at its line (the room's corners, unseen) stay, as does a face whose crossing lines
    are shorter than furniture is deep."""
    cot = 1.0 / math.tan(math.radians(70.0))
    room = [[0.0, 0.0, 4.9, 0.0], [0.0, 4.2, 6.4, 4.2], [0.0, 0.4, 0.0, 3.0]]
    a, b = np.array([4.6 + 1.5 * cot, 1.5]), np.array([4.6 + 2.32 * cot, 2.32])
    face = [*a, *b]
    why: dict[str, int] = {}
    lines = np.array([*room, face], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, np.array([2.5, 2.1]), CFG, 3.0, why)).tolist() == [3]
    assert why["front_inside"] == 1
    # the south wall ends 0.3 m short of the face's line: the room's corner may be there
    cut = lines.copy()
    cut[0, 2] = 4.4
    assert not furniture_in_front(cut, np.array([2.5, 2.1]), CFG, 3.0).any()
    # an L-room (main part 0-6 x 0-4, the wing 0-3 x 4-7): the inner wall y = 4 seen at x 3.8-5.0 only
    l_room = [[0, 0, 6, 0], [6, 0, 6, 4], [0, 0, 0, 7], [0, 7, 3, 7], [3.8, 4, 5.0, 4]]
    assert not furniture_in_front(np.array(l_room, dtype=float), np.array([2.6, 2.8]), CFG, 3.0).any()
    # short lines across (a chair's legs, a door's jambs) make no walls of the room
    short = np.array([*room[2:], face, [5.0, 1.0, 5.6, 1.0], [5.3, 2.8, 5.9, 2.8]], dtype=float)
    assert not furniture_in_front(short, np.array([2.5, 2.1]), CFG, 3.0)[1]
