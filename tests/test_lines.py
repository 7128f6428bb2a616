"""Known-answer tests of the shared 2D line geometry (thesis 5.2.4-5.2.5)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tasks.connect import EXTENDED, OBSERVED, connect, connect_detailed
from tasks.lines import (
    LinesConfig,
    angles,
    explained_variance,
    fit_line,
    is_closed,
    lengths,
    merge_segments,
    point_segment_distances,
    regularize,
    room_polygons,
    rotate_segments,
    sample_segments,
    transform_segments,
    wall_graph,
)

CFG = LinesConfig()


def pieces_along(a, b, n, rng, noise=0.004, margin=0.02):
    """n short noisy Hough-like pieces covering the segment a-b, as a Hough transform returns them."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    out = []
    for k in range(n):
        t0, t1 = k / n + margin, (k + 1) / n - margin
        p = a + (b - a) * t0 + rng.normal(0, noise, 2)
        q = a + (b - a) * t1 + rng.normal(0, noise, 2)
        out.append([*p, *q])
    return out


def polygon_walls(corners):
    c = np.asarray(corners, float)
    return np.concatenate([c, np.roll(c, -1, axis=0)], axis=1)


def test_box_gives_four_walls(rng):
    box = polygon_walls([(0, 0), (4, 0), (4, 3), (0, 3)])
    hough = np.array([p for s in box for p in pieces_along(s[:2], s[2:], 6, rng)])
    merged = merge_segments(hough, CFG)
    assert len(merged.segments) == 4
    assert len(merged.orientation_deg) == 2
    reg, _ = regularize(merged.segments, CFG)
    walls, origin = connect(reg, CFG)
    assert len(walls) == 4 and set(origin) == {OBSERVED}
    # every true wall has one model wall within 1 cm at both ends
    for s in box:
        d = point_segment_distances(np.array([s[:2], s[2:]]), walls)
        assert d.min(axis=1).max() < 0.01
    g = wall_graph(walls)
    assert g.number_of_nodes() == 4 and g.number_of_edges() == 4 and is_closed(g)
    assert room_polygons(walls)[0].area == pytest.approx(12.0, rel=0.01)


def test_two_collinear_pieces_with_a_03_m_gap_give_one_wall():
    pieces = np.array([[0.0, 1.0, 2.0, 1.0], [2.3, 1.0, 4.0, 1.0]])
    merged = merge_segments(pieces, CFG)
    assert merged.segments.shape == (1, 4)
    assert lengths(merged.segments)[0] == pytest.approx(4.0)
    assert list(merged.labels) == [0, 0]
    # a gap wider than max_gap_m (a door) stays two walls
    far = np.array([[0.0, 1.0, 2.0, 1.0], [2.9, 1.0, 4.0, 1.0]])
    assert len(merge_segments(far, CFG).segments) == 2


def jog_pieces(step, rng, noise=0.003):
    """A 10 m wall of Hough-like pieces on a 1 cm grid whose second half lies `step` m further out (a jog
    where two rooms' walls meet), the two halves 0.5 m apart along the line (a door at the jog)."""
    left = pieces_along((0.0, 0.0), (4.75, 0.0), 5, rng, noise)
    right = pieces_along((5.25, step), (10.0, step), 5, rng, noise)
    return np.round(np.array(left + right), 2)  # pixel-rounded ends, as a Hough transform gives them


