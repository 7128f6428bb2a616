"""Corridor ends (issue 14): an end wall smeared by frames levelled a few degrees apart is one wall, not
furniture in front of one (`evidence.own_band`, `evidence.unshadowed_lines`); an open corridor closes
where the data pin its corners (`topology.pinned_corners`), and a join within the tolerance leaves the walls
it joined meeting (`topology._room_polygon`). Below the slice top, a short line is a thin wall's other face
by its distance from the wall line at its middle (`evidence.thin_wall_faces`)."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.evaluate import evaluate_walls
from tasks.lines import is_closed, lengths, wall_graph
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import TopCells, own_band, thin_wall_faces, unshadowed_lines
from tasks.walls.image import Grid
from tasks.walls.model import model_walls
from tasks.walls.topology import _room_polygon, pinned_corners
from tests.scenes import wall_points

CFG = WallsConfig()
G = 0.01


def _cells(shape: tuple[int, int], boxes: list[tuple[float, float, float, float]]) -> np.ndarray:
    """(H, W) bool image of 1 cm cells with the boxes (x0, x1, y0, y1 in metres) filled."""
    img = np.zeros(shape, dtype=bool)
    for x0, x1, y0, y1 in boxes:
        img[round(y0 / G) : round(y1 / G), round(x0 / G) : round(x1 / G)] = True
    return img


def _end_wall(smear_to: float, top_at: tuple[float, float]) -> tuple[np.ndarray, TopCells]:
    """An end wall at x = 1.005 (the room west of it), y 0.5-2.5, its line on its nearest cells; the
    wall's cells reach `smear_to` behind it, its top-reaching cells lie at x `top_at`; and a wall reaching
    the top far away (the corridor's side), which shadows nothing here."""
    shape = (300, 300)
    data = _cells(
        shape, [(1.0, 1.01 + smear_to, 0.5, 2.5), (top_at[0], top_at[1], 0.5, 2.5), (0.0, 0.5, 0.1, 0.12)]
    )
    top = _cells(shape, [(top_at[0], top_at[1], 0.5, 2.5), (0.0, 0.5, 0.1, 0.12)])
    cells = TopCells(top, Grid(np.zeros(2), G, shape), data)
    lines = np.array([[1.005, 0.5, 1.005, 2.5], [0.0, 0.11, 0.5, 0.11]])
    return lines, cells


def test_own_band_is_the_unbroken_run_of_the_line_s_data():
    lines, cells = _end_wall(0.11, (1.22, 1.25))
    lo, hi = own_band(lines[0], cells.data_xy, G)
    # the cells from 1.0 to 1.12 (centres 1.005-1.115): 0 to 11 cm behind the line; the wall cells 10 cm
    # clear of the smear are not part of it. The line runs north: its left normal points west (-x)
    assert (lo, hi) == pytest.approx((-0.11, 0.0), abs=1e-9)
    assert own_band(np.array([5.0, 0.5, 5.0, 2.5]), cells.data_xy, G) == (0.0, 0.0)  # no data there


def test_a_sloping_smear_of_one_end_wall_does_not_shadow_it_and_a_cabinet_front_is_still_shadowed():
    cfg = CFG
    # frames levelled a few degrees apart: the end wall's cells run on unbroken to 12 cm behind its line,
    # and its only top-reaching data lie 8-11 cm behind it, in its own smear: no furniture front
    lines, cells = _end_wall(0.11, (1.08, 1.11))
    keep = np.array([False, True])
    assert unshadowed_lines(lines, keep, cells, cfg)[0]
    # a cabinet's front: its cells 2 cm deep, then nothing for 18 cm, then the wall seen above it
    lines, cells = _end_wall(0.01, (1.2, 1.23))
    assert not unshadowed_lines(lines, keep, cells, cfg)[0]


def _corridor(rng: np.random.Generator) -> np.ndarray:
    """The survey hallway's case (seed 817): a 12 m x 2 m corridor whose north wall the capture missed over
    its western 3 m (a sparse point here and there) while its west wall was seen up to 0.2 m from the
    corner; the west wall has a door 0.25 m wide near its south end, with its jamb's reveal outside."""
    faces = [
        ((0, 0), (12, 0)),
        ((12, 0), (12, 2)),
        ((12, 2), (3, 2)),
        ((0, 1.8), (0, 0.6)),
        ((0, 0.35), (0, 0)),
        ((0, 0.35), (-0.3, 0.35)),  # the door's jamb, the reveal going away from the corridor
    ]
    return np.concatenate([wall_points(a, b, 1.5, 2.5, rng, noise=0.003) for a, b in faces])


def test_pinned_corners_closes_a_corner_one_wall_s_data_pin_and_not_one_neither_does():
    walls = np.array(
        [
            [0, 0, 12, 0],
            [12, 0, 12, 2],
            [12, 2, 3, 2],  # stops 3 m short of the corner
            [0, 1.8, 0, 0.6],  # stops 0.2 m short of it: the corner is pinned
            [0, 0.35, 0, 0],
            [0, 0.35, -0.3, 0.35],  # a door's jamb: the gap 0.6-0.35 ends on it
        ],
        dtype=float,
    )
    origin = np.full(len(walls), "observed")
    closed = pinned_corners(walls, origin, CFG.lines.extend_m, G)
    assert closed is not None
    out, out_origin, polygon, longest = closed
    assert polygon.area == pytest.approx(24.0, abs=0.05) and longest == pytest.approx(3.0)
    assert (out_origin == "extended").sum() == 3  # north wall 3 m, west wall 0.2 m, the door's 0.25 m
    truth = np.array([[0, 0, 12, 0], [12, 0, 12, 2], [12, 2, 0, 2], [0, 2, 0, 0]], float)
    assert evaluate_walls(out, truth)["correctness"] == 1.0
    # the west wall seen only 1.5 m short of the corner: nothing pins it, nothing is invented
    walls[3] = [0, 0.5, 0, 0.6]
    assert pinned_corners(walls, origin, CFG.lines.extend_m, G) is None
    # nor does a wall run on unseen for more than its own length
    walls[3] = [0, 1.8, 0, 0.6]
    walls[2] = [12, 2, 10, 2]
    assert pinned_corners(walls, origin, CFG.lines.extend_m, G) is None


def test_a_corridor_whose_corner_the_west_wall_pins_closes_along_the_north_wall(rng):
    model = model_walls(_corridor(rng), 0.0, 2.7, CFG)
    truth = np.array([[0, 0, 12, 0], [12, 0, 12, 2], [12, 2, 0, 2], [0, 2, 0, 0]], float)
    ev = evaluate_walls(model.walls, truth)
    assert model.closed, model.walls
    assert ev["completeness"] >= 0.99 and ev["correctness"] >= 0.99 and ev["corner_f1"] == 1.0, ev
    assert "pinned" in model.metrics["alpha_reason"]
    assert lengths(model.walls[model.origin == "extended"]).max() == pytest.approx(3.0, abs=0.05)


def test_a_wall_runs_on_past_a_partition_standing_on_it_to_the_corner_its_data_pin():
    """A room 3.6 m x 4.6 m with a partition 1.4 m long and 9 cm thick standing on its west wall 2.9 m from
    the south-west corner: the west wall behind the partition, in the pocket it makes, went unseen, and the
    north wall stops 0.3 m short of the north-west corner. The west wall's end at the partition's face is
    no corner (the partition's other face and its end stand beside it): the wall runs on to the corner."""
    walls = np.array(
        [
            [3.6, 0, 3.6, 4.6],  # east
            [0, 2.9, 0, 0],  # west, up to the partition's upper face
            [3.6, 4.6, 0.3, 4.6],  # north, stopping short of the corner
            [1.4, 2.9, 0, 2.9],  # the partition's upper face, ending on the west wall's end
            [1.4, 2.81, 0, 2.81],  # its lower face, ending on the west wall
            [0, 0, 3.6, 0],  # south
            [1.4, 2.9, 1.4, 2.81],  # its end
        ],
        dtype=float,
    )
    origin = np.array(["observed"] * 6 + ["extended"])
    truth = np.array([[0, 0, 3.6, 0], [3.6, 0, 3.6, 4.6], [3.6, 4.6, 0, 4.6], [0, 4.6, 0, 0]], float)
    closed = pinned_corners(walls, origin, CFG.lines.extend_m, G, thin_m=CFG.thin_wall_max_m)
    assert closed is not None
    out, _, polygon, longest = closed
    assert longest == pytest.approx(1.7)
    assert polygon.area == pytest.approx(3.6 * 4.6 - 1.4 * 0.09, abs=0.02)
    assert evaluate_walls(out, truth)["completeness"] == pytest.approx(1.0)
    # a wall's end at one line across it, a corner, stays one: without the partition's other face the room
    # stays open
    assert pinned_corners(np.delete(walls, 4, axis=0), origin[:-1], CFG.lines.extend_m, G, thin_m=0.3) is None
    # and without looking for partitions too
    assert pinned_corners(walls, origin, CFG.lines.extend_m, G) is None


def test_a_join_within_the_tolerance_leaves_the_walls_it_joined_meeting():
    # a 4 m x 3 m room whose south wall is two pieces 0.8 mm apart, joined by a step of that length
    walls = np.array(
        [
            [0, 0, 2, 0],
            [2, 0, 2, 0.0008],
            [2, 0.0008, 4, 0.0008],
            [4, 0.0008, 4, 3],
            [4, 3, 0, 3],
            [0, 3, 0, 0],
        ],
        dtype=float,
    )
    origin = np.array(["observed", "extended", "observed", "observed", "observed", "observed"])
    polygon, kept, _, _ = _room_polygon(walls, origin, 0.01)
    assert polygon is not None and len(kept) == 5  # the step is no wall at this tolerance
    assert is_closed(wall_graph(kept))  # but the two pieces still meet, at its middle
    np.testing.assert_allclose(kept[0], [0, 0, 2, 0.0004])
    np.testing.assert_allclose(kept[1], [2, 0.0004, 4, 0.0008])


@pytest.mark.slow
def test_a_corridor_whose_refined_walls_leave_a_sparse_stretch_open_closes_on_the_refined_walls():
    """Survey building 783's hallway as Kinect v1 frames: its south wall's far 2.9 m hold few points. The
    pixel model bridged them and closed; the walls refined on the points stopped short of that and stayed
    open, and the pixel model, each piece on its own cells, was kept with a 2 cm jog in the west wall
    (corner F1 0.86). The refined walls are now closed at the corners their data pin, or across the unseen
    stretch, before the pixel model is fallen back on."""
    from bench.walls_survey import run_room
    from tasks.config import load_config
    from tasks.synth.building import generate_building

    r = run_room(generate_building(783), 783, "hall", "mini", load_config([], []), None)
    assert r.error is None and r.closed, r
    assert r.corner_f1 == 1.0 and r.acc_mean_mm <= 2.0, r


def test_a_short_line_a_degree_or_two_off_is_judged_a_thin_wall_s_face_by_its_distance_at_its_middle():
    """A wall reaching the slice top, y = 1.0 from x = 0 to 3.4, and a shelf's side 0.34 m from it (further
    than a thin wall is thick), 0.3 m long, ending with the wall at x = 0 and drawn 2° off it (clean 854 r1):
    no face of a thin wall. Judged by the wall's ends off the short line's own direction, the wall's far end
    came 0.22 m from it, the two 0.28 m apart on average: a partition's two faces, and the side stayed as a
    wall. A stub's other face 0.1 m from the wall, drawn as far off, is one."""
    shape = (200, 400)
    top = _cells(shape, [(0.0, 3.4, 0.995, 1.005)])
    cells = TopCells(top, Grid(np.zeros(2), G, shape), top)
    tilt = np.tan(np.radians(2.0))
    for gap, face in ((0.34, False), (0.1, True)):
        lines = np.array([[0.0, 1.0, 3.4, 1.0], [0.0, 1.0 - gap, 0.3, 1.0 - gap + 0.3 * tilt]])
        got = thin_wall_faces(lines, np.array([True, False]), cells, CFG, 3.0)
        assert got.tolist() == [False, face], gap
