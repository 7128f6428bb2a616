"""Furniture in a slice with nothing seen above it (a handheld scan without a ceiling): a wardrobe reaches
the slice top like the walls, so its faces are told by where they stand (`evidence.furniture_in_front`)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from tasks.evaluate import evaluate_walls
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import furniture_in_front
from tests.scenes import wall_points

CFG = WallsConfig()


def _cut_slice_model(pts: np.ndarray, truth: np.ndarray, cut: float) -> tuple[np.ndarray, Any, dict]:
    """(slice, model, scores against `truth`) of a cloud cut at `cut` with no ceiling: the slice is the
    highest half metre under the walls' top, and the top given to the model is the walls'."""
    from tasks.walls.model import model_walls

    band = pts[pts[:, 2] >= cut - 0.5]
    model = model_walls(band, 0.0, cut, CFG)
    return band, model, evaluate_walls(model.walls, truth)


def test_furniture_faces_in_front_of_a_wall_are_told_from_walls_and_an_alcove():
    lines = np.array(
        [
            [0, 0, 2, 0],  # south wall, hidden behind the wardrobe from x = 2 to 3
            [3, 0, 4.5, 0],
            [5.3, 0, 5.95, 0],  # a piece of it at the corner, in line with the rest: not a side
            [6, 0, 6, 4],  # east
            [6, 4, 4.2, 4],  # north, 1.8 m: as short as a wardrobe, beside the alcove's mouth
            [4.2, 4, 4.2, 4.6],  # the alcove (outside the room's line): side, back, side
            [4.2, 4.6, 3, 4.6],
            [3, 4.6, 3, 4],
            [3, 4, 0, 4],
            [0, 4, 0, 0],  # west
            [2, 0.55, 3, 0.55],  # the wardrobe's front, 0.55 m in front of the south wall
            [2, 0, 2, 0.55],  # and its sides
            [3, 0, 3, 0.55],
            [5.4, 4, 5.4, 3.6],  # a short stub meeting nothing, 0.4 m from the north wall: a shelf's side
        ],
        dtype=float,
    )
    found = furniture_in_front(lines, np.array([3.0, 2.0]), CFG, 3.0)
    assert np.flatnonzero(found).tolist() == [10, 11, 12, 13]
    # switched off by a depth range nothing falls in
    off = replace(CFG, furniture_min_depth_m=0.7, furniture_max_depth_m=0.72)
    assert not furniture_in_front(lines, np.array([3.0, 2.0]), off, 3.0).any()


def _room_with_a_wardrobe(rng: np.random.Generator, cut: float) -> tuple[np.ndarray, np.ndarray]:
    corners = [(0, 0), (6, 0), (6, 4), (0, 4)]
    truth = np.array([[*corners[i], *corners[(i + 1) % 4]] for i in range(4)], float)
    faces = [wall_points(t[:2], t[2:], 0.0, cut, rng, step=0.02, noise=0.005) for t in truth]
    # a wardrobe 1 m wide and 0.55 m deep against the south wall, taller than the cut
    box = [((2, 0.55), (3, 0.55)), ((2, 0), (2, 0.55)), ((3, 0.55), (3, 0))]
    faces += [wall_points(a, b, 0.0, cut, rng, step=0.02, noise=0.005) for a, b in box]
    pts = np.concatenate(faces)
    # the wall behind the wardrobe is hidden from the room
    hidden = (pts[:, 1] < 0.02) & (pts[:, 0] > 2.02) & (pts[:, 0] < 2.98)
    return pts[~hidden], truth


def test_a_room_without_a_ceiling_keeps_its_walls_and_drops_a_wardrobe(rng):
    from tasks.walls.model import model_walls

    cut = 1.6
    pts, truth = _room_with_a_wardrobe(rng, cut)
    band, model, ev = _cut_slice_model(pts, truth, cut)
    assert model.closed and len(model.walls) == 4, model.walls
    assert ev["correctness"] == 1.0 and ev["completeness"] > 0.99, ev
    assert model.metrics["lines_furniture_no_ceiling"] >= 1
    # without the test the wardrobe's front is a wall of the room
    kept = model_walls(band, 0.0, cut, replace(CFG, furniture_max_length_m=0.0))
    assert evaluate_walls(kept.walls, truth)["correctness"] < 0.95
    # with a ceiling far above the slice the test is not made (the top-reach test's job)
    high = model_walls(band, 0.0, 2.7, CFG)
    assert high.metrics["lines_furniture_no_ceiling"] == 0


def test_a_wall_seen_through_a_door_beyond_a_barely_seen_wall_goes_and_an_l_room_s_wing_stays():
    from tasks.walls.beyond import beyond_the_room

    room = np.array(
        [
            [0, 0, 1.0, 0],  # the south wall, seen only west of its door (the rest unseen)
            [0, 0, 0, 4],  # west, north, east
            [0, 4, 5, 4],
            [5, 4, 5, 1.5],
            [1.5, -2.0, 2.3, -2.0],  # the corridor's far wall, seen through the door 2 m beyond
        ],
        dtype=float,
    )
    found = beyond_the_room(room, np.array([2.5, 2.0]), CFG, 3.0)
    assert found.tolist() == [False, False, False, False, True]
    # an L-shaped room: the far wing's wall (y = 5) lies 2 m behind the line of the y = 3 wall, but the
    # wing's west wall runs between them
    ell = np.array(
        [[0, 0, 6, 0], [6, 0, 6, 3], [6, 3, 3, 3], [0, 5, 2.6, 5], [0, 5, 0, 0]],
        dtype=float,
    )
    assert not beyond_the_room(ell, np.array([2.5, 2.3]), CFG, 3.0).any()
    # and without it (the wing's side walls unseen) the test cannot tell: switched off, nothing goes
    off = replace(CFG, beyond_room_min_depth_m=0.0)
    assert not beyond_the_room(room, np.array([2.5, 2.0]), off, 3.0).any()


def test_a_wardrobe_in_a_corner_whose_wall_the_sensor_never_saw_above_it_is_no_wall(rng):
    """A full-height room (ceiling captured): a 2 m wardrobe, 1 m wide and 0.5 m deep, in the south-east
    corner hides the south wall behind it at every height (a scanner's view). Its front stops below the
    slice top, but no top-reaching data lies behind it: the south wall's line, which goes on behind it,
    shadows it all the same, and the room closes along the south wall."""
    from tasks.walls.model import model_walls

    corners = [(0, 0), (6, 0), (6, 4), (0, 4)]
    truth = np.array([[*corners[i], *corners[(i + 1) % 4]] for i in range(4)], float)
    faces = [wall_points(t[:2], t[2:], 1.5, 2.5, rng, step=0.01, noise=0.003) for t in truth]
    pts = np.concatenate(faces)
    pts = pts[~((pts[:, 1] < 0.02) & (pts[:, 0] > 4.98))]  # the wall behind the wardrobe, unseen
    box = [((5, 0.5), (6, 0.5)), ((5, 0), (5, 0.5))]
    pts = np.concatenate([pts, *[wall_points(a, b, 1.5, 2.0, rng, noise=0.003) for a, b in box]])
    model = model_walls(pts, 0.0, 2.7, CFG)
    ev = evaluate_walls(model.walls, truth)
    assert model.closed and len(model.walls) == 4 and ev["correctness"] == 1.0, (ev, model.walls)


def test_a_box_beside_a_wall_s_seen_end_is_furniture_and_a_step_into_a_corner_stays():
    """A cabinet 0.9 m wide and 0.5 m deep stands against the south wall just past where the capture saw
    that wall (the wall behind it and beyond it unseen): no wall line runs along its front, but both its
    ends are joined to the wall's line by sides, so it is a box standing on the wall; so is one with a side
    at one end and the room's corner beyond the other, and one with a side at the wall's seen end and its
    other end free (the capture saw the wall up to the box and nothing past it). A step of the same depth
    whose free end runs into a wall of the room meeting its line (the room's outline jogs in there) stays."""
    room = [
        [0, 0, 2, 0],  # south, seen up to x = 2
        [6, 0, 6, 4],  # east, north, west
        [6, 4, 0, 4],
        [0, 4, 0, 0],
    ]
    box = [[2.1, 0.5, 3.0, 0.5], [2.1, 0.02, 2.1, 0.5], [3.0, 0.5, 3.0, 0.04]]
    lines = np.array([*room, *box], dtype=float)
    found = furniture_in_front(lines, np.array([3.0, 2.0]), CFG, 3.0)
    assert np.flatnonzero(found).tolist() == [4, 5, 6]
    # one side, at the south wall's seen end, the other end free 2.5 m short of the east wall
    one_side = np.array([*room, [2.0, 0.5, 3.5, 0.5], [2.0, 0.0, 2.0, 0.5]], dtype=float)
    assert np.flatnonzero(furniture_in_front(one_side, np.array([3.0, 2.0]), CFG, 3.0)).tolist() == [4, 5]
    # the outline steps in at x = 2 and runs on to the east wall, which meets the step's line 0.2 m past
    # its free end (the two lines' ends stop short of the corner)
    step_room = [[0, 0, 2, 0], [3.7, 0.5, 3.7, 4], [3.7, 4, 0, 4], [0, 4, 0, 0]]
    step = np.array([*step_room, [2.0, 0.5, 3.5, 0.5], [2.0, 0.0, 2.0, 0.5]], dtype=float)
    assert not furniture_in_front(step, np.array([1.8, 2.0]), CFG, 3.0).any()
    # a cabinet with one side seen, 0.5 m from the room's corner: the east wall reaches the south wall's
    # line beyond its other end, so the room goes on behind it
    corner = np.array([*room, [4.2, 0.5, 5.5, 0.5], [4.2, 0.0, 4.2, 0.5]], dtype=float)
    assert np.flatnonzero(furniture_in_front(corner, np.array([3.0, 2.0]), CFG, 3.0)).tolist() == [4, 5]


def test_a_short_wall_beside_an_alcove_is_no_box_on_the_alcove_s_back():
    """An alcove 1.4 m wide and 0.6 m deep in the south wall, of which only the 0.6 m west of the alcove was
    seen (the rest, and the south-west corner, unseen): that stretch stands 0.6 m in front of the alcove's
    back with the alcove's side at its end, like a box beside a wall's seen end, but the alcove's other side
    runs from the back's other end into the room as deep and stops there: the back of a recess, and the
    stretch is the room's wall; so is an alcove's side beside the room's corner, past the wall's seen end,
    when the room's wall runs on in line with the piece joining them. A wall of the room seen only near that
    corner, as deep as the box and in line with another piece of it, is no recess's side: the box beside the
    east wall's seen end goes."""
    alcove = [
        [1.4, 0, 2.0, 0],  # the south wall's stretch beside the alcove
        [2.0, -0.6, 3.4, -0.6],  # the alcove's back and sides
        [2.0, -0.6, 2.0, 0],
        [3.4, -0.6, 3.4, 0],
        [0, 1.5, 0, 4],  # west (its south end unseen), north, east
        [0, 4, 5, 4],
        [5, 4, 5, 1],
    ]
    found = furniture_in_front(np.array(alcove, dtype=float), np.array([2.5, 2.0]), CFG, 3.0)
    assert not found[0]
    # an alcove 0.4 m from the south-west corner, its back unseen: its west side stands 0.4 m in front of
    # the west wall's line past that wall's end, the south wall's piece at the corner joining them like a
    # box's side, but the south wall runs on in line with that piece: the side lies beyond the room's wall
    corner_alcove = [
        [0, 4, 0, 0.05],  # west
        [0, 0, 0.4, 0],  # south, by the corner, and in line with it further east
        [3.0, 0, 5, 0],
        [0.4, 0, 0.4, -0.6],  # the alcove's west side
        [5, 0, 5, 4],
        [5, 4, 0, 4],
    ]
    assert not furniture_in_front(np.array(corner_alcove, dtype=float), np.array([2.5, 2.0]), CFG, 3.0).any()
    room = [
        [6, 0.5, 6, 2.8],  # east, seen from 0.5 m above the south-east corner (behind the box) to 2.8 m
        [5.5, 2.8, 5.5, 3.7],  # a cabinet's front beyond the east wall's seen end, and its side
        [5.5, 2.8, 6.0, 2.8],
        [0, 0, 0.5, 0],  # south, seen only by the south-west corner, and in line with it a piece
        [3.0, 0, 4.5, 0],
        [0, 0, 0, 4],  # west
    ]
    found = furniture_in_front(np.array(room, dtype=float), np.array([3.0, 2.0]), CFG, 3.0)
    assert found[1] and found[2] and not found[[0, 3, 4, 5]].any()


def _box_past_a_seen_end(rng: np.random.Generator, cut: float) -> tuple[np.ndarray, np.ndarray]:
    """A 6 x 4 m room without a ceiling whose south wall was seen only east of a cabinet (0.9 m wide,
    0.47 m deep, its east side at x = 3) and whose west wall only from 1.5 m up: the wall behind the cabinet
    and the south-west corner unseen, as a handheld capture leaves them."""
    corners = [(0, 0), (6, 0), (6, 4), (0, 4)]
    truth = np.array([[*corners[i], *corners[(i + 1) % 4]] for i in range(4)], float)
    seen = [((3.0, 0), (6, 0)), ((6, 0), (6, 4)), ((6, 4), (0, 4)), ((0, 4), (0, 1.5))]
    faces = [wall_points(a, b, 0.0, cut, rng, step=0.03, noise=0.008) for a, b in seen]
    box = [((2.1, 0.47), (3.0, 0.47)), ((3.0, 0.47), (3.0, 0.0))]
    faces += [wall_points(a, b, 0.0, cut, rng, step=0.03, noise=0.008) for a, b in box]
    return np.concatenate(faces), truth


def test_a_room_without_a_ceiling_drops_a_cabinet_standing_past_a_wall_s_seen_end(rng, monkeypatch):
    from tasks.walls import topology
    from tasks.walls.model import model_walls

    cut = 1.5
    pts, truth = _box_past_a_seen_end(rng, cut)
    band, model, ev = _cut_slice_model(pts, truth, cut)
    assert ev["correctness"] == 1.0, (ev, model.walls)
    assert model.metrics["lines_furniture_no_ceiling"] >= 1
    # without the furniture tests the closing step takes the cabinet's front and side for a box's
    # (`topology._box_fronts`); without that as well they are walls of the room
    no_tests = replace(CFG, furniture_max_length_m=0.0)
    assert evaluate_walls(model_walls(band, 0.0, cut, no_tests).walls, truth)["correctness"] == 1.0
    monkeypatch.setattr(topology, "_box_fronts", lambda walls, *_: np.zeros(len(walls), dtype=bool))
    kept = model_walls(band, 0.0, cut, no_tests)
    assert evaluate_walls(kept.walls, truth)["correctness"] < 0.95


def test_a_long_wall_beyond_a_short_wall_at_a_corner_and_an_oblique_one_go_and_an_island_s_wall_stays():
    """Seen through a door in the south wall, of which only the 1.5 m by the south-east corner was seen:
    the next room's wall 2 m beyond is longer than that piece, and a sparse one is drawn 12 degrees off.
    Both lie wholly beyond the room's line with nothing of the room between: gone. A 1.5 m counter in the
    middle of the room (free ends, no corner) with the room's wall 1.5 m behind it keeps that wall."""
    from tasks.walls.beyond import beyond_the_room

    room = np.array(
        [
            [3.5, 0, 5, 0],  # south, seen only by the south-east corner
            [5, 0, 5, 4],  # east, north, west (its south end unseen)
            [5, 4, 0, 4],
            [0, 4, 0, 2.0],
            [0.5, -2.0, 3.0, -2.0],  # the next room's wall, 2.5 m
            [0.4, -2.8, 1.4, -2.59],  # and one of its walls drawn from a few points, 12 degrees off
        ],
        dtype=float,
    )
    found = beyond_the_room(room, np.array([2.5, 2.0]), CFG, 3.0)
    assert found.tolist() == [False] * 4 + [True, True]
    island = np.array(
        [[1.5, 1.5, 3.0, 1.5], [0, 0, 4, 0], [0, 4, 4, 4], [0, 3.0, 0, 4], [4, 3.0, 4, 4]], dtype=float
    )
    assert not beyond_the_room(island, np.array([2.0, 3.0]), CFG, 3.0).any()


def test_a_free_standing_front_past_a_slanted_wall_s_seen_end_is_furniture_and_a_jog_in_line_stays():
    """A slanted east wall (70°) seen only on its southern half; a cabinet's front, 0.9 m long, stands 0.4 m
    in front of its unseen northern half, both ends free and in line with nothing: the wall's line runs
    behind it between the room's corners (where the south and north walls meet that line), so it is
    furniture. The same front with a piece of wall in line with it (a jog of the wall, its pieces seen
    apart) stays, and so does a free line standing beyond the room's corner."""
    u = np.array([math.cos(math.radians(70)), math.sin(math.radians(70))])
    inward = np.array([-u[1], u[0]])
    corner = np.array([5.0, 0.0]) + 4.0 / u[1] * u  # where the east wall meets the north wall's line
    room = [
        [0, 0, 5, 0],  # south
        [5.0, 0.0, *(np.array([5.0, 0.0]) + 2.1 * u)],  # east, seen up to 2.1 m along it
        [*corner, 0, 4],  # north, west
        [0, 4, 0, 0],
    ]

    def along(t0: float, t1: float, depth: float) -> list[float]:
        a = np.array([5.0, 0.0]) + t0 * u + depth * inward
        return [*a, *(a + (t1 - t0) * u)]

    centre = np.array([2.5, 2.0])
    front = np.array([*room, along(2.6, 3.5, 0.4)], dtype=float)
    assert np.flatnonzero(furniture_in_front(front, centre, CFG, 3.0)).tolist() == [4]
    jog = np.array([*room, along(2.6, 3.5, 0.4), along(3.6, 3.9, 0.4)], dtype=float)
    assert not furniture_in_front(jog, centre, CFG, 3.0)[4]
    past = np.array([*room, along(4.6, 5.4, 0.4)], dtype=float)
    assert not furniture_in_front(past, centre, CFG, 3.0).any()


def test_a_cabinet_s_short_side_drawn_some_degrees_off_is_still_its_side():
    """A cabinet's side 0.45 m long, drawn 8° off the perpendicular from its few noisy points (each end good
    to a few cm), joins its 1.45 m front to the east wall: it is the cabinet's side, not a wall."""
    room = [[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]]
    tilt = math.tan(math.radians(8.0)) * 0.45
    cabinet = [[5.5, 1.0, 5.5, 2.45], [5.52, 2.45, 5.97, 2.45 + tilt]]
    lines = np.array([*room, *cabinet], dtype=float)
    assert np.flatnonzero(furniture_in_front(lines, np.array([3.0, 2.0]), CFG, 3.0)).tolist() == [4, 5]


def test_a_wall_s_piece_at_a_corner_in_line_with_its_next_piece_past_a_door_is_no_side():
    """A corridor's south wall seen 0.69 m from its west corner (its line drawn 1.7° off from the few points)
    and again past a door from x = 1.7 on; the west end wall's line runs on past the corner (the building's
    wall seen through the door). The corner piece stands on the end wall's line, short, its inner end free:
    like a cabinet's side, but in line with the south wall's next piece a door's opening away (judged
    along that piece's line, as the short line's own direction is good to a few degrees only), so it stays
    (held-out 256's corridor). With the next piece 1.3 m away, further than a door opens, it goes."""
    lines = np.array([[0, -1.5, 0, 2], [0, 2, 6, 2], [6, 2, 6, 0], [1.7, 0, 6, 0], [0, 0, 0.69, -0.02]])
    assert not furniture_in_front(lines, np.array([3.0, 1.0]), CFG, 3.0).any()
    lines[3] = [2.0, 0, 6, 0]
    assert np.flatnonzero(furniture_in_front(lines, np.array([3.0, 1.0]), CFG, 3.0)).tolist() == [4]


def test_a_plant_s_facets_are_lone_directions_and_a_wall_at_its_own_angle_is_not():
    """A plant's pot, a decagon 0.3 m in radius, in a room's corner gives short lines at directions no wall
    takes; the room's walls, its slanted wall (seen over 2 m in two pieces) and the facets that happen to
    lie along the walls' directions are not lone."""
    from tasks.walls.evidence import lone_directions

    u = np.array([math.cos(math.radians(70)), math.sin(math.radians(70))])
    room = [
        [0, 0, 5, 0],
        [5.0, 0.0, *(np.array([5.0, 0.0]) + 1.2 * u)],
        [*(np.array([5.0, 0.0]) + 2.0 * u), *(np.array([5.0, 0.0]) + 2.9 * u)],
        [0, 4, 0, 0],
    ]
    k = np.arange(11) * 2 * math.pi / 10
    ring = np.column_stack([0.6 + 0.3 * np.cos(k), 3.4 + 0.3 * np.sin(k)])
    facets = [[*ring[i], *ring[i + 1]] for i in range(10)]
    lines = np.array([*room, *facets], dtype=float)
    lone = lone_directions(lines, CFG.furniture_lone_direction_m, 3.0, 0.02)
    assert not lone[:4].any()
    d = ring[1:] - ring[:-1]
    facet_deg = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180
    off = np.abs((facet_deg[:, None] - np.array([0.0, 70.0, 90.0])[None, :] + 90) % 180 - 90)
    along_walls = off.min(axis=1) <= 3.0  # the facets at 0° and 72°
    assert (lone[4:] == ~along_walls).all() and lone[4:].sum() == 6
    # the same slanted wall seen over 0.5 m only is lone under a 0.75 m total; a zero total switches it off
    short = np.array([room[0], [5.0, 0.0, *(np.array([5.0, 0.0]) + 0.5 * u)], room[3]], dtype=float)
    assert lone_directions(short, 0.75, 3.0, 0.02).tolist() == [False, True, False]
    assert not lone_directions(short, 0.0, 3.0, 0.02).any()


def test_the_next_room_s_corner_seen_through_a_door_does_not_join_its_far_wall_to_the_room():
    """Seen through a door in the south wall (two pieces, 1.2 m and 1.6 m, the door between them): the
    next room's far wall 2.3 m beyond, running behind the west piece's data, and its west wall's end by its
    corner (a short line across, wholly beyond the room's reach too). That line lies between the south
    wall's line and the far wall, but it joins nothing of this room to it: the far wall goes all the same
    (it stayed when any line there counted). An L-room's wing, whose west wall runs from the room's line
    to the far wall, keeps its wall."""
    from tasks.walls.beyond import beyond_the_room

    room = np.array(
        [
            [0, 4, 4, 4],  # north
            [4, 4, 4, 0],  # east
            [2.1, 0, 3.6, 0],  # south, east of the door
            [0, 0, 1.2, 0],  # south, west of the door
            [0.0, -2.3, 1.6, -2.3],  # the next room's far wall
            [0.0, -1.75, 0.0, -2.3],  # the next room's west wall, by its corner
            [0, 4, 0, 0.7],  # west
        ],
        dtype=float,
    )
    found = beyond_the_room(room, np.array([2.0, 2.0]), CFG, 3.0)
    assert found.tolist() == [False] * 4 + [True, False, False]
    # a wing: its west wall runs from the south wall's line down to the far wall, which stays
    wing = room.copy()
    wing[5] = [0.0, 0.0, 0.0, -2.3]
    assert not beyond_the_room(wing, np.array([2.0, 2.0]), CFG, 3.0)[4]


def test_a_corridor_s_far_wall_is_not_behind_a_short_piece_by_the_lines_centre():
    """A corridor 2 m wide: its south wall in pieces (doors between them) and the walls of the rooms south
    of it seen through them pull the lines' length-weighted centre to 0.1 m from the south wall's line, where
    a door's 0.3 m jamb face runs (at the corridor's west end, the west wall beside it barely seen). Judged
    by that centre, the jamb's back is the corridor and its north wall lies 1.6 m behind it: that line has no
    side to tell (the centre is nearer it than the depth asked for), and the north wall stays."""
    from tasks.walls.beyond import beyond_the_room

    lines = np.array(
        [
            [6.5, 2.0, 9.3, 2.0],  # north, in two pieces (a jog of 6 cm)
            [9.3, 1.94, 13.0, 1.94],
            [-0.3, 0.4, 0.0, 0.4],  # a jamb's face by the west end
            [0.0, 0.0, 1.2, 0.0],  # south, in pieces
            [2.1, 0.0, 3.6, 0.0],
            [4.5, 0.0, 7.3, 0.0],
            [8.3, 0.0, 10.4, 0.0],
            [3.0, -1.0, 3.0, -2.2],  # the rooms south of it, seen through the doors
            [0.0, -2.1, 0.0, 0.4],  # ...and the west wall's line below the jamb
            [0.0, 1.6, 0.0, 2.0],  # west, barely seen above it
        ],
        dtype=float,
    )
    assert not beyond_the_room(lines, np.array([6.0, 0.1]), CFG, 3.0)[:2].any()


def _room_with_an_open_shelf(rng: np.random.Generator, cut: float) -> tuple[np.ndarray, np.ndarray]:
    """A 6 x 4 m room cut at `cut` whose south wall the capture saw only through a shelf standing against
    it (1.2 m wide, 0.35 m deep, no back): its two sides, a row of books with their backs 0.3 m out, and
    above them a few points of the wall."""
    corners = [(0, 0), (6, 0), (6, 4), (0, 4)]
    truth = np.array([[*corners[i], *corners[(i + 1) % 4]] for i in range(4)], float)
    pts = [wall_points(t[:2], t[2:], 0.0, cut, rng, step=0.02, noise=0.005) for t in truth[1:]]
    pts += [wall_points((x, 0), (x, 0.35), 0.0, cut, rng, step=0.02, noise=0.005) for x in (2.0, 3.2)]
    pts.append(wall_points((2, 0.3), (3.2, 0.3), cut - 0.5, cut - 0.25, rng, step=0.02, noise=0.005))
    pts.append(wall_points((2, 0), (3.2, 0), cut - 0.2, cut - 0.1, rng, step=0.08, noise=0.005))
    return np.concatenate(pts), truth


def test_an_open_shelf_s_front_seen_through_is_moved_onto_the_wall_behind_it(rng, monkeypatch):
    from tasks.walls import topology
    from tasks.walls.model import model_walls

    cut = 1.6
    pts, truth = _room_with_an_open_shelf(rng, cut)
    band, model, ev = _cut_slice_model(pts, truth, cut)
    assert ev["correctness"] == 1.0, (ev, model.walls)
    assert model.metrics["furniture_rules_no_ceiling"]["seen_through"] == 1
    # without the rule the books stand 0.3 m in front of the wall
    monkeypatch.setattr(
        topology,
        "seen_through_fronts",
        lambda lines, *a: (np.zeros(len(lines), bool), np.zeros(len(lines), bool), lines),
    )
    kept = model_walls(band, 0.0, cut, CFG)
    assert evaluate_walls(kept.walls, truth)["correctness"] < 0.95


def test_a_shelf_s_front_seen_through_moves_with_its_side_and_a_wall_door_partition_or_wing_is_not():
    from tasks.walls.evidence import seen_through_fronts

    lines = np.array(
        [
            [0, 0, 6, 0],  # south wall
            [6, 0, 6, 4],
            [6, 4, 0, 4],
            [0, 4, 0, 0],
            [2, 0.35, 3.2, 0.35],  # a front 0.35 m before the south wall
        ],
        dtype=float,
    )
    centre = np.array([3.0, 2.0])
    along = np.arange(2.0, 3.2, 0.02)
    front = np.column_stack([along, np.full(len(along), 0.35)])

    def behind(xs: np.ndarray) -> np.ndarray:
        return np.column_stack([xs, np.zeros(len(xs))])

    # the wall between the boards in 0.6 of the front's bins: moved onto it
    seen = behind(along[(along - 2.0) % 0.5 < 0.3])
    moved, sides, out = seen_through_fronts(
        lines, np.ones(5, bool), centre, np.concatenate([front, seen]), CFG
    )
    assert moved.tolist() == [False] * 4 + [True] and not sides.any()
    assert np.allclose(out[4], [2, 0, 3.2, 0], atol=0.01) and np.allclose(out[:4], lines[:4])
    # its side, from its end to the wall behind, goes with it
    sided = np.vstack([lines, [2.0, 0.36, 2.0, 0.01]])
    moved, sides, _ = seen_through_fronts(sided, np.ones(6, bool), centre, np.concatenate([front, seen]), CFG)
    assert moved.tolist() == [False] * 4 + [True, False] and sides.tolist() == [False] * 5 + [True]
    # a wall across its end runs on past the wall found behind it: the room lies there (an L-shaped room's
    # centre may lie on the wrong side of a line in its wing)
    crossed = np.vstack([lines, [3.2, 0.35, 3.2, -2.0]])
    occ = np.concatenate([front, seen])
    assert not seen_through_fronts(crossed, np.ones(6, bool), centre, occ, CFG)[0].any()
    # ...in a quarter of them: a shelf with a back, some stray points: stays
    few = behind(along[(along - 2.0) % 0.5 < 0.08])
    assert not seen_through_fronts(lines, np.ones(5, bool), centre, np.concatenate([front, few]), CFG)[
        0
    ].any()
    # a wall with a door: what lies beyond is seen where the wall is not
    wall = front[along < 2.6]
    beyond = behind(along[along >= 2.6])
    assert not seen_through_fronts(lines, np.ones(5, bool), centre, np.concatenate([wall, beyond]), CFG)[
        0
    ].any()
    # a partition standing in the room, its other face 0.1 m behind: the room goes on behind it
    both = np.vstack([lines, [2, 0.25, 3.2, 0.25]])
    occ = np.concatenate([front, front - [0, 0.1], seen])
    assert not seen_through_fronts(both, np.ones(6, bool), centre, occ, CFG)[0].any()
    # a front no longer than furniture is deep is left to the side rule
    short = lines.copy()
    short[4] = [2, 0.35, 2.7, 0.35]
    occ = np.concatenate([front[along < 2.7], seen[seen[:, 0] < 2.7]])
    assert not seen_through_fronts(short, np.ones(5, bool), centre, occ, CFG)[0].any()