@pytest.mark.parametrize("step", [0.03, 0.045, 0.075])
def test_a_jog_of_a_few_cm_between_pieces_that_do_not_overlap_is_two_walls_and_a_step(rng, step):
    hough = jog_pieces(step, rng)
    if step < CFG.offset_tol_m:
        assert len(merge_segments(hough, CFG).segments) == 1  # plain offset clustering: one slanted wall
    merged = merge_segments(hough, CFG, quantum=0.01)
    assert len(merged.segments) == 2
    offs = sorted(float(s[1] + s[3]) / 2 for s in merged.segments)
    assert offs[0] == pytest.approx(0.0, abs=0.004) and offs[1] == pytest.approx(step, abs=0.004)
    if step < CFG.offset_tol_m:
        assert merged.chain[0] == merged.chain[1]  # one chain of pieces, split at its step
    walls = connect_detailed(regularize(merged.segments, CFG)[0], CFG, step_chain=merged.chain).segments
    steps = walls[lengths(walls) < 0.5]  # the connecting wall, across the line
    assert len(steps) == 1 and lengths(steps)[0] == pytest.approx(step, abs=0.004)
    assert abs(angles(steps)[0] - math.pi / 2) < math.radians(1.0)
    assert len(walls) == 3 and is_closed(wall_graph(walls)) is False  # a chain: two walls and the step


def test_a_jog_beside_a_doubled_face_far_off_is_still_two_walls_and_a_step(rng):
    # a 4 cm jog at x = 5; the first wall's far half (x < 2.5) holds its face twice, 4.5 cm apart (a drifting
    # registration): its spread about one line hides the jog from the whole sides, not from the 2 m beside it
    near = pieces_along((2.5, 0.0), (4.75, 0.0), 3, rng, 0.002)
    far = pieces_along((0.0, 0.0), (2.5, 0.0), 3, rng, 0.002) + pieces_along(
        (0.1, -0.045), (2.4, -0.045), 3, rng, 0.002
    )
    right = pieces_along((5.25, 0.04), (10.0, 0.04), 5, rng, 0.002)
    hough = np.round(np.array(far + near + right), 2)
    assert len(merge_segments(hough, replace(CFG, step_window_m=None), quantum=0.01).segments) == 1
    merged = merge_segments(hough, CFG, quantum=0.01)
    assert len(merged.segments) == 2 and merged.chain[0] == merged.chain[1], merged.segments
    second = merged.segments[np.argmax(merged.segments[:, [0, 2]].max(axis=1))]
    assert 0.5 * (second[1] + second[3]) == pytest.approx(0.04, abs=0.004)
    assert min(second[0], second[2]) == pytest.approx(5.25 + 0.02 * 4.75, abs=0.03)


def test_a_wall_whose_pieces_drift_a_cell_at_a_time_gets_no_step(rng):
    # a wall seen in pieces that creep outward a cell (1 cm) every 0.6 m (a slow registration drift) and
    # one long piece two cells off at the end: no step of a few cells stands out of that, whatever window
    ramp = [[0.6 * k + 0.01, 0.01 * k, 0.6 * (k + 1) - 0.01, 0.01 * k] for k in range(6)]
    hough = np.array([*ramp, [3.62, 0.07, 8.0, 0.07]])
    merged = merge_segments(hough, CFG, quantum=0.01)
    assert len(merged.segments) <= 2, merged.segments
    # two pieces of one wall two cells apart with no spread each: the skeleton's rounding, not a step
    two = np.array([[0.0, 0.0, 4.0, 0.0], [4.1, 0.02, 9.0, 0.02]])
    assert len(merge_segments(two, CFG, quantum=0.01).segments) == 1


def test_parallel_walls_overlapping_past_their_step_get_one_step():
    # two walls 3.5 cm apart whose data each ran 7.5 cm on into the step's corner (15 cm overlap)
    walls = np.array([[0.0, 0.0, 5.075, 0.0], [4.925, 0.035, 10.0, 0.035]])
    out = connect_detailed(walls, CFG, step_chain=np.array([0, 0])).segments
    steps = out[lengths(out) < 0.5]
    assert len(steps) == 1 and lengths(steps)[0] == pytest.approx(0.035)
    assert len(out) == 3 and lengths(out).sum() == pytest.approx(10.0 + 0.035)  # no overlap left


