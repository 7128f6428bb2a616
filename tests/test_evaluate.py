"""Known answers for the wall metrics (PIPELINE.md's definitions)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tasks.evaluate import evaluate_walls, rooms, wall_corners


def box(x0, y0, x1, y1):
    c = np.array([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], dtype=float)
    return np.concatenate([c, np.roll(c, -1, axis=0)], axis=1)


TRUTH = box(0, 0, 4, 3)


def test_perfect_prediction():
    ev = evaluate_walls(TRUTH, TRUTH)
    assert ev["completeness"] == 1.0 and ev["correctness"] == 1.0
    assert ev["accuracy_mean_m"] == pytest.approx(0.0, abs=1e-12)
    assert ev["corner_f1"] == 1.0 and ev["corners_truth"] == 4
    assert ev["angle_error_deg"] == pytest.approx(0.0, abs=1e-9)
    assert ev["room_iou"] == pytest.approx(1.0)


def test_offset_walls_give_their_offset_as_accuracy():
    pred = box(-0.05, -0.05, 4.05, 3.05)  # every wall 5 cm out
    ev = evaluate_walls(pred, TRUTH)
    assert ev["completeness"] == 1.0 and ev["correctness"] == 1.0
    # truth samples are 5 cm from the predicted walls (corner samples a little more: sqrt(2) * 5 cm)
    assert ev["accuracy_median_m"] == pytest.approx(0.05, abs=1e-9)
    assert 0.05 - 1e-9 <= ev["accuracy_mean_m"] < 0.0502
    assert ev["corner_f1"] == 1.0  # corners 7 cm away
    assert ev["room_iou"] == pytest.approx(12.0 / (4.1 * 3.1))
    far = evaluate_walls(box(-0.2, -0.2, 4.2, 3.2), TRUTH)
    assert far["completeness"] == 0.0 and far["corner_f1"] == 0.0
    assert math.isnan(far["accuracy_mean_m"])


def test_missing_wall_and_spurious_wall():
    pred = TRUTH[[0, 1, 2]]  # the left wall (3 m of 14 m) is missing, but for 0.10 m at each end
    ev = evaluate_walls(pred, TRUTH)
    assert ev["completeness"] == pytest.approx(11.2 / 14.0, abs=0.002)
    assert ev["correctness"] == 1.0
    assert ev["corners_pred"] == 2 and ev["corner_recall"] == 0.5 and ev["corner_precision"] == 1.0
    assert ev["corner_f1"] == pytest.approx(2 / 3)
    assert ev["rooms_pred"] == 0 and ev["room_iou"] == 0.0
    extra = np.concatenate([TRUTH, [[1.0, 1.0, 3.0, 1.0]]])  # a 2 m wall in the middle of the room
    ev = evaluate_walls(extra, TRUTH)
    assert ev["correctness"] == pytest.approx(14.0 / 16.0, abs=0.01)


def test_angle_error_of_a_turned_wall():
    a = math.radians(1.0)
    pred = TRUTH.copy()
    pred[1] = [4.0, 0.0, 4.0 - 3 * math.sin(a), 3 * math.cos(a)]  # right wall 1° off
    ev = evaluate_walls(pred, TRUTH)
    assert ev["angle_error_deg"] == pytest.approx(1.0 / 4, abs=1e-6)  # one wall of four


def test_a_jog_shorter_than_the_tolerance_has_no_angle_error():
    """A 3 cm jog lies wholly within 0.10 m of the long walls beside it: its nearest predicted wall is one
    of them, at 90 degrees, which says nothing of the jog's direction."""
    jogged = np.array(
        [[0, 0, 2, 0], [2, 0, 2, 0.03], [2, 0.03, 4, 0.03], [4, 0.03, 4, 3], [4, 3, 0, 3], [0, 3, 0, 0.0]]
    )
    ev = evaluate_walls(jogged, jogged)
    assert ev["angle_error_deg"] == pytest.approx(0.0, abs=1e-9)
    assert ev["walls_matched"] == 5


def test_corners_closer_than_a_centimetre_count_as_one():
    # a slanted room whose inner wall faces meet with a 4 mm jog (walls of different thickness): the
    # model's single corner there matches both, and a jog of 2 cm still has two corners
    def room(jog: float) -> np.ndarray:
        return np.array(
            [[0, 0, 5, 0], [5, 0, 5, jog], [5, jog, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0.0]], dtype=np.float64
        )

    model = np.array([[0, 0, 5, 0], [5, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0.0]])
    ev = evaluate_walls(model, room(0.004))
    assert ev["corners_truth"] == 4 and ev["corner_f1"] == 1.0
    two = evaluate_walls(model, room(0.02))
    assert two["corners_truth"] == 5 and two["corner_recall"] == pytest.approx(0.8)


def test_corners_are_junctions_not_free_ends():
    assert len(wall_corners(np.array([[0, 0, 1, 0.0]]))) == 0
    assert len(wall_corners(np.array([[0, 0, 1, 0], [1, 0, 2, 0.0]]))) == 0  # collinear join
    np.testing.assert_allclose(wall_corners(np.array([[0, 0, 1, 0], [1, 0, 1, 1.0]])), [[1, 0]])


def test_column_inside_is_not_a_room():
    walls = np.concatenate([TRUTH, box(1.8, 1.3, 2.2, 1.7)])
    r = rooms(walls)
    assert len(r) == 1 and r[0].area == pytest.approx(12.0 - 0.16)
    assert evaluate_walls(walls, walls)["room_iou"] == pytest.approx(1.0)


def test_empty_prediction():
    ev = evaluate_walls(np.zeros((0, 4)), TRUTH)
    assert ev["completeness"] == 0.0 and ev["correctness"] == 0.0 and ev["corner_f1"] == 0.0
    assert ev["room_iou"] == 0.0
