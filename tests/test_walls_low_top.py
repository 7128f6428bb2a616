"""Walls a handheld capture saw only part of the way up (`tasks.walls.lowtop.low_topped_walls`,
`tasks.walls.stage.room_model`): synthetic rooms without a ceiling, with known answers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tasks.evaluate import evaluate_walls
from tasks.walls.config import WallsConfig
from tasks.walls.lowtop import low_topped_walls
from tasks.walls.stage import room_model
from tests.scenes import wall_points

CFG = WallsConfig()
STEP = 0.04  # a handheld scan's spacing
TRUTH = np.array([[0, 0, 5, 0], [5, 0, 5, 4], [5, 4, 0, 4], [0, 4, 0, 0]], dtype=float)


def face(a, b, z0, z1, rng):
    return wall_points(a, b, z0, z1, rng, step=STEP, noise=0.005)


def top_surface(x0, x1, y0, y1, z, rng):
    """A horizontal surface (a cabinet's top), one point per STEP², 5 mm of noise in height."""
    x, y = np.meshgrid(np.arange(x0, x1, STEP) + STEP / 2, np.arange(y0, y1, STEP) + STEP / 2)
    return np.column_stack([x.ravel(), y.ravel(), z + rng.normal(0, 0.005, x.size)])


def room(rng, north_top: float, cabinet_top: float = 1.45):
    """A 5 m x 4 m room without a ceiling, its walls seen up to 2 m but the north wall only up to
    `north_top`; against the east wall a cabinet 0.45 m deep and 1.2 m wide, `cabinet_top` high, its top
    surface seen. Returns the levelled cloud (floor at 0)."""
    return np.concatenate(
        [
            face((0, 0), (5, 0), 0, 2.0, rng),
            face((5, 0), (5, 4), 0, 2.0, rng),
            face((5, 4), (0, 4), 0, north_top, rng),
            face((0, 4), (0, 0), 0, 2.0, rng),
            face((4.55, 1.0), (4.55, 2.2), 0, cabinet_top, rng),  # its front
            face((4.55, 1.0), (5.0, 1.0), 0, cabinet_top, rng),  # its sides
            face((4.55, 2.2), (5.0, 2.2), 0, cabinet_top, rng),
            top_surface(4.55, 5.0, 1.0, 2.2, cabinet_top, rng),
        ]
    )


def the_slice(levelled, lo=1.5, hi=2.0):
    return levelled[(levelled[:, 2] >= lo) & (levelled[:, 2] <= hi)]


def test_a_wall_seen_only_to_1_35_m_is_draped_into_the_slice_and_the_room_closes(rng):
    """The slice is the highest half metre under the top of the data (1.5-2 m): the north wall, seen up
    to 1.35 m, is not in it at all. Draped, it closes the room; without that the room stays open."""
    levelled = room(rng, north_top=1.35)
    slice_points = the_slice(levelled)
    off, _ = room_model(slice_points, levelled, 0.0, 2.0, replace(CFG, low_top_min_m=0))
    assert evaluate_walls(off.walls, TRUTH)["completeness"] < 0.85
    model, choices = room_model(slice_points, levelled, 0.0, 2.0, CFG)
    ev = evaluate_walls(model.walls, TRUTH)
    assert model.closed and ev["completeness"] >= 0.97 and ev["correctness"] >= 0.99, ev
    assert 1.3 <= choices["low_top_heights_m"][1] <= 1.36, choices


def test_the_draped_columns_are_the_wall_s_not_the_cabinet_s_whose_top_is_a_surface(rng):
    """The cabinet's top (1.45 m, under the slice too) is a surface 0.45 m deep: its columns stay out,
    while the north wall's columns are moved up by their shortfall, 0.65 m, into the slice's band."""
    levelled = room(rng, north_top=1.35)
    slice_points = the_slice(levelled)
    out, found = low_topped_walls(levelled, slice_points, 0.0, 2.0, CFG, STEP)
    added = out[len(slice_points) - found["low_top_slice_points_replaced"] :]
    assert found["low_top_columns"] > 0 and found["low_top_surfaces"] > 0, found
    assert np.all(np.abs(added[:, 1] - 4.0) < 0.1), "only the north wall's columns are draped"
    assert added[:, 2].min() >= 1.5 - 0.05 and added[:, 2].max() <= 2.0 + 1e-9
    assert added[:, 0].max() - added[:, 0].min() > 4.5  # along the whole wall


def test_nothing_is_draped_under_a_ceiling_nor_below_the_lowest_wall_top(rng):
    """With a ceiling above the slice every wall reaches it (a low top is furniture's), and a column that
    stops under `low_top_min_m` (a counter's or a sideboard's front, 0.95 m) is no wall's seen part way up."""
    levelled = room(rng, north_top=1.35)
    slice_points = the_slice(levelled)
    out, found = low_topped_walls(levelled, slice_points, 0.0, 2.6, CFG, STEP)
    assert found == {"low_top_columns": 0} and out is slice_points
    low = room(rng, north_top=0.95)
    out, found = low_topped_walls(low, the_slice(low), 0.0, 2.0, CFG, STEP)
    assert found.get("low_top_columns", 0) == 0 and len(out) == len(the_slice(low))


def rim(centre, radius, z0, z1, arc_deg, rng):
    """An open cylinder's face (a plant's leaves) about `centre`, seen over `arc_deg` facing -y."""
    a = np.deg2rad(np.arange(-90 - arc_deg / 2, -90 + arc_deg / 2, np.rad2deg(STEP / radius)))
    z = np.arange(z0, z1, STEP) + STEP / 2
    aa, zz = np.meshgrid(a, z)
    r = radius + rng.normal(0, 0.005, aa.size)
    return np.column_stack(
        [centre[0] + r * np.cos(aa.ravel()), centre[1] + r * np.sin(aa.ravel()), zz.ravel()]
    )


def test_a_plant_s_rim_is_an_edge_but_not_a_straight_one_and_stays_out(rng):
    """A plant 1.3 m high (an open cylinder of 0.25 m radius, no top surface) by the north wall, seen over
    half its round or a third of it: its columns end in an edge, curved, and are not draped; the north
    wall, seen to 1.35 m, still is."""
    for arc in (180.0, 100.0):
        levelled = np.concatenate([room(rng, north_top=1.35), rim((2.5, 3.55), 0.25, 0.4, 1.3, arc, rng)])
        slice_points = the_slice(levelled)
        out, found = low_topped_walls(levelled, slice_points, 0.0, 2.0, CFG, STEP)
        added = out[len(slice_points) - found["low_top_slice_points_replaced"] :]
        assert found["low_top_columns"] > 0, found
        assert np.all(np.abs(added[:, 1] - 4.0) < 0.1), (arc, found)


def test_a_slice_capped_under_walls_seen_higher_is_no_ceiling_when_preprocess_found_none(rng):
    """Walls seen up to 2.7 m but the slice capped at 2.5 m (`slice_max_m`): its top lies 0.2 m under the
    top of the data, as under a ceiling. Preprocess's verdict (no ceiling captured) decides: the north
    wall, seen to 1.35 m, is draped; judged from the slice alone it would not be."""
    levelled = np.concatenate(
        [
            face((0, 0), (5, 0), 0, 2.7, rng),
            face((5, 0), (5, 4), 0, 2.7, rng),
            face((5, 4), (0, 4), 0, 1.35, rng),
            face((0, 4), (0, 0), 0, 2.7, rng),
        ]
    )
    slice_points = the_slice(levelled, 1.5, 2.5)
    _, found = low_topped_walls(levelled, slice_points, 0.0, 2.7, CFG, STEP)
    assert found == {"low_top_columns": 0}
    _, found = low_topped_walls(levelled, slice_points, 0.0, 2.7, CFG, STEP, ceiling_captured=False)
    assert found["low_top_columns"] > 0 and 1.3 <= found["low_top_heights_m"][1] <= 1.36, found
    model, _ = room_model(slice_points, levelled, 0.0, 2.7, CFG, ceiling_captured=False)
    ev = evaluate_walls(model.walls, TRUTH)
    assert model.closed and ev["completeness"] >= 0.97 and ev["correctness"] >= 0.99, ev