def test_collinear_pieces_either_side_of_a_door_a_little_apart_get_no_step(rng):
    # one straight wall seen either side of a 0.9 m door (wider than max_gap_m), its two pieces 1.2 cm apart
    # (registration noise): two chains, as nothing joined them into one
    left = pieces_along((0.0, 0.0), (3.0, 0.0), 4, rng, 0.002)
    right = pieces_along((3.9, 0.012), (8.0, 0.012), 5, rng, 0.002)
    merged = merge_segments(np.round(np.array(left + right), 2), CFG, quantum=0.01)
    assert len(merged.segments) == 2 and merged.chain[0] != merged.chain[1]
    # later the data carried their ends 0.3 m nearer: connect must not invent a 1.2 cm step between them,
    # nothing showed one; the same two walls found as the two sides of one chain's step are joined by it
    walls = np.array([[0.0, 0.0, 3.15, 0.0], [3.75, 0.012, 8.0, 0.012]])
    out = connect_detailed(walls, CFG, step_chain=np.array([0, 1])).segments
    assert len(out) == 2 and np.allclose(out, walls)
    out = connect_detailed(walls, CFG, step_chain=np.array([3, 3])).segments
    assert len(out) == 3 and lengths(out).min() == pytest.approx(0.012)


def test_noisy_collinear_pieces_without_a_step_stay_one_wall(rng):
    for _ in range(20):
        merged = merge_segments(jog_pieces(0.0, rng, noise=0.004), CFG, quantum=0.01)
        assert len(merged.segments) == 1


def test_a_jog_whose_pieces_overshoot_its_corner_by_a_few_cm_is_still_two_walls():
    # a corridor's wall with a 4 cm jog (719's hallway): the skeleton's pieces on either side each run a few
    # cm past the jog (6 cm of overlap, more than the step itself), as a Hough segment's end does
    hough = np.array([[1.96, 0.0, 10.52, 0.0], [10.46, -0.04, 15.89, -0.04], [15.9, -0.05, 17.49, -0.05]])
    merged = merge_segments(hough, CFG, quantum=0.01)
    assert len(merged.segments) == 2 and merged.chain[0] == merged.chain[1]


def test_overlapping_parallel_pieces_a_few_cm_apart_stay_one_wall():
    # two skeleton branches of one thick wall, 3 cm apart, overlapping along the line
    hough = np.array([[0.0, 0.0, 6.0, 0.0], [4.0, 0.03, 10.0, 0.03]])
    assert len(merge_segments(hough, CFG, quantum=0.01).segments) == 1


def test_885_degrees_becomes_90():
    a = math.radians(88.5)
    segs = np.array([[0, 0, 4, 0], [0, 0, 3 * math.cos(a), 3 * math.sin(a)]], dtype=float)
    out, rot = regularize(segs, CFG)
    th = np.degrees(angles(out))
    diff = abs(th[1] - th[0])
    assert diff == pytest.approx(90.0, abs=1e-9)
    # eq 5.9 with lengths 4 and 3: the shorter wall turns more, the two turns add up to 1.5°
    assert np.degrees(abs(rot[0]) + abs(rot[1])) == pytest.approx(1.5, abs=1e-9)
    assert abs(rot[1]) > abs(rot[0])
    # undoing the rotation gives the input back
    np.testing.assert_allclose(rotate_segments(out, -rot), segs, atol=1e-12)


def test_70_degree_wall_stays_70():
    a = math.radians(70.0)
    segs = np.array(
        [
            [0, 0, 5, 0],
            [5, 0, 5, 3],
            [0, 3, 5, 3],
            [0, 0, 0, 0],  # replaced below
        ],
        dtype=float,
    )
    segs[3] = [0, 0, 3 / math.tan(a), 3]  # a wall at 70° from the x axis
    segs[1, 3] = 2.99  # 0.19° off vertical: snapped
    out, _ = regularize(segs, CFG)
    th = np.degrees(angles(out))
    assert th[3] == pytest.approx(70.0, abs=1e-6)
    assert th[0] == pytest.approx(0.0, abs=0.05) or th[0] == pytest.approx(180.0, abs=0.05)
    assert abs(th[1] - th[0]) % 180 == pytest.approx(90.0, abs=1e-9)


