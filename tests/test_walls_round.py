"""Round things in the slice (`round.round_objects`): a plant's pot standing by a wall is found and its points
go; a corner's or an alcove's noisy walls, which a circle can thread, are no round thing; and in a room cut
low without a ceiling the pot's facets no longer make walls."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tasks.evaluate import evaluate_walls
from tasks.walls.config import WallsConfig
from tasks.walls.round import MAX_OUTSIDE_SHARE, _outside_share, _walled_in, round_objects
from tests.scenes import wall_points

CFG = WallsConfig()
GRID = 0.015


def _pot(
    centre: tuple[float, float],
    radius: float,
    z0: float,
    z1: float,
    rng: np.random.Generator,
    seen_deg: tuple,
) -> np.ndarray:
    """A plant's pot as the survey generator builds it: a decagon `radius` across its corners, z0..z1, its
    facets' points seen from `seen_deg[0]` to `seen_deg[1]` (degrees about its centre, less than 360 apart)."""
    k = np.radians(np.arange(11) * 36.0)
    ring = np.column_stack([centre[0] + radius * np.cos(k), centre[1] + radius * np.sin(k)])
    faces = [wall_points(ring[i], ring[i + 1], z0, z1, rng, step=0.02, noise=0.008) for i in range(10)]
    pts = np.concatenate(faces)
    ang = np.degrees(np.arctan2(pts[:, 1] - centre[1], pts[:, 0] - centre[0]))
    lo, hi = seen_deg
    return pts[(ang - lo) % 360 <= hi - lo]


def test_a_pot_by_a_wall_is_round_and_its_points_go(rng):
    wall = wall_points((0, 0), (3, 0), 0.8, 1.3, rng, step=0.02, noise=0.008)
    # a pot 0.3 m in radius, 5 cm from the wall, seen from the room over 200 degrees
    pot = _pot((1.5, 0.35), 0.3, 0.8, 1.3, rng, seen_deg=(-10.0, 190.0))
    xy = np.concatenate([wall, pot])[:, :2]
    on, things = round_objects(xy, GRID, CFG)
    assert len(things) == 1, things
    (t,) = things
    assert (
        math.hypot(t["centre"][0] - 1.5, t["centre"][1] - 0.35) < 0.03 and abs(t["radius_m"] - 0.29) < 0.03
    ), t
    assert t["arc_deg"] >= 150 and t["circle_share"] - t["lines_share"] >= CFG.round_margin
    assert on[len(wall) :].mean() > 0.95
    # the wall keeps its points, but for those where the pot's round nearly touches it
    assert on[: len(wall)].mean() < 0.05
    assert not on[: len(wall)][np.abs(wall[:, 0] - 1.5) > 0.25].any()
    # switched off by a radius of 0
    off, none = round_objects(xy, GRID, replace(CFG, round_radius_m=(0.0, 0.0)))
    assert not off.any() and none == []


def test_a_pot_seen_over_a_quarter_of_its_round_is_round_and_a_box_s_corner_is_not(rng):
    # a handheld pass shows a pot by a wall over 100 degrees only: its facets (0.19 m, shorter than its
    # radius) are no box's faces, which three lines would explain as well as its round
    wall = wall_points((0, 0), (3, 0), 0.8, 1.3, rng, step=0.03, noise=0.008)
    pot = _pot((1.5, 0.35), 0.3, 0.8, 1.3, rng, seen_deg=(40.0, 140.0))
    # a cabinet's corner, its two 0.5 m faces seen, and a corner seen over 0.4 m of each wall
    box = np.concatenate(
        [
            wall_points((4.0, 0.5), (4.5, 0.5), 0.8, 1.3, rng, step=0.03, noise=0.008),
            wall_points((4.5, 0.5), (4.5, 0.0), 0.8, 1.3, rng, step=0.03, noise=0.008),
            wall_points((6.0, 0.0), (6.4, 0.0), 0.8, 1.3, rng, step=0.03, noise=0.008),
            wall_points((6.0, 0.0), (6.0, 0.4), 0.8, 1.3, rng, step=0.03, noise=0.008),
        ]
    )
    xy = np.concatenate([wall, pot, box])[:, :2]
    on, things = round_objects(xy, GRID, CFG)
    assert len(things) == 1 and math.hypot(things[0]["centre"][0] - 1.5, things[0]["centre"][1] - 0.35) < 0.05
    assert things[0]["arc_deg"] < 120 and things[0]["circle_share"] > things[0]["lines_share"], things
    assert on[len(wall) : len(wall) + len(pot)].mean() > 0.95 and not on[len(wall) + len(pot) :].any()


def test_no_round_thing_stands_where_walls_cut_its_circle():
    r = 0.45
    # a wall it stands by, touching it or a few cm into its round (a pot's leaves against the wall)
    assert not _walled_in(np.array([[0.0, 0.45]]), r) and not _walled_in(np.array([[0.0, 0.40]]), r)
    # one through its middle half, or two on opposite sides (an alcove 0.8 m wide round a pot in it)
    assert _walled_in(np.array([[0.2, 0.0]]), r)
    assert _walled_in(np.array([[-0.41, 0.0], [0.40, 0.0]]), r)
    # two at a corner it stands in are no alcove; nor is a wall across the room beyond its round
    assert not _walled_in(np.array([[0.40, 0.0], [0.0, 0.40]]), r)
    assert not _walled_in(np.array([[-0.41, 0.0], [0.60, 0.0]]), r)
    assert not _walled_in(np.zeros((0, 2)), r)


