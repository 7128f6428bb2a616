"""A line the Hough merge ran on past a reflex corner of the room, across a gap in its data, in a slice with
nothing seen above it (a handheld scan without a ceiling): a wardrobe's front in line with an alcove's
side is cut off the side and judged on its own (`evidence.split_past_corners`)."""

from __future__ import annotations

import numpy as np

from tasks.evaluate import evaluate_walls
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import split_past_corners
from tests.scenes import wall_points

CFG = WallsConfig()
CENTRE = np.array([3.0, 2.0])
# a 6 x 4 m room with an alcove in its south wall from x 4.4 to 5.5, 0.6 m deep
TRUTH = np.array(
    [
        [0, 0, 4.4, 0],
        [4.4, 0, 4.4, -0.6],
        [4.4, -0.6, 5.5, -0.6],
        [5.5, -0.6, 5.5, 0],
        [5.5, 0, 6, 0],
        [6, 0, 6, 4],
        [6, 4, 0, 4],
        [0, 4, 0, 0],
    ],
    dtype=float,
)


def test_a_wardrobe_s_front_in_line_with_an_alcove_s_side_is_cut_off_it_and_taken_for_furniture(
    rng, monkeypatch
):
    """A wardrobe 0.5 m deep against the east wall from y 0.65 to 1.5, its front in line with the alcove's
    east side (x 5.5); the east wall seen above the wardrobe and by the corner only (degraded 347 r4). The
    merge takes the front and the alcove's side, 0.65 m apart, for one line (and the south wall across the
    alcove's mouth); cut at the corners, the front is furniture and the room is the truth. Without the cut
    the front stands as the room's wall down to the alcove."""
    from tasks.walls import topology
    from tasks.walls.model import model_walls

    seen = [
        *[(TRUTH[i, :2], TRUTH[i, 2:]) for i in range(5)],
        ((6, 0), (6, 0.25)),
        ((6, 1.5), (6, 4)),
        ((6, 4), (0, 4)),
        ((0, 4), (0, 0)),
        ((5.5, 0.65), (5.5, 1.5)),  # the wardrobe's front
        ((5.5, 1.5), (6, 1.5)),  # and its side
    ]
    cut = 1.6
    pts = np.concatenate([wall_points(a, b, 0.0, cut, rng, step=0.02, noise=0.005) for a, b in seen])
    band = pts[pts[:, 2] >= cut - 0.5]
    model = model_walls(band, 0.0, cut, CFG)
    ev = evaluate_walls(model.walls, TRUTH)
    assert model.closed and ev["correctness"] == 1.0 and ev["corner_f1"] == 1.0, (ev, model.walls)
    assert model.metrics["furniture_rules_no_ceiling"]["split_past_corner"] >= 1
    monkeypatch.setattr(topology, "split_past_corners", lambda lines, *a: (lines, np.arange(len(lines))))
    kept = model_walls(band, 0.0, cut, CFG)
    assert evaluate_walls(kept.walls, TRUTH)["correctness"] < 0.95