def test_over_extended_segment_without_data_is_removed():
    # a wall along y=0, a wall along x=4, and a stub at x=3 that ends 0.3 m above the first wall
    segs = np.array([[0, 0, 4, 0], [4, 0, 4, 3], [3, 0.3, 3, 2]], dtype=float)
    data = segs.copy()  # the data is exactly the observed walls: nothing between y=0 and y=0.3 at x=3

    def support(pieces, parent):
        pts, owner = sample_segments(pieces, 0.01)
        near = point_segment_distances(pts, data).min(axis=1) < 0.02
        return np.bincount(owner, near, len(pieces)) / np.bincount(owner, minlength=len(pieces))

    extended, _origin = connect(segs, CFG)
    assert any(np.allclose(s, [3, 0, 3, 2]) or np.allclose(s, [3, 2, 3, 0]) for s in extended)
    res = connect_detailed(segs, CFG, support)
    stub = res.segments[res.parent == 2]
    assert len(stub) == 1 and min(stub[0, 1], stub[0, 3]) == pytest.approx(0.3)
    assert len(res.removed) == 1 and lengths(res.removed)[0] == pytest.approx(0.3)
    assert set(res.origin) == {OBSERVED}


def test_a_partition_whose_root_was_not_seen_still_stands_on_its_wall():
    """A partition stub 0.1 m thick stands on the west wall (x = 0). The wall's span between the stub's two
    faces has no data (it is inside the partition), nor has the north face's first 0.3 m (hidden from the
    camera). The span goes and the face reaches the wall: the pieces meeting at one node are judged one at
    a time, so the face's root closes a corner once the span is gone."""
    west = [0.0, 0.0, 0.0, 4.0]
    south_face = [0.0, 2.0, 1.5, 2.0]
    north_face = [0.3, 2.1, 1.5, 2.1]
    end = [1.5, 2.0, 1.5, 2.1]
    segs = np.array([west, south_face, north_face, end])
    data = np.array([[0.0, 0.0, 0.0, 2.0], [0.0, 2.1, 0.0, 4.0], south_face, north_face, end])

    def support(pieces, parent):
        pts, owner = sample_segments(pieces, 0.01)
        near = point_segment_distances(pts, data).min(axis=1) < 0.005
        return np.bincount(owner, near, len(pieces)) / np.bincount(owner, minlength=len(pieces))

    res = connect_detailed(segs, CFG, support)
    north = res.segments[res.parent == 2]
    assert len(north) == 1 and min(north[0, 0], north[0, 2]) == pytest.approx(0.0, abs=1e-9)
    assert len(res.removed) == 1 and res.removed[0, [0, 2]] == pytest.approx([0.0, 0.0])
    assert lengths(res.removed)[0] == pytest.approx(0.1)


def test_a_wall_is_not_trimmed_back_to_a_partition_standing_on_it():
    """The west wall's data runs 0.6 m past a partition's face that ends on it (a T-junction): with
    `trim_m` 0.3 the wall keeps that length, while its 0.1 m overshoot past the south corner is cut; with
    the thesis' trimming (as far as it extends) the 0.6 m go too."""
    segs = np.array([[0.0, -0.1, 0.0, 2.6], [0.0, 0.0, 3.0, 0.0], [0.0, 2.0, 1.5, 2.0]])
    walls, _ = connect(segs, replace(CFG, trim_m=0.3))
    west = walls[np.abs(walls[:, 0] - walls[:, 2]) < 1e-9]
    assert [west[:, [1, 3]].min(), west[:, [1, 3]].max()] == pytest.approx([0.0, 2.6])
    thesis, _ = connect(segs, CFG)
    west = thesis[np.abs(thesis[:, 0] - thesis[:, 2]) < 1e-9]
    assert max(west[:, [1, 3]].max(axis=1)) == pytest.approx(2.0)


