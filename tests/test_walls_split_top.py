"""A cabinet standing in an alcove, its front a few cm in front of the mouth and seen askew, merged with the
wall beside it into one line across the mouth: `topology.split_below_top` cuts it where its pieces stop
below the slice top (issue 14: a clean room's alcove, corner F1 0.71 -> 1.00)."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.lines import MergedLines, fit_line
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import TopCells
from tasks.walls.image import Grid
from tasks.walls.topology import split_below_top

CFG = WallsConfig()
G = 0.01
SHAPE = (200, 600)


def _cells(boxes: list[tuple[float, float, float, float]]) -> np.ndarray:
    img = np.zeros(SHAPE, dtype=bool)
    for x0, x1, y0, y1 in boxes:
        img[round(y0 / G) : round(y1 / G), round(x0 / G) : round(x1 / G)] = True
    return img


def _wall_and_front(front_dy: float, front_top: bool) -> tuple[np.ndarray, TopCells]:
    """A wall at y = 1.0 from x 2.5 to 5.5 whose data reach the top, and a front from x 0.5 to 2.2 at
    y = 1.0 + front_dy, askew by 3 degrees (its pieces as a skeleton gives them), reaching the top or not."""
    wall = [[2.5 + 0.5 * k, 1.0 + 0.002 * (k % 2), 3.0 + 0.5 * k, 1.0 - 0.002 * (k % 2)] for k in range(6)]
    slope = np.tan(np.radians(3.0))
    front = [
        [x, 1.0 + front_dy + slope * (x - 1.35), x + 0.4, 1.0 + front_dy + slope * (x + 0.4 - 1.35)]
        for x in (0.5, 0.9, 1.3, 1.7)
    ]
    data = _cells([(2.5, 5.5, 0.99, 1.01), (0.5, 2.2, 1.0 + front_dy - 0.04, 1.0 + front_dy + 0.04)])
    top = _cells([(2.5, 5.5, 0.99, 1.01)] + ([(0.5, 2.2, 0.9, 1.1)] if front_top else []))
    return np.array(wall + front, dtype=np.float64), TopCells(top, Grid(np.zeros(2), G, SHAPE), data)


def _one_line(hough: np.ndarray) -> MergedLines:
    """The merge's result when it takes all the pieces for one wall (the askew front as its clutter)."""
    n = len(hough)
    zeros = np.zeros(n, dtype=np.intp)
    return MergedLines(
        fit_line(hough, np.ones(n)), zeros, zeros, np.array([0.0]), (), chain=np.zeros(1, np.intp)
    )


def test_a_front_below_the_top_a_few_cm_before_the_wall_is_cut_off():
    hough, top = _wall_and_front(-0.045, front_top=False)
    merged = _one_line(hough)
    out = split_below_top(hough, merged, top, CFG, 3.0, G)
    assert len(out.segments) == 2
    assert out.chain[0] == out.chain[1]  # two walls either side of a step
    wall, front = out.segments
    assert min(wall[0], wall[2]) == pytest.approx(2.5, abs=0.02) and wall[1] == pytest.approx(1.0, abs=0.005)
    assert max(front[0], front[2]) == pytest.approx(2.1, abs=0.02)
    assert set(out.labels[:6]) == {0} and set(out.labels[6:]) == {1}


def test_no_cut_where_both_reach_the_top_or_there_is_no_step():
    hough, top = _wall_and_front(-0.045, front_top=True)
    merged = _one_line(hough)
    assert split_below_top(hough, merged, top, CFG, 3.0, G) is merged
    # pieces of one wall at one offset whose end stops below the top (the sensor's view): no step, no cut
    hough, top = _wall_and_front(0.0, front_top=False)
    merged = _one_line(hough)
    assert split_below_top(hough, merged, top, CFG, 3.0, G) is merged
