"""Walls of the next rooms that run across one of the room's walls, seen through its doors in a slice with
nothing seen above it (a handheld scan): `beyond.across_beyond_the_room`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tasks.walls.beyond import across_beyond_the_room
from tasks.walls.config import WallsConfig

CFG = WallsConfig()
INTERIOR = np.array([6.0, 1.0])

# a corridor 12 m x 2 m: its south wall (y = 0) has doors at x = 3-4 and x = 7-8, its north wall (y = 2)
# one at x = 5-6
CORRIDOR = [
    [0, 0, 3, 0],
    [4, 0, 7, 0],
    [8, 0, 12, 0],
    [0, 2, 5, 2],
    [6, 2, 12, 2],
    [12, 0, 12, 2],
]


def _run(extra: list[list[float]], cfg: WallsConfig = CFG) -> tuple[np.ndarray, np.ndarray]:
    lines = np.array(CORRIDOR + extra, dtype=float)
    return across_beyond_the_room(lines, INTERIOR, cfg, 3.0)


def test_the_next_rooms_partitions_behind_a_corridor_wall_go():
    new, out = _run(
        [
            [10, -0.25, 10, -1.5],  # a partition standing on the south wall's back face: behind its data
            [3.5, -1.2, 3.5, -2.5],  # seen through the door at x = 3-4, deep behind it, held by nothing
        ]
    )
    assert out.tolist() == [False] * 6 + [True, True]
    assert np.array_equal(new, np.array([*CORRIDOR, [10, -0.25, 10, -1.5], [3.5, -1.2, 3.5, -2.5]]))
    # both faces of that partition seen: each is held by nothing but the other
    new, out = _run([[3.4, -1.2, 3.4, -2.5], [3.55, -1.3, 3.55, -2.4]])
    assert out.tolist() == [False] * 6 + [True, True]


def test_the_next_room_s_wall_by_a_door_s_jamb_goes():
    # seen through the door at x = 3-4 from 0.6 m behind the south wall's line, beside the jamb at x = 4: the
    # wall's own piece ends within a door's width of it, but holds it no more than a back wall or a side would
    new, out = _run([[4.05, -0.6, 4.05, -1.75]])
    assert out.tolist() == [False] * 6 + [True]
    assert new[-1].tolist() == [4.05, -0.6, 4.05, -1.75]  # judged, not cut


def test_a_line_held_only_by_a_line_gone_beyond_the_room_goes():
    # the next room's corner seen through the door at x = 3-4: its two walls hold each other, until the one
    # along the corridor is found beyond the room (`beyond_the_room`)
    corner = [[3.5, -1.2, 3.5, -2.5], [3.0, -1.2, 3.5, -1.2]]
    _, out = _run(corner)
    assert not out.any()
    lines = np.array(CORRIDOR + corner, dtype=float)
    gone = np.array([False] * 7 + [True])
    new, out = across_beyond_the_room(lines, INTERIOR, CFG, 3.0, gone)
    assert out.tolist() == [False] * 6 + [True, False]  # the one it judged; the one gone stays gone, not out
    assert np.array_equal(new, lines)


def test_the_building_wall_beyond_a_corner_is_cut_or_goes():
    # the west end wall seen with the outer wall that goes on past the corner (through the north door)
    new, out = _run([[0, 0, 0, 3.8]])
    assert not out.any()
    np.testing.assert_allclose(new[-1], [0, 0, 0, 2])
    # and seen apart from it: the piece in line with the end wall, 1 m behind the south wall, goes
    new, out = _run([[0, 0.2, 0, 2], [0, -1.0, 0, -2.2]])
    assert out.tolist() == [False] * 7 + [True]


def test_an_alcove_and_a_wing_stay():
    # an alcove behind the door gap x = 7-8: its sides stand on the south wall's line, its back joins them
    alcove = [[7, 0, 7, -0.9], [7, -0.9, 8, -0.9], [8, -0.9, 8, 0]]
    new, out = _run(alcove)
    assert not out.any()
    assert np.array_equal(new, np.array(CORRIDOR + alcove, dtype=float))
    # an alcove side seen only from 0.4 m behind the line, with the alcove's back beside it
    new, out = _run([[7, -0.4, 7, -0.9], [7, -0.9, 8, -0.9]])
    assert not out.any()
    # a wing's side leaving the line outward next to a far piece: the room goes on there
    new, out = _run([[8, 0, 8, -2.0], [7.2, -1.0, 7.2, -1.8]])
    assert not out.any()


def test_switched_off():
    off = replace(CFG, beyond_room_min_depth_m=0.0)
    new, out = _run([[10, -0.25, 10, -1.5], [0, 0, 0, 3.8]], off)
    assert not out.any()
    assert new[-1].tolist() == [0, 0, 0, 3.8]


def test_a_wall_seen_through_a_door_goes_when_the_corner_s_last_centimetres_are_unseen():
    from tasks.walls.beyond import beyond_the_room

    room = np.array(
        [
            [0.14, 4, 1.7, 4],  # the north wall, seen up to 14 cm short of the corner, a door east of it
            [0, 3.91, 0, 0],  # the west wall, seen up to 9 cm short of it
            [0, 0, 5, 0],
            [5, 0, 5, 2.2],
            # the next room's wall seen through the door 2.1 m beyond, on past the west wall's line by 0.5 m
            [-0.5, 6.1, 1.9, 6.1],
        ],
        dtype=float,
    )
    assert beyond_the_room(room, np.array([2.5, 2.0]), CFG, 3.0).tolist() == [False] * 4 + [True]
    # a wing: the far wall runs on 1.5 m past the room's lines (its side walls unseen), so it stays; not
    # past a corner of the room, though (the west wall ending on the north wall's line: a wing there would
    # leave that wall's end inside it), only where the west wall stops 0.9 m short of that line
    wing = room.copy()
    wing[4] = [-1.5, 6.1, 1.9, 6.1]
    assert beyond_the_room(wing, np.array([2.5, 2.0]), CFG, 3.0).tolist() == [False] * 4 + [True]
    wing[1] = [0, 3.1, 0, 0]
    assert not beyond_the_room(wing, np.array([2.5, 2.0]), CFG, 3.0).any()