def test_an_acute_corner_seen_short_of_both_walls_closes_at_their_intersection():
    """A 70° corner at (5, 0): the north wall's data stops 1.0 m short of it, the slanted wall's 0.27 m. No
    perpendicular join is made onto the oblique wall (it would be a wall at neither direction); with a
    reach of 1.2 m both walls are extended to the corner."""
    d = np.array([math.cos(math.radians(250)), math.sin(math.radians(250))])
    corner = np.array([5.0, 0.0])
    segs = np.array([[0.0, 0.0, 4.0, 0.0], [*(corner + 0.27 * d), *(corner + 4.0 * d)]])
    walls, origin = connect(segs, CFG)
    assert len(walls) == 2 and set(origin) == {OBSERVED}
    walls, _ = connect(segs, replace(CFG, extend_m=1.2))
    ends = walls.reshape(-1, 2)
    assert (np.hypot(*(ends - corner).T) < 1e-9).sum() == 2


def test_extension_trimming_and_perpendicular_join():
    # corner gap of 0.2 m, an overshoot of 0.1 m, and a step between two parallel walls 0.25 m apart
    segs = np.array(
        [
            [0.0, 0.0, 3.8, 0.0],  # bottom, 0.2 short of the right wall
            [4.0, -0.1, 4.0, 3.0],  # right wall overshooting the bottom by 0.1
            [4.0, 3.0, 2.0, 3.0],  # top right part
            [1.9, 3.25, 0.0, 3.25],  # top left part, stepped 0.25 m out, 0.1 m gap along x
            [0.0, 3.25, 0.0, 0.0],  # left
        ]
    )
    walls, origin = connect(segs, CFG)
    g = wall_graph(walls)
    assert is_closed(g)
    assert EXTENDED in set(origin)  # the step joining the two top parts is new
    poly = room_polygons(walls)[0]
    assert poly.area == pytest.approx(4 * 3 + 2 * 0.25, abs=0.03)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_the_join_across_an_unseen_alcove_side_goes_at_the_room_side_end(order):
    """An alcove 0.6 m deep whose west side was not seen: the room's south wall runs up to the alcove's
    mouth at x = 2.0 (a reflex corner, seen from anywhere in the room), the alcove's back wall only from
    x = 2.3 (hidden from the room behind the unseen side). With the room's interior given, the join goes
    at x = 2.0 whatever the input order; without it, at the end taken first."""
    south = [0.0, 0.0, 2.0, 0.0]
    back = [2.3, -0.6, 3.5, -0.6]
    segs = np.array([[south, back][k] for k in order])
    walls, origin = connect(segs, CFG, interior_xy=np.array([1.5, 2.0]))
    join = walls[origin == EXTENDED]
    assert len(join) == 1
    assert join[0, [0, 2]] == pytest.approx([2.0, 2.0], abs=1e-9)
    assert sorted(np.round(np.abs(join[0, [1, 3]]), 9)) == pytest.approx([0.0, 0.6])
    plain, plain_origin = connect(segs, CFG)
    assert plain[plain_origin == EXTENDED][0, 0] == pytest.approx(2.3)


def test_the_join_across_an_alcove_side_goes_where_its_few_points_are():
    """The alcove of the test above, with 0.25 m of its west side (x = 2.3) seen at the back: the join goes
    there, and the south wall is extended to it; with no point of the side, at the room side's end."""
    south = [0.0, 0.0, 2.0, 0.0]
    back = [2.3, -0.6, 3.5, -0.6]
    segs = np.array([south, back])
    for side, x_join in (([2.3, -0.6, 2.3, -0.35], 2.3), (None, 2.0)):
        data = np.array([s for s in (south, back, side) if s is not None])

        def support(pieces, parent, data=data):
            pts, owner = sample_segments(pieces, 0.01)
            near = point_segment_distances(pts, data).min(axis=1) < 0.02
            return np.bincount(owner, near, len(pieces)) / np.bincount(owner, minlength=len(pieces))

        walls, origin = connect(segs, CFG, support, interior_xy=np.array([1.5, 2.0]))
        join = walls[origin == EXTENDED]
        assert len(join) == 1 and join[0, [0, 2]] == pytest.approx([x_join, x_join], abs=0.01)
        assert len(walls) == 3 and is_closed(wall_graph(np.vstack([walls, [[0, 0, 3.5, -0.6]]])))


