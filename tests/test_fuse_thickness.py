"""Known answers for the local faces of the both-sides thickness (tasks.fuse.thickness) and for a gap that
starts where a wall stops short of its corner (tasks.fuse.gaps)."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import box

from tasks.fuse.config import FuseConfig
from tasks.fuse.gaps import fill_gaps
from tasks.fuse.thickness import PlacedWalls, both_sides_thickness, face_offset, residual_thickness


def face_points(rng: np.random.Generator, x0: float, x1: float, y: float, noise_m: float) -> np.ndarray:
    """A wall face seen from a room: 10 points per cm along it, depth noise across it."""
    x = np.repeat(np.arange(x0, x1, 0.01), 10)
    return np.column_stack([x, y + rng.normal(0.0, noise_m, len(x))])


def test_face_offset_finds_the_face_not_its_noise_or_the_furniture_before_it() -> None:
    rng = np.random.default_rng(1)
    crisp = rng.normal(0.080, 0.002, 700)
    wardrobe = rng.normal(0.030, 0.002, 300)  # 5 cm in front of the face, fewer points
    assert face_offset(np.concatenate([crisp, wardrobe])) == pytest.approx(0.080, abs=0.002)
    noisy = rng.normal(-0.070, 0.020, 2000)  # far-range depth: a wide, symmetric spread
    assert face_offset(noisy) == pytest.approx(-0.070, abs=0.003)
    assert np.isnan(face_offset(np.zeros(0)))


def test_both_sides_thickness_takes_the_faces_where_the_clouds_show_them() -> None:
    """A corridor's face wanders along the wall (0.08 from the centreline where the room beyond lies,
    0.12 past it): its model line, straight over the whole wall, lies at 0.10, so the model lines say
    0.18; the clouds, where both see the wall, say 0.16 (the true wall). A wardrobe before the room's
    face (6 cm in front of it, 20 cm of it) does not move it."""
    rng = np.random.default_rng(2)
    centre = np.array([[0.0, 0.0, 6.0, 0.0]])
    corridor_cloud = np.concatenate(
        [face_points(rng, -1.0, 3.0, 0.08, 0.003), face_points(rng, 3.0, 7.0, 0.12, 0.003)]
    )
    room_cloud = np.concatenate(
        [face_points(rng, 0.0, 3.0, -0.08, 0.003), face_points(rng, 1.0, 1.2, -0.02, 0.003)]
    )
    corridor = PlacedWalls(
        "hall", np.array([[-1.0, 0.10, 7.0, 0.10]]), np.array([[0.0, 1.0]]), corridor_cloud
    )
    room = PlacedWalls("r1", np.array([[0.0, -0.08, 3.0, -0.08]]), np.array([[0.0, -1.0]]), room_cloud)
    args = (centre, np.array([0.2]), [corridor, room], (0.05, 0.6), 0.15)
    got = both_sides_thickness(*args)
    assert got.thickness_m[0] == pytest.approx(0.16, abs=0.002) and got.source[0] == "measured"
    lines = both_sides_thickness(*args, local=False)
    assert lines.thickness_m[0] == pytest.approx(0.18, abs=1e-9)
    # the thesis' residuals (one figure per room) stay available for the comparison
    assert residual_thickness(*args).source[0] == "measured"


def test_both_sides_thickness_keeps_the_lines_where_a_cloud_never_saw_the_wall() -> None:
    """Where one room's cloud shows nothing of its face (the stretch was never looked at), the stations
    both clouds see are fewer than the overlap asked for: the model lines measure it, as without clouds."""
    rng = np.random.default_rng(3)
    centre = np.array([[0.0, 0.0, 4.0, 0.0]])
    left = PlacedWalls(
        "a",
        np.array([[0.0, 0.07, 4.0, 0.07]]),
        np.array([[0.0, 1.0]]),
        face_points(rng, 0.0, 4.0, 0.07, 0.002),
    )
    right = PlacedWalls("b", np.array([[0.0, -0.07, 4.0, -0.07]]), np.array([[0.0, -1.0]]), np.zeros((0, 2)))
    got = both_sides_thickness(centre, np.array([0.2]), [left, right], (0.05, 0.6), 0.15)
    assert got.thickness_m[0] == pytest.approx(0.14, abs=1e-9) and got.source[0] == "measured"


def test_a_wall_stopping_short_of_its_corner_leaves_a_gap_to_the_corner() -> None:
    """The west wall stops 19 cm short of the north-west corner and the north wall 1.5 m short of it: the
    19 cm from the west wall's end to the corner lie within 10 cm of that end, but no wall runs beside
    them; they are gap, filled with the rest, and the room closes."""
    shell = box(0.0, 0.0, 4.0, 3.0)
    walls = np.array(
        [
            [0.0, 0.0, 4.0, 0.0],
            [4.0, 0.0, 4.0, 3.0],
            [4.0, 3.0, 1.5, 3.0],
            [0.0, 2.81, 0.0, 0.0],
        ]
    )
    got = fill_gaps(walls, shell, FuseConfig().gap_end_tol_m)
    assert got.closed and got.free_ends == 2
    assert got.polygon.area == pytest.approx(12.0, rel=1e-6)
    filled = np.hypot(*(got.walls[:, 2:] - got.walls[:, :2]).T).sum()
    assert filled == pytest.approx(0.19 + 1.5, abs=1e-6)
