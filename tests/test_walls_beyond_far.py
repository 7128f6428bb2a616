"""Lines seen beyond the room that `beyond.beyond_the_room` and `beyond.across_beyond_the_room` let through
(issue 14, the degraded rooms and hallways): the next room's wall held only by the building's wall going on
past the room's corner, a wall of the room judged from a short line far out, and the lines seen beyond the
end of a wall's seen span."""

from __future__ import annotations

import numpy as np

from tasks.walls.beyond import across_beyond_the_room, beyond_the_room, past_a_corner
from tasks.walls.config import WallsConfig
from tasks.walls.topology import _centre

CFG = WallsConfig()
TOL = 3.0


def test_the_building_wall_past_the_corner_joins_nothing_to_the_next_room_s_wall():
    # a room 4 m x 5 m; its north wall (y = 5) has a door at x = 2.4-3.3
    room = [[0, 0, 4, 0], [4, 0, 4, 4.9], [0, 5, 2.4, 5], [3.3, 5, 4, 5], [0, 0.2, 0, 4.8]]
    beyond = [
        [4, 5.7, 4, 6.4],  # the east wall going on past the room's corner, seen through the door
        [2.9, 6.8, 3.7, 6.8],  # the next room's wall seen through the door, 1.8 m behind the north wall
    ]
    lines = np.array(room + beyond, dtype=float)
    interior = np.array([2.0, 2.5])
    _, gone = across_beyond_the_room(lines, interior, CFG, TOL)
    assert gone.tolist() == [False] * 5 + [True, False]
    # the piece of the east wall looks like a wing's side wall joining the far line to the room...
    assert not beyond_the_room(lines, interior, CFG, TOL).any()
    # ...but it was found beyond the room: it joins nothing, and the far line goes
    assert beyond_the_room(lines, interior, CFG, TOL, gone).tolist() == [False] * 6 + [True]


def test_a_short_line_far_out_does_not_judge_the_room_s_walls():
    # a corridor 12 m x 3 m with its west end barely seen: the end wall's piece at x = 0
    room = [[0, 0, 2, 0], [3.5, 0, 12, 0], [4, 3, 12, 3], [12, 0, 12, 3], [0, 2.0, 0, 2.5]]
    # a short piece of the next room's wall 3 m north of the corridor, seen through a door: the corridor's
    # end wall lies 3 m behind its line, runs along it and is shorter; but the corridor's south wall lies
    # behind it too (2 m of it), more than its own length: it bounds nothing
    far = [[3, 6, 3, 6.8]]
    lines = np.array(room + far, dtype=float)
    out = beyond_the_room(lines, np.array([6.0, 1.5]), CFG, TOL)
    assert not out[4]