def test_a_step_s_join_stays_at_the_interior_side_wall_s_end_whatever_the_support():
    """A corridor's wall with a 6.5 cm step (more than `offset_tol`): the recessed stretch (y = 0.065, away from
    the interior) seen up to x = 2.0, the protruding one (y = 0) from x = 2.3: the step's shadow along the wall
    hides the recessed stretch beside it. The join stays at x = 2.3, the protruding wall's end (a convex
    corner), though the support (the walls' data within 5 cm) is as high anywhere along the gap: a join this
    short lies near one wall's data or the other's all along. An alcove's 0.6 m side still goes where its
    points are (the test above)."""
    recessed = [0.0, 0.065, 2.0, 0.065]
    protruding = [2.3, 0.0, 5.0, 0.0]
    segs = np.array([recessed, protruding])

    def support(pieces, parent):
        pts, owner = sample_segments(pieces, 0.005)
        near = point_segment_distances(pts, segs).min(axis=1) < 0.05
        # the recessed wall's data denser: a join at its end would be held best if that were asked
        dense = point_segment_distances(pts, segs[:1]).min(axis=1) < 0.05
        return (np.bincount(owner, near, len(pieces)) + 0.2 * np.bincount(owner, dense, len(pieces))) / (
            np.bincount(owner, minlength=len(pieces))
        )

    walls, origin = connect(segs, CFG, support, interior_xy=np.array([2.5, -1.0]))
    join = walls[origin == EXTENDED]
    assert len(join) == 1 and join[0, [0, 2]] == pytest.approx([2.3, 2.3], abs=1e-9)


def test_explained_variance_elbow_finds_three_directions(rng):
    th = np.concatenate(
        [rng.normal(0, 0.01, 20), rng.normal(np.pi / 2, 0.01, 20), rng.normal(1.2217, 0.01, 5)]
    )
    x = np.column_stack([np.cos(2 * th), np.sin(2 * th)])
    assert explained_variance(x, np.zeros(len(th), int)) == pytest.approx(0.0, abs=0.05)
    segs = np.column_stack([np.zeros_like(th), np.zeros_like(th), np.cos(th), np.sin(th)])
    merged = merge_segments(segs, CFG)
    assert sorted(np.round(merged.orientation_deg).astype(int)) == [0, 70, 90]
    assert merged.explained_variance[-1] >= CFG.explained_variance
    assert merged.explained_variance[1] < CFG.explained_variance


def test_fit_line_is_length_weighted_regression():
    segs = np.array([[0, 0, 2, 0], [2.5, 0.02, 4, 0.02]])
    line = fit_line(segs)[0]
    assert line[0] == pytest.approx(0, abs=1e-3) and line[2] == pytest.approx(4, abs=1e-3)
    # the offset is the length-weighted mean of the pieces' offsets
    assert 0.5 * (line[1] + line[3]) == pytest.approx(0.02 * 1.5 / 3.5, abs=2e-3)


