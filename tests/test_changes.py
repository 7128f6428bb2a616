"""Known answers for change detection: added and removed walls, a wall never seen (unknown, not removed),
a moved door, and the room-level changes (split, merged, enlarged)."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from tasks.changes.config import ChangesConfig
from tasks.changes.detect import ADDED, REMOVED, UNKNOWN, PlacedRoom, added_walls, removed_walls, room_changes
from tasks.fuse.openings import Coverage
from tasks.fuse.truth import change_scores

CFG = ChangesConfig()
# a 6 x 4 room (faces), walls 0.2 thick: centrelines 0.1 outside the faces
CENTRE = np.array(
    [[-0.1, -0.1, 6.1, -0.1], [6.1, -0.1, 6.1, 4.1], [6.1, 4.1, -0.1, 4.1], [-0.1, 4.1, -0.1, -0.1]]
)
THICK = np.full(4, 0.2)
FACES = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]], dtype=float)


def seen_everywhere(lo=(-1.0, -1.0), hi=(7.0, 5.0), cell=0.1) -> Coverage:
    shape = (int((hi[1] - lo[1]) / cell), int((hi[0] - lo[0]) / cell))
    return Coverage(lo, cell, np.ones(shape, dtype=bool))


def room(walls: np.ndarray, coverage=None, doors=None, polygon=None, closed=()) -> PlacedRoom:
    return PlacedRoom(
        "r1",
        walls,
        np.ones(len(walls)),
        np.zeros((0, 4)) if doors is None else doors,
        coverage,
        "R1",
        box(0, 0, 6, 4) if polygon is None else polygon,
        closed,
    )


def test_a_new_partition_is_added_and_nothing_else() -> None:
    walls = np.vstack([FACES, [[0, 2.0, 2.0, 2.0], [2.0, 2.0, 2.0, 2.1], [2.0, 2.1, 0, 2.1]]])
    got = added_walls(room(walls, seen_everywhere()), CENTRE, THICK, np.zeros((0, 4)), CFG)
    assert [c.kind for c in got] == [ADDED, ADDED]
    assert min(got[0].x0, got[0].x1) == pytest.approx(0.1)  # from the wall's buffer (t/2 + margin) on
    assert all(c.distance_m > 1.0 for c in got)


def test_a_plan_wall_without_support_is_removed_where_seen_and_unknown_where_never_seen() -> None:
    plan = np.vstack([CENTRE, [[-0.1, 2.0, 3.0, 2.0]]])  # a partition the plan draws, gone in the room
    thick = np.append(THICK, 0.1)
    seen = removed_walls(plan, thick, [room(FACES, seen_everywhere())], CFG)
    assert [(c.kind, round(c.x1 - c.x0, 1)) for c in seen] == [(REMOVED, pytest.approx(3.0, abs=0.31))]
    never = Coverage((4.0, 0.0), 0.1, np.ones((40, 20), dtype=bool))  # the camera only saw x in 4..6
    unseen = removed_walls(plan, thick, [room(FACES, never)], CFG)
    assert [c.kind for c in unseen] == [UNKNOWN]


def test_a_moved_door_is_a_removed_gap_plus_an_added_one() -> None:
    """The plan has a door in the south wall at x 1..2; the room has it at x 4..5 and its wall closed
    at 1..2 (its capture shows that gap closed)."""
    plan = np.array([[-0.1, -0.1, 1.0, -0.1], [2.0, -0.1, 6.1, -0.1], *CENTRE[1:]])
    plan_doors = np.array([[1.0, -0.1, 2.0, -0.1]])
    model_doors = np.array([[4.0, 0.0, 5.0, 0.0]])
    thick = np.full(len(plan), 0.2)
    r = room(FACES, seen_everywhere(), doors=model_doors, closed=(0,))
    added = added_walls(r, plan, thick, plan_doors, CFG)
    removed = removed_walls(plan, thick, [r], CFG)
    assert [(c.kind, round(min(c.x0, c.x1), 1), round(max(c.x0, c.x1), 1)) for c in added] == [
        (ADDED, 1.0, 2.0)
    ]
    assert [c.kind for c in removed] == [REMOVED]
    assert 3.9 < min(removed[0].x0, removed[0].x1) < 4.3 and 4.7 < max(removed[0].x0, removed[0].x1) < 5.1
    open_gap = room(FACES, seen_everywhere(), doors=model_doors)  # the gap not shown closed: no claim
    assert added_walls(open_gap, plan, thick, plan_doors, CFG) == []


def test_a_split_room_a_merged_room_and_an_enlarged_room() -> None:
    plan = {"A": box(0, 0, 6, 4), "B": box(6.2, 0, 10, 4)}
    west = PlacedRoom("w", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, 0, 2.9, 4))
    east = PlacedRoom("e", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(3.0, 0, 6, 4))
    split = room_changes([west, east], plan, CFG)
    assert [(c.kind, c.room_ids, c.plan_rooms) for c in split] == [("room_split", ("e", "w"), ("A",))]
    merged = PlacedRoom("m", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, 0, 10, 4))
    kinds = {c.kind: c for c in room_changes([merged], plan, CFG)}
    assert set(kinds) == {"rooms_merged"} and kinds["rooms_merged"].plan_rooms == ("A", "B")
    big = PlacedRoom("g", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, -1.5, 6, 4))
    kinds = {c.kind: c for c in room_changes([big], plan, CFG)}
    assert set(kinds) == {"room_enlarged"} and kinds["room_enlarged"].share == pytest.approx(
        1.4 * 6 / 24, abs=0.02
    )


def test_a_split_by_a_new_wall_in_one_capture() -> None:
    walls = np.vstack([FACES, [[3.0, 0.0, 3.0, 4.0]]])
    one = PlacedRoom("s", walls, np.ones(5), np.zeros((0, 4)), None, "A", box(0, 0, 6, 4))
    got = room_changes([one], {"A": box(0, 0, 6, 4)}, CFG)
    assert [c.kind for c in got] == ["room_split"] and got[0].extra["parts"] == 2


def test_change_scores() -> None:
    truth = [
        {"x0": 0, "y0": 0, "x1": 2, "y1": 0, "kind": ADDED},
        {"x0": 5, "y0": 5, "x1": 6, "y1": 5, "kind": REMOVED},
    ]
    pred = [
        {"x0": 0.1, "y0": 0.05, "x1": 1.9, "y1": 0.05, "kind": ADDED},
        {"x0": 9, "y0": 9, "x1": 10, "y1": 9, "kind": ADDED},
        {"x0": 5, "y0": 5, "x1": 6, "y1": 5, "kind": UNKNOWN},
    ]
    got = change_scores(pred, truth)
    assert got["precision"] == pytest.approx(0.5) and got["recall"] == pytest.approx(0.5)