def _corridor(extra: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    # a corridor 12 m x 2 m whose west end went unseen: its south wall seen from x = 1, its north from 2.5
    room = [[1, 0, 3, 0], [4, 0, 12, 0], [2.5, 2, 12, 2], [12, 0, 12, 2]]
    return across_beyond_the_room(np.array(room + extra, dtype=float), np.array([7.0, 1.0]), CFG, TOL)


def test_lines_beyond_the_end_of_a_wall_s_seen_span_go():
    _, out = _corridor(
        [
            [0, -0.8, 0, -2.0],  # the building's wall past the unseen west end, 0.8 m behind the south wall
            [1.0, 3.5, 1.0, 5.0],  # a wall of the room north-west, seen through a door in the unseen stretch
        ]
    )
    assert out.tolist() == [False] * 4 + [True, True]


def test_a_wing_beyond_the_end_of_a_wall_s_seen_span_stays():
    # the west wall seen, and in line with it a piece behind the north wall's line: the wall goes on (a wing)
    _, out = _corridor([[0, 0.1, 0, 1.6], [0, 2.9, 0, 4.0]])
    assert not out.any()
    # a wing's side held by its back wall
    _, out = _corridor([[1.0, 2.8, 1.0, 4.0], [1.0, 4.0, 2.4, 4.0]])
    assert not out.any()
    # too shallow to tell from furniture before the wall
    _, out = _corridor([[1.0, 2.5, 1.0, 3.5]])
    assert not out.any()


def test_a_wall_s_unseen_stretch_runs_to_the_end_wall_crossing_its_line():
    # a corridor 12 m x 2 m whose south wall went unseen for its first 1.5 m; its west end wall, seen 0.6 m
    # on past the corner (the building's wall), crosses the south wall's line there: the room's corner, not
    # the room going on behind the south wall. The next room's wall seen through the door at x = 3-4 goes
    room = [[1.5, 0, 3, 0], [4, 0, 12, 0], [0, 2, 12, 2], [12, 0, 12, 2], [0, 1.6, 0, -0.6]]
    lines = np.array([*room, [3.5, -1.2, 3.5, -2.5]], dtype=float)
    _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
    assert out.tolist() == [False] * 5 + [True]
    # a wall running on further behind the line (an L-room's outer wall, its wing behind the south wall)
    # does not end the span there: the room may go on behind it
    lines[4] = [0, 1.6, 0, -2.5]
    _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
    assert not out.any()


def _end_door(extra: list[list[float]]) -> np.ndarray:
    # a corridor 12 m x 2 m whose west end wall (x = 0) has a door at y = 0.6-1.5
    room = [[0, 0, 12, 0], [0, 2, 12, 2], [12, 0, 12, 2], [0, 0, 0, 0.6], [0, 1.5, 0, 2.0]]
    return across_beyond_the_room(np.array(room + extra, dtype=float), np.array([6.0, 1.0]), CFG, TOL)[1]


def test_a_door_s_reveals_go():
    # the wall's end faces at the door's jambs, 0.2 m deep: the wall's thickness, no wall of the room
    out = _end_door([[0, 0.6, -0.2, 0.6], [0, 1.5, -0.2, 1.5]])
    assert out.tolist() == [False] * 5 + [True, True]


def test_a_niche_and_a_partition_s_end_stay():
    # a niche 0.2 m deep behind the door's place: its back holds its sides
    out = _end_door([[0, 0.6, -0.2, 0.6], [-0.2, 0.6, -0.2, 1.5], [0, 1.5, -0.2, 1.5]])
    assert not out.any()
    # a short line behind the wall away from any gap (on the wall's data on both sides): not a reveal
    out = _end_door([[0, 0.3, -0.2, 0.3]])
    assert not out.any()


def test_a_reveal_where_the_wall_was_seen_only_up_to_the_door_goes():
    # the end wall seen only from the corridor's south-west corner up to the door's jamb: its reveal stands
    # at the end of the wall's seen span (degraded 295 hall)
    room = [[0, 0, 12, 0], [0, 2, 12, 2], [12, 0, 12, 2], [0, 0, 0, 0.6], [0, 0.6, -0.2, 0.6]]
    _, out = across_beyond_the_room(np.array(room, dtype=float), np.array([6.0, 1.0]), CFG, TOL)
    assert out.tolist() == [False] * 4 + [True]
    # seen only near its north-west corner: the reveal at the door's south jamb lies past the seen span, the
    # corridor still in front of the end wall's line there (degraded 127 hall)
    room = [[0, 0, 12, 0], [0, 2, 12, 2], [12, 0, 12, 2], [0, 1.5, 0, 2.0], [0, 0.6, -0.2, 0.6]]
    _, out = across_beyond_the_room(np.array(room, dtype=float), np.array([6.0, 1.0]), CFG, TOL)
    assert out.tolist() == [False] * 4 + [True]


def test_the_room_s_wall_beside_an_alcove_is_no_reveal():
    # a room 4.28 m x 4 m with an alcove 1 m wide and 0.6 m deep in its south wall, 0.28 m from the east wall;
    # the east wall seen only up north. The south wall's piece east of the alcove stands on the line of the
    # alcove's side as a reveal would, but the room goes on behind that line: the east wall stands there
    # (degraded 139 r4)
    room = [[0, 0, 3, 0], [3, 0, 3, -0.6], [3, -0.6, 4, -0.6], [4, -0.6, 4, 0], [0, 0, 0, 4], [0, 4, 4.28, 4]]
    lines = np.array([*room, [4.28, 2.0, 4.28, 4.0], [4, 0, 4.28, 0]], dtype=float)
    _, out = across_beyond_the_room(lines, np.array([2.0, 2.0]), CFG, TOL)
    assert not out.any()


def test_a_far_wall_drawn_as_several_lines_counts_once_for_the_room_s_centre():
    """The lines of degraded 331 r4 (plan frame, metres): the next room's wall seen through the door in the
    north wall, 1.9 m behind it, its points smeared a decimetre by the distance and drawn as three lines. By
    their length they pulled the lines' centre out to the north wall's line, which then had no side to tell;
    as one band they count once, and the three go."""
    room = [
        [11.463, -8.63, 11.455, -11.061],  # east
        [8.228, -13.084, 8.226, -13.764],  # the alcove's side, and the west wall's pieces
        [7.724, -8.613, 7.72, -9.905],
        [7.726, -12.744, 7.724, -13.118],
        [9.901, -8.658, 11.482, -8.664],  # north, either side of the door
        [7.708, -8.654, 9.0, -8.658],
        [7.708, -13.075, 8.235, -13.077],  # south, by the south-west corner
    ]
    far = [[8.694, -6.683, 10.53, -6.69], [8.541, -6.741, 10.446, -6.748], [8.795, -6.783, 10.291, -6.664]]
    lines = np.array(room + far)
    assert not beyond_the_room(lines, _centre(lines), CFG, TOL).any()
    centre = _centre(lines, CFG.thin_wall_max_m)
    assert centre[1] < -9.3  # as far from the north wall as the room's own lines put it
    assert beyond_the_room(lines, centre, CFG, TOL).tolist() == [False] * 7 + [True] * 3


def test_a_line_past_a_corner_goes():
    # a room 5 m x 4 m whose south-east corner went unseen (the south wall seen to x = 3, the east from y = 1.2)
    room = [[0, 0, 3, 0], [5, 1.2, 5, 4], [0, 4, 5, 4], [0, 0, 0, 4]]
    past = [[5.2, -1.5, 6.5, -1.5]]  # the next room's wall, 1.5 m behind the south wall, 0.2 m past the east
    lines = np.array(room + past, dtype=float)
    assert beyond_the_room(lines, np.array([2.5, 2.0]), CFG, TOL).tolist() == [False] * 4 + [True]
    assert past_a_corner(lines, np.array([2.5, 2.0]), CFG).tolist() == [False] * 4 + [True]
    # beyond one wall's line only (the room may go on there: a wing), it stays
    lines[-1] = [3.5, -1.5, 4.8, -1.5]
    assert not past_a_corner(lines, np.array([2.5, 2.0]), CFG).any()


def test_a_furniture_face_and_a_jamb_make_no_corner_to_judge_the_far_walls_by():
    """A handheld room (survey building 192's r2, its south-west corner at the origin) whose north wall was
    seen only east of 4.6 m and its slanted east wall only up north: a cabinet's 0.4 m top face before the
    west wall and a door's 0.24 m jamb on the south wall lie across each other, and both far walls lie
    behind both their lines. They are the room's walls, longer than either: they stay."""
    room = [
        [0.0, 0.0, 3.0, 0.0],  # the south wall west of the door
        [0.1, 0.0, 0.1, 1.2],  # the west wall's two pieces
        [0.09, 4.08, 0.09, 2.23],
        [0.19, 2.2, 0.59, 2.2],  # the cabinet's top face
        [3.9, 0.03, 3.9, -0.21],  # the door's east jamb
    ]
    far = [[4.64, 4.08, 6.01, 4.08], [5.38, 2.42, 5.98, 4.08]]  # the north wall's seen end, the east wall's
    lines = np.array(room + far, dtype=float)
    interior = np.array([2.61, 1.31])
    assert not past_a_corner(lines, interior, CFG).any()
    # shorter than the cabinet's face, a line there would be what a door shows of the next room
    lines[5] = [4.64, 4.08, 4.94, 4.08]
    assert past_a_corner(lines, interior, CFG).tolist() == [False] * 5 + [True, False]


def test_an_l_room_s_wing_is_not_past_a_corner():
    # an L-room: 6 m x 3 m with a wing 2 m x 3 m north of its west end; the walls' centre lies east of the
    # wing's inner wall (x = 2), so that wall's back is the wing's side: the wing lies behind both inner walls
    room = [[0, 0, 6, 0], [6, 0, 6, 3], [2, 3, 6, 3], [2, 3, 2, 6], [0, 6, 2, 6], [0, 0, 0, 6]]
    lines = np.array(room, dtype=float)
    assert not past_a_corner(lines, np.array([2.6, 1.9]), CFG).any()
    # the wing's far wall seen alone, its side walls unseen (and the west wall seen only in the main part)
    lines = np.array(
        [[0, 0, 6, 0], [6, 0, 6, 3], [2.4, 3, 6, 3], [0, 0, 0, 2.6], [0.3, 6, 1.7, 6]], dtype=float
    )
    assert not past_a_corner(lines, np.array([2.6, 1.9]), CFG).any()


def test_a_far_wall_running_on_past_the_room_s_corner_is_the_next_room_s():
    # a room 3.6 m x 4 m whose south wall (y = 0) was seen only at its ends; 1.3 m behind it lies a wall of
    # the next room, seen through the gap, that runs on 1.2 m past the room's east corner
    room = [[0, 0, 0.7, 0], [3.0, 0, 3.6, 0], [3.6, 0, 3.6, 4], [0, 0, 0, 4], [2.5, 4, 3.6, 4]]
    far = [[2.9, -1.3, 4.8, -1.3]]
    lines = np.array(room + far, dtype=float)
    interior = np.array([1.8, 2.0])
    assert beyond_the_room(lines, interior, CFG, TOL).tolist() == [False] * 5 + [True]
    # with no corner there (the east wall runs on behind the south wall's line: an L-room's wing), the
    # far line may be the wing's wall and stays
    lines[2] = [3.6, -2.0, 3.6, 4]
    assert not beyond_the_room(lines, interior, CFG, TOL)[5]


def test_walls_seen_through_a_door_go_when_they_pull_the_lines_centre_near_the_door_s_wall():
    """A room 4.6 m x 4.8 m seen mostly along its west and north walls, its north wall's door showing 3 m of
    the next room's walls 1.9 m behind it: with those lines the walls' length-weighted centre, taken for the
    room's interior, lies 0.6 m from the north wall's line. That is on the room's side by more than a thin
    wall's thickness, enough to tell the room's side, so the lines behind the door go."""
    from tasks.walls.topology import _centre

    room = [[0, 0, 1.1, 0], [2.0, 0, 4.6, 0], [0, 0, 0, -4.3], [4.6, -0.8, 4.6, -1.9], [1.8, -4.8, 2.4, -4.8]]
    through_door = [[0.7, 1.85, 2.2, 1.85], [0.7, 1.85, 1.7, 1.72], [1.05, 1.9, 1.6, 1.67]]
    lines = np.array(room + through_door, dtype=float)
    centre = _centre(lines)
    assert CFG.thin_wall_max_m < -centre[1] < CFG.beyond_room_min_depth_m
    _, across = across_beyond_the_room(lines, centre, CFG, TOL)
    assert beyond_the_room(lines, centre, CFG, TOL, across).tolist() == [False] * 5 + [True] * 3


def test_the_building_wall_past_a_corner_the_end_wall_only_reaches_goes():
    """A corridor 12 m x 2 m whose south wall went unseen from x = 8 to its east end; the east end wall's data
    end on the south wall's line (a few centimetres either side) without running on past it. The building's
    wall goes on in line with the end wall 1.5 m past the corner, seen through a door (held-out 241's
    corridor): the end wall ending on the line is the room's corner, so the south wall's span runs on to it
    and the line in line with the end wall, wholly behind, is the next room's (before: only when the end
    wall's data ran on more than `thin_wall_end_tol_m` past the line)."""
    room = [[0, 0, 3, 0], [4, 0, 8, 0], [0, 2, 12, 2], [0, 0, 0, 2]]
    past = [12, -1.5, 12, -3]
    for end_y in (0.0, -0.03, 0.04):
        lines = np.array([*room, [12, 2, 12, end_y], past], dtype=float)
        _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
        assert out.tolist() == [False] * 5 + [True], end_y
    # the end wall running on 1 m behind the line instead: an L-room's outer wall, its wing behind W, may
    # do that; the line in line with it is not judged
    lines = np.array([*room, [12, 2, 12, -1.0], past], dtype=float)
    _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
    assert not out[-1]


def test_a_wall_seen_through_a_door_goes_when_the_corner_s_last_stretch_of_the_side_wall_is_unseen():
    """The north wall seen only 0.8 m, up to 0.2 m short of the north-west corner; the west wall seen up to
    0.7 m short of it (sparse TLS, held-out 247's r5). The next room's wall seen through a door 2.1 m beyond
    is longer than the north wall's piece; the north wall ends at a corner (within a wall's thickness of
    where the lines cross, the west wall within the largest occlusion, `lines.max_gap_m`), so it bounds the
    room and the far line goes. The north wall's piece ending 0.6 m short of the crossing (an L-room's inner
    wall, its wing beyond) or the west wall 0.9 m short make no corner: the far line stays."""
    room = np.array(
        [[0.2, 4, 1.0, 4], [0, 3.3, 0, 0], [0, 0, 5, 0], [5, 0, 5, 2.2], [-0.5, 6.1, 1.9, 6.1]], dtype=float
    )
    interior = np.array([2.5, 2.0])
    assert beyond_the_room(room, interior, CFG, TOL).tolist() == [False] * 4 + [True]
    inner = room.copy()
    inner[0] = [0.6, 4, 1.4, 4]
    assert not beyond_the_room(inner, interior, CFG, TOL).any()
    short = room.copy()
    short[1] = [0, 3.1, 0, 0]
    assert not beyond_the_room(short, interior, CFG, TOL).any()


def test_an_l_room_s_far_wing_stays_when_its_side_wall_is_seen_only_near_both_ends():
    """An L-room (held-out 267 r3): the wing's inner walls never seen but for a piece of the one across
    (W, y = -9.9, 0.6 m), the far wing's wall (y = -8.4) seen in two pieces 1.5 m behind W's line. The
    room's west wall was seen only near its ends, on both sides of W's line, and crosses it 4.6 m from W:
    its pieces in line run on behind W, so W does not bound the room there, and the wing's wall stays (it
    went as a wall of the next room seen through a door). Crossing W's line at W's end, the pieces would
    meet W's wall at a corner, the one behind a wall of the next room (`test_walls_furniture`); and the
    room goes on behind W only as deep as they reach."""
    lines = np.array(
        [
            [7.35, -9.9, 7.36, -13.11],  # east wall
            [1.96, -12.79, 1.96, -13.15],  # west wall, its south piece
            [1.95, -8.35, 1.95, -8.65],  # ...and its north piece, behind W's line
            [3.42, -8.4, 5.01, -8.39],  # the wing's wall, in two pieces
            [1.93, -8.4, 2.49, -8.4],
            [6.57, -9.9, 7.21, -9.9],  # W: the inner wall's piece at the east wall
            [6.19, -13.12, 7.41, -13.12],  # south wall, in two pieces
            [1.95, -13.13, 4.48, -13.12],
        ]
    )
    assert not beyond_the_room(lines, np.array([5.16, -11.31]), CFG, TOL).any()
    # a wall deeper than the side wall's pieces reach (a piece of the next room seen past the wing) goes
    deeper = np.concatenate([lines, [[6.0, -7.85, 6.4, -7.85]]])
    assert beyond_the_room(deeper, np.array([5.16, -11.31]), CFG, TOL).tolist() == [False] * 8 + [True]
    # without the west wall's north piece nothing tells the wing from a room beyond W's line
    assert beyond_the_room(np.delete(lines, 2, axis=0), np.array([5.16, -11.31]), CFG, TOL)[2:4].all()


def test_the_next_room_s_partition_on_the_wall_s_back_face_beside_a_door_goes():
    """A corridor 12 m x 2 m with a door at x = 3-4 in its south wall (0.2 m thick): the next room's
    partition, seen through the door from the wall's back face on (0.2 m behind its line), stands at the
    door's west jamb, held by nothing: it goes (before: only a line wholly more than `thin_wall_max_m`
    behind, or with its foot on the wall's data). Held by an alcove's back within `lines.max_gap_m`, the
    same line stays."""
    room = [[0, 0, 3, 0], [4, 0, 12, 0], [0, 2, 12, 2], [0, 0, 0, 2], [12, 0, 12, 2]]
    partition = [3.0, -0.2, 3.0, -1.0]
    _, out = across_beyond_the_room(np.array([*room, partition], dtype=float), np.array([6.0, 1.0]), CFG, TOL)
    assert out.tolist() == [False] * 5 + [True]
    back = [3.0, -1.0, 4.0, -1.0]
    lines = np.array([*room, partition, back], dtype=float)
    _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
    assert not out.any()


def test_the_building_wall_in_line_with_an_end_wall_seen_only_at_its_far_corner_goes():
    """A corridor 12 m x 2 m whose south wall was seen from x = 2 on and whose west end wall only near its
    north corner (down to y = 1.6); in line with that end wall, 0.85 m behind the south wall's line, the
    building's wall runs on past the corridor (the next room's wall, seen through a door). A wing's outer wall
    goes on from a wall of the room near the line it opens through; this end wall stops 1.6 m short of it:
    the line goes. Seen down to y = 0.4, the end wall may be a wing's outer wall going on: the line stays."""
    room = [[2, 0, 12, 0], [0, 2, 12, 2], [12, 0, 12, 2]]
    building = [0, -0.85, 0, -2.9]
    for end_y, gone in ((1.6, True), (0.4, False)):
        lines = np.array([*room, [0, 2, 0, end_y], building], dtype=float)
        _, out = across_beyond_the_room(lines, np.array([6.0, 1.0]), CFG, TOL)
        assert out.tolist() == [False] * 4 + [gone], end_y


def test_an_end_wall_running_on_through_a_wall_s_line_just_past_its_seen_span_is_the_room_s_corner():
    """A corridor 12 m x 2 m whose north wall was seen from x = 0.33 (its last 0.33 m by the west corner
    unseen); the west end wall, seen from inside the corridor, runs on through the north wall's line and 1 m
    past it (the building's wall, seen through a door): the room's corner, by less than a wing's width
    (`lines.max_gap_m`) past the span, and not an L-room's outer wall with its wing behind the north wall. It
    is cut at the line, and the next room's partition standing on the north wall's back face goes (degraded
    285 hall; before, the end wall kept the north wall from being judged at all). Seen from 1 m on, the north
    wall may end at a wing's opening: nothing is judged."""
    partition = [5.0, 2.25, 5.0, 3.3]
    for seen_from, judged in ((0.33, True), (1.0, False)):
        room = [[seen_from, 2, 3, 2], [4, 2, 12, 2], [0, 0, 12, 0], [12, 0, 12, 2], [0, 1.4, 0, 3.0]]
        cut, out = across_beyond_the_room(
            np.array([*room, partition], dtype=float), np.array([6.0, 1.0]), CFG, TOL
        )
        assert out.tolist() == [False] * 5 + [judged], seen_from
        assert np.allclose(cut[4], [0, 1.4, 0, 2.0] if judged else room[4]), seen_from


def test_a_wall_past_an_l_room_s_inner_step_stays_where_the_room_goes_on_behind_the_step():
    """An L-room (6 x 3 m, and 4 m wide from y = 3 to 6), the lines' centre in its south part: its inner step
    (y = 3, x 4-6) has the room's wall leaving its line outward at its west end (x = 4, going north). The
    west wall's piece seen at y 4-4.7 lies past that end, 1-1.7 m behind the step's line: it is the wing's
    wall, and stays (degraded 308 r3 lost it and closed the room on the next room's wall). Without the wall
    leaving the step's line at that end, nothing says the room goes on there: it goes."""
    room = [[0, 0, 3, 0], [4.5, 0, 6, 0], [6, 0, 6, 3], [6, 3, 4, 3], [0, 0, 0, 0.4], [0, 4, 0, 4.7]]
    step_side = [[4, 3, 4, 4]]
    interior = np.array([3.0, 1.5])
    _, out = across_beyond_the_room(np.array(room + step_side, dtype=float), interior, CFG, TOL)
    assert not out.any()
    _, out = across_beyond_the_room(np.array(room, dtype=float), interior, CFG, TOL)
    assert out.tolist() == [False] * 5 + [True]