def test_pixels_and_metres_give_the_same_walls(rng):
    box = polygon_walls([(0, 0), (4, 0), (4, 3), (0, 3)])
    hough = np.array([p for s in box for p in pieces_along(s[:2], s[2:], 4, rng)])
    walls_m, _ = connect(regularize(merge_segments(hough, CFG).segments, CFG)[0], CFG)
    px = 100.0
    cfg_px = CFG.scaled(px)
    assert cfg_px.max_gap_m == pytest.approx(100 * CFG.max_gap_m)
    walls_px, _ = connect(regularize(merge_segments(hough * px, cfg_px).segments, cfg_px)[0], cfg_px)
    np.testing.assert_allclose(np.sort(walls_px / px, axis=0), np.sort(walls_m, axis=0), atol=1e-6)


def test_rigid_transform_round_trip(rng):
    segs = rng.uniform(-5, 5, (6, 4))
    moved = transform_segments(segs, 0.3, [1.0, -2.0])
    c, s = math.cos(-0.3), math.sin(-0.3)
    back = transform_segments(moved - [1.0, -2.0, 1.0, -2.0], np.array([[c, -s], [s, c]]), [0, 0])
    np.testing.assert_allclose(back, segs, atol=1e-12)


def test_empty_and_degenerate_inputs():
    assert merge_segments(np.zeros((0, 4)), CFG).segments.shape == (0, 4)
    assert merge_segments(np.array([[1, 1, 1, 1.0]]), CFG).segments.shape == (0, 4)
    out, rot = regularize(np.zeros((0, 4)), CFG)
    assert out.shape == (0, 4) and rot.shape == (0,)
    walls, origin = connect(np.zeros((0, 4)), CFG)
    assert walls.shape == (0, 4) and len(origin) == 0
    assert wall_graph(np.zeros((0, 4))).number_of_edges() == 0
    assert room_polygons(np.zeros((0, 4))) == []
    single = np.array([[0, 0, 1, 0.0]])
    assert len(merge_segments(single, CFG).segments) == 1
    assert connect(single, CFG)[0].shape == (1, 4)


def test_the_two_sides_of_a_step_do_not_run_on_over_each_other_to_a_corner():
    # a wall seen in two pieces 3.5 cm apart (a step), the later one ending 0.75 m from the west wall:
    # extending it to that corner would run it along the earlier piece, and the outline double back
    walls = np.array(
        [
            [0.0, -3.0, 0.0, 0.0],  # west wall
            [0.1, 0.035, 0.9, 0.035],  # the step's earlier side
            [0.75, 0.0, 2.5, 0.0],  # its later side, overlapping the earlier one by 0.15 m
            [2.5, 0.0, 2.5, -3.0],  # east wall
        ]
    )
    out = connect_detailed(walls, CFG, step_chain=np.array([0, 1, 1, 2])).segments
    along = out[np.abs(out[:, 1] - out[:, 3]) < 1e-9]  # the pieces along x
    # together they cover the wall once (2.5 m), with no piece lying over another
    assert lengths(along).sum() == pytest.approx(2.5, abs=0.01), out
    # on different chains (no step seen between them) the later one still may not run along the earlier
    out = connect_detailed(walls, CFG, step_chain=np.array([0, 1, 2, 3])).segments
    along = out[np.abs(out[:, 1] - out[:, 3]) < 1e-9]
    assert lengths(along).sum() <= 2.5 + 0.15 + 1e-6, out


def test_the_data_do_not_carry_a_step_s_side_over_the_other():
    from tasks.walls.topology import stop_at_steps

    before = np.array([[2.73, 0.0, 3.15, 0.0], [1.89, 0.035, 2.79, 0.035], [0.0, 1.0, 0.0, 2.0]])
    after = np.array([[2.07, 0.0, 3.19, 0.0], [1.88, 0.035, 3.17, 0.035], [0.0, 0.9, 0.0, 2.1]])
    out = stop_at_steps(before, after, np.array([4, 4, 5]))
    # each side runs on outward, not past where the other side began; another chain's line is untouched
    assert np.allclose(out, [[2.73, 0.0, 3.19, 0.0], [1.88, 0.035, 2.79, 0.035], [0.0, 0.9, 0.0, 2.1]])
