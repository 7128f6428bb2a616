"""A wardrobe standing in an alcove, in a slice with nothing seen above it (a handheld scan without a
ceiling): its front reaches the slice top like the walls, and the alcove's side, seen past it, tells that
the alcove's back lies deeper (`evidence.recess_backs`)."""

from __future__ import annotations

import numpy as np

from tasks.evaluate import evaluate_walls
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import recess_backs
from tests.scenes import wall_points

CFG = WallsConfig()
CENTRE = np.array([3.0, 2.0])
# a 6 x 4 m room whose south wall has an alcove from x 2.5 to 3.7, 0.6 m deep (its back at y = -0.6)
TRUTH = np.array(
    [
        [0, 0, 2.5, 0],
        [2.5, 0, 2.5, -0.6],
        [2.5, -0.6, 3.7, -0.6],
        [3.7, -0.6, 3.7, 0],
        [3.7, 0, 6, 0],
        [6, 0, 6, 4],
        [6, 4, 0, 4],
        [0, 4, 0, 0],
    ],
    dtype=float,
)


def _alcove_with_a_wardrobe(rng: np.random.Generator, cut: float, east_piece: bool) -> np.ndarray:
    """The room cut at `cut`, a wardrobe 0.35 m deep and 0.9 m wide against the alcove's back, 0.15 m from
    its west side: seen are the alcove's west side down to the back, the back in the gap beside the
    wardrobe, the wardrobe's front and west side; the alcove's east side is unseen, the east wall below
    y = 1.5 too, and the south wall east of the alcove only when `east_piece`."""
    seen = [
        ((0, 0), (2.5, 0)),
        ((2.5, 0), (2.5, -0.6)),
        ((2.5, -0.6), (2.65, -0.6)),
        ((6, 1.5), (6, 4)),
        ((6, 4), (0, 4)),
        ((0, 4), (0, 0)),
        ((2.65, -0.25), (3.55, -0.25)),
        ((2.65, -0.25), (2.65, -0.6)),
    ]
    if east_piece:
        seen.append(((3.7, 0), (6, 0)))
    return np.concatenate([wall_points(a, b, 0.0, cut, rng, step=0.02, noise=0.005) for a, b in seen])


def test_a_wardrobe_in_an_alcove_seen_with_one_side_gives_way_to_the_alcove_s_back(rng, monkeypatch):
    """The wardrobe's front moves back to where the alcove's side's data end, its own side goes, and the
    room closes with the alcove's back 0.6 m deep (with the south wall east of the alcove seen or not);
    without the rule the front stands as the alcove's back, 0.35 m short of it."""
    from tasks.walls import topology
    from tasks.walls.model import model_walls

    cut = 1.6
    for east_piece in (False, True):
        pts = _alcove_with_a_wardrobe(rng, cut, east_piece)
        band = pts[pts[:, 2] >= cut - 0.5]
        model = model_walls(band, 0.0, cut, CFG)
        assert model.closed
        assert model.metrics["furniture_rules_no_ceiling"]["recess_back"] == 1
        walls = np.asarray(model.walls)
        flat = np.abs(walls[:, 1] - walls[:, 3]) < 0.01
        assert np.abs(walls[flat, 1] + 0.6).min() < 0.02, walls  # the alcove's back
        assert np.abs(walls[flat, 1] + 0.25).min() > 0.1, walls  # no wardrobe's front
        if east_piece:
            assert evaluate_walls(model.walls, TRUTH)["correctness"] >= 0.97
    monkeypatch.setattr(
        topology,
        "recess_backs",
        lambda lines, *a: (np.zeros(len(lines), bool), np.zeros(len(lines), bool), lines),
    )
    kept = model_walls(band, 0.0, cut, CFG)
    walls = np.asarray(kept.walls)
    flat = np.abs(walls[:, 1] - walls[:, 3]) < 0.01
    assert np.abs(walls[flat, 1] + 0.25).min() < 0.02, walls


def _column(x: float, y0: float, y1: float) -> np.ndarray:
    """Cell centres every 2 cm along x = `x` from y0 to y1."""
    ys = np.arange(y0, y1, -0.02 if y1 < y0 else 0.02)
    return np.column_stack([np.full(len(ys), x), ys])


def test_a_front_moves_only_with_a_side_seen_past_it_from_the_room_s_wall_and_nothing_behind_it():
    """Lines: the room's walls, the wall's piece west of the alcove, the alcove's west side (its line to
    -0.4, its data to -0.58) and the wardrobe's front at -0.25 and own side. The front moves to -0.58 and
    its own side goes. It stays when the side starts from no wall of the room (a partition's stub across the
    room's end), when the side's data end within furniture's least depth past it (an alcove's back with
    its side's few cm of noise), when data lie behind it (an open shelf), and when the room's centre lies
    within furniture's depth of it."""
    room = [[6, 4, 0, 4], [0, 4, 0, 0], [6, 1.5, 6, 4], [0, 0, 2.5, 0]]
    side = [2.5, 0, 2.5, -0.4]
    front = [2.65, -0.25, 3.55, -0.25]
    own = [2.65, -0.27, 2.65, -0.55]
    lines = np.array([*room, side, front, own], dtype=float)
    occ = np.concatenate(
        [_column(2.5, 0.0, -0.59), np.column_stack([np.arange(2.65, 3.55, 0.02), np.full(45, -0.25)])]
    )
    moved, sides, out = recess_backs(lines, np.ones(7, bool), CENTRE, occ, CFG)
    assert moved.tolist() == [False] * 5 + [True, False] and sides.tolist() == [False] * 6 + [True]
    assert np.allclose(out[5], [2.65, -0.58, 3.55, -0.58], atol=0.015) and np.allclose(out[:5], lines[:5])
    # the side's corner on no wall of the room
    alone = lines.copy()
    alone[3] = [0, 0, 1.5, 0]
    assert not recess_backs(alone, np.ones(7, bool), CENTRE, occ, CFG)[0].any()
    # the side's data end 0.1 m past the front
    shallow = np.concatenate([_column(2.5, 0.0, -0.35), occ[occ[:, 0] > 2.6]])
    short = lines.copy()
    short[4, 3] = -0.3
    assert not recess_backs(short, np.ones(7, bool), CENTRE, shallow, CFG)[0].any()
    # data behind the front in its bins
    behind = np.column_stack([np.arange(2.7, 3.5, 0.02), np.full(40, -0.5)])
    assert not recess_backs(lines, np.ones(7, bool), CENTRE, np.concatenate([occ, behind]), CFG)[0].any()
    # the room's centre 0.5 m from the front
    assert not recess_backs(lines, np.ones(7, bool), np.array([3.0, 0.25]), occ, CFG)[0].any()