def _along(a: tuple, b: tuple, step: float = 0.02) -> np.ndarray:
    """Cell centres every `step` from a to b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    s = np.arange(0.0, 1.0, step / float(np.hypot(*(b - a))))
    return a + s[:, None] * (b - a)


def test_a_line_is_cut_only_past_a_corner_turning_away_from_the_room_across_a_gap_in_its_data():
    """The east side of an alcove (x 5.5, y -0.6..0) run on to y 1.5, its data gapped from 0 to 0.65, the
    south wall's piece east of the alcove turning off it at y 0 away from the room: cut into the side
    (to the corner) and the front (from where its data resume). Not cut: with data through the gap (a
    wall with a T behind it), with the piece turning into the room (a corner of the room, the line running
    on as a wall), and with the gap narrower than twice `thin_wall_end_tol_m` (a few cells unseen)."""
    line = [5.5, -0.6, 5.5, 1.5]
    piece = [5.5, 0.0, 6.0, 0.0]
    lines = np.array([line, piece, [0, 4, 6, 4]], dtype=float)
    occ = np.concatenate(
        [_along((5.5, -0.6), (5.5, 0.0)), _along((5.5, 0.65), (5.5, 1.5)), _along((5.5, 0), (6, 0))]
    )
    out, src = split_past_corners(lines, CENTRE, occ, CFG, 3.0)
    assert src.tolist() == [0, 1, 2, 0]
    assert np.allclose(out[0], [5.5, -0.6, 5.5, 0.0], atol=0.01) and np.allclose(
        out[3], [5.5, 0.65, 5.5, 1.5], atol=0.03
    )
    through = np.concatenate([occ, _along((5.5, 0.0), (5.5, 0.65))])
    assert len(split_past_corners(lines, CENTRE, through, CFG, 3.0)[1]) == 3
    inward = lines.copy()
    inward[1] = [5.5, 0.0, 5.0, 0.0]
    occ_in = np.concatenate([occ[: -len(_along((5.5, 0), (6, 0)))], _along((5.0, 0), (5.5, 0))])
    assert len(split_past_corners(inward, CENTRE, occ_in, CFG, 3.0)[1]) == 3
    narrow = np.concatenate(
        [_along((5.5, -0.6), (5.5, 0.0)), _along((5.5, 0.25), (5.5, 1.5)), _along((5.5, 0), (6, 0))]
    )
    assert len(split_past_corners(lines, CENTRE, narrow, CFG, 3.0)[1]) == 3


def test_the_merge_s_line_across_an_alcove_s_mouth_is_cut_where_the_side_crosses_it():
    """The south wall's line run across the alcove's mouth (x 4.4 to 5.5) and the alcove's east side run
    on to the wardrobe's front cross at the alcove's corner: both are cut there, and the wall's piece past
    the mouth starts where its data resume."""
    lines = np.array([[5.5, -0.6, 5.5, 1.5], [3.0, 0.0, 6.0, 0.0], [0, 4, 6, 4]], dtype=float)
    occ = np.concatenate(
        [
            _along((5.5, -0.6), (5.5, 0.0)),
            _along((5.5, 0.65), (5.5, 1.5)),
            _along((5.5, 0), (6, 0)),
            _along((3.0, 0), (4.4, 0)),
        ]
    )
    out, src = split_past_corners(lines, CENTRE, occ, CFG, 3.0)
    assert sorted(src.tolist()) == [0, 0, 1, 1, 2]
    pieces = {tuple(np.round(out[k], 1)) for k in range(len(out))}
    assert (5.5, -0.6, 5.5, 0.0) in pieces and (5.5, 0.6, 5.5, 1.5) in pieces
    assert (3.0, 0.0, 4.4, 0.0) in pieces and (5.5, 0.0, 6.0, 0.0) in pieces


def test_a_front_cut_off_an_alcove_s_side_is_not_in_line_with_it():
    """Degraded 278 r4 at its chosen alpha, after the cuts: a wardrobe's front (x 8.05, 0.85 m) standing
    alone 0.5 m before the west wall's unseen stretch, in line with the alcove's side it was cut from.
    Told its source, `furniture_in_front` takes it (`front_alone`); taken for a piece of one wall with the
    side, it stays."""
    from tasks.walls.evidence import furniture_in_front

    lines = np.array(
        [
            [11.311, -10.62, 11.311, -12.996],
            [8.026, -13.022, 8.02, -13.668],  # the alcove's west side
            [7.541, -11.532, 7.542, -13.056],  # the west wall, seen near its south end
            [8.489, -13.831, 9.055, -13.785],
            [7.567, -13.021, 8.026, -13.022],
            [9.57, -8.191, 10.771, -8.206],
            [8.779, -6.192, 9.247, -6.372],
            [8.05, -10.356, 8.042, -11.208],  # the wardrobe's front, cut off line 1
            [9.102, -13.024, 11.263, -13.028],
        ]
    )
    centre = np.array([9.5, -11.62])
    why: dict[str, int] = {}
    source = np.array([0, 1, 2, 3, 4, 5, 6, 1, 4])
    assert np.flatnonzero(furniture_in_front(lines, centre, CFG, 3.0, why=why, source=source)).tolist() == [7]
    assert why["front_alone"] == 1
    assert not furniture_in_front(lines, centre, CFG, 3.0).any()
