"""Handheld-like rooms (issue 14): a room closed only by the wider reaches must hold the walls seen
(`topology._held_share`)."""

from __future__ import annotations

import numpy as np
import pytest


def test_a_box_the_wider_reaches_close_in_a_corner_does_not_hold_the_walls_seen():
    """A 6 x 4 m room seen along its south, west and part of its north and east walls; the wider reaches
    (`bridge_gaps_m`) joined two pieces of furniture into a line that, with the north-east corner's walls,
    closes a 1.6 x 2.4 m box: it holds under half the observed wall length (`HELD_MIN_SHARE`) and is not the
    room, while the room's own outline holds it all."""
    from shapely.geometry import Polygon

    from tasks.walls.topology import HELD_MIN_SHARE, _held_share

    walls = np.array(
        [[0, 0, 5, 0], [0, 4, 0, 0], [6, 4, 0, 4], [6, 1.2, 6, 4], [4.4, 1.6, 6, 1.6], [4.4, 4, 4.4, 1.6]],
        dtype=float,
    )
    origin = np.array(["observed"] * 4 + ["extended"] * 2)
    box = Polygon([(4.4, 1.6), (6, 1.6), (6, 4), (4.4, 4)])
    room = Polygon([(0, 0), (6, 0), (6, 4), (0, 4)])
    assert _held_share(walls, origin, box, 0.05) < HELD_MIN_SHARE
    assert _held_share(walls, origin, room, 0.05) == pytest.approx(1.0)