def test_a_wall_s_noisy_band_shows_points_just_outside_a_circle_threading_it_and_a_pot_none(rng):
    # the back of an alcove seen from 5 m off (a clean held-out room's): its points spread by 3.8 cm across it,
    # and a circle of 0.31 m laid on it, tangent to the wall's line
    back = wall_points((-0.4, 0.0), (0.4, 0.0), 1.5, 2.5, rng, step=0.025, noise=0.038)[:, :2]
    centre = np.array([0.0, 0.31])
    assert _outside_share(back - centre, 0.31, 0.01) > 2 * MAX_OUTSIDE_SHARE
    # a pot's facets seen from the room over 200 degrees, as noisy as the walls of the tests above
    pot = _pot((1.5, 0.35), 0.3, 0.8, 1.3, rng, seen_deg=(-10.0, 190.0))[:, :2]
    assert _outside_share(pot - (1.5, 0.35), 0.29, GRID) < 0.2 * MAX_OUTSIDE_SHARE
    # nothing on the circle: nothing to compare
    assert _outside_share(np.array([[1.0, 0.0]]), 0.29, GRID) == 0.0


def test_a_pot_across_the_transform_s_tiles_is_found_as_in_one(rng, monkeypatch):
    import tasks.walls.round as round_module

    wall = wall_points((0, 0), (3, 0), 0.8, 1.3, rng, step=0.02, noise=0.008)
    pot = _pot((1.5, 0.35), 0.3, 0.8, 1.3, rng, seen_deg=(-10.0, 190.0))
    xy = np.concatenate([wall, pot])[:, :2]
    whole = round_objects(xy, GRID, CFG)
    # tiles of 1.2 m (40 cells of 3 cm): the pot's centre lies 0.3 m from a tile's edge
    monkeypatch.setattr(round_module, "TILE_CELLS", 40)
    tiled = round_objects(xy, GRID, CFG)
    assert len(tiled[1]) == 1 and tiled[1] == whole[1] and (tiled[0] == whole[0]).all()


def test_a_noisy_corner_and_an_alcove_are_no_round_thing(rng):
    # a corner whose walls' points spread by 2.5 cm (a handheld scan's registration): a circle threads it
    corner = np.concatenate(
        [
            wall_points((0, 0), (2, 0), 1.0, 1.5, rng, step=0.02, noise=0.025),
            wall_points((0, 0), (0, 2), 1.0, 1.5, rng, step=0.02, noise=0.025),
        ]
    )
    # an alcove 0.5 m wide and 0.4 m deep: three sides a circle of 0.25 m touches
    alcove = np.concatenate(
        [
            wall_points((4, 0), (4, 0.4), 1.0, 1.5, rng, step=0.02, noise=0.008),
            wall_points((4, 0.4), (4.5, 0.4), 1.0, 1.5, rng, step=0.02, noise=0.008),
            wall_points((4.5, 0.4), (4.5, 0), 1.0, 1.5, rng, step=0.02, noise=0.008),
            wall_points((3, 0), (4, 0), 1.0, 1.5, rng, step=0.02, noise=0.008),
            wall_points((4.5, 0), (5.5, 0), 1.0, 1.5, rng, step=0.02, noise=0.008),
        ]
    )
    on, things = round_objects(np.concatenate([corner, alcove])[:, :2], GRID, CFG)
    assert things == [] and not on.any()


def test_a_room_cut_low_loses_no_wall_to_a_pot_and_draws_none_of_its_facets():
    from tasks.walls.model import model_walls

    rng = np.random.default_rng(0)
    cut = 1.3
    corners = [(0, 0), (5, 0), (5, 4), (0, 4)]
    truth = np.array([[*corners[i], *corners[(i + 1) % 4]] for i in range(4)], float)
    walls = [wall_points(t[:2], t[2:], 0.0, cut, rng, step=0.03, noise=0.008) for t in truth]
    # a pot 0.1 m from the west wall, seen from the room over 240 degrees, up to the cut like the walls
    pot = _pot((0.4, 2.0), 0.3, 0.4, cut, rng, seen_deg=(-120.0, 120.0))
    band = np.concatenate([*walls, pot])
    band = band[band[:, 2] >= cut - 0.5]
    model = model_walls(band, 0.0, cut, CFG)
    assert len(model.metrics["round_objects"]) == 1 and model.metrics["round_object_points"] > 0
    ev = evaluate_walls(model.walls, truth)
    assert model.closed and ev["correctness"] == 1.0 and ev["completeness"] > 0.99, (ev, model.walls)
    # the pot went before any line was drawn: without looking for round things its facets are lines, which
    # only the furniture rules take (a front along the wall, short ones standing alone before it)
    assert model.metrics["lines_furniture_no_ceiling"] == 0
    kept = model_walls(band, 0.0, cut, replace(CFG, round_radius_m=(0.0, 0.0)))
    assert kept.metrics["lines_furniture_no_ceiling"] >= 2
