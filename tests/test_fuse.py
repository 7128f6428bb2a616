"""Known answers for the fuse stage's pure parts: registration (eq 7.1-7.10, fig 7.4), correspondence,
thickness, gap filling and doors."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from tasks.fuse.config import FuseConfig
from tasks.fuse.correspond import PlanRoom, RoomEvidence, correspond_rooms, turning_distance
from tasks.fuse.gaps import GAP_FILLED, fill_gaps, shell_polygon
from tasks.fuse.openings import find_doors, span_state, wall_columns
from tasks.fuse.place import RoomInput, place_rooms
from tasks.fuse.register2d import (
    DoorPair,
    Faces,
    Placement,
    best_fit,
    centroid_start,
    collinear_faces,
    correspond,
    fine_register,
    inward_normals,
    optimal_fit,
    polygon_faces,
    shell_mask,
)
from tasks.fuse.thickness import PlacedWalls, both_sides_thickness, room_thickness_from_residuals

CFG = FuseConfig()


def ring_segments(poly: Polygon) -> np.ndarray:
    xy = np.asarray(poly.exterior.coords)
    return np.column_stack([xy[:-1], xy[1:]])


def to_room_frame(segments: np.ndarray, truth: Placement) -> np.ndarray:
    """Plan-frame segments expressed in a room frame that `truth` maps back to the plan."""
    r = truth.rotation
    ends = (segments.reshape(-1, 2) - np.asarray(truth.t)) @ r
    return ends.reshape(-1, 4)


def errors(est: Placement, truth: Placement, centre: np.ndarray) -> tuple[float, float]:
    d = math.degrees(math.atan2(math.sin(est.theta - truth.theta), math.cos(est.theta - truth.theta)))
    return abs(d), float(np.hypot(*(est.points(centre)[0] - truth.points(centre)[0])))


TRUTH = Placement(math.radians(30.0), (12.0, -4.0))


def room_model(walls: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(model walls in the room frame, their polygon's centroid, inward normals) of plan-frame walls at TRUTH."""
    model = to_room_frame(walls, TRUTH)
    poly = Polygon(model[:, :2])
    centre = np.array(poly.centroid.coords[0])
    return model, centre, inward_normals(model, poly, centre)


# an asymmetric cell: walls 0.30 thick in the west, 0.10 in the east, 0.20 north and south
CELL = box(0.0, 0.0, 5.0, 3.0)
FACES = Polygon([(0.15, 0.10), (4.95, 0.10), (4.95, 2.90), (0.15, 2.90)])


def test_optimal_fit_keeps_an_asymmetric_room_off_centre_fig_7_4() -> None:
    """The optimal fit on the plan's faces puts the room where it is; the thesis' springs on the
    centrelines (best fit) pull it to the centre of its cell by a quarter of the thickness difference."""
    model = to_room_frame(ring_segments(FACES), TRUTH)
    shell = shell_mask(model, CFG.shell_tol_m)
    assert shell.all()
    centre = model.reshape(-1, 2).mean(axis=0)
    inward = inward_normals(model, None, centre)
    faces = polygon_faces(FACES)
    start = centroid_start(math.radians(-10.0), centre, np.array(FACES.centroid.coords[0]))
    fit = fine_register(model, inward, centre, faces, start, CFG)
    rot, shift = errors(fit.placement, TRUTH, centre)
    assert rot < 1e-6 and shift < 1e-6
    assert fit.score == pytest.approx(1.0)
    centrelines = polygon_faces(CELL)
    # from the same start (no search over turns: on centrelines no wall lies within the score's
    # tolerance of its line, so the fit score cannot rank turns)
    cl_fit = optimal_fit(model, inward, centre, centrelines, start, replace(CFG, max_residual_m=1.0))
    springs = best_fit(model, centrelines, cl_fit.matched, cl_fit.placement)
    _, pulled = errors(springs, TRUTH, centre)
    assert pulled == pytest.approx((0.30 - 0.10) / 4, abs=1e-3)


L_ROOM = Polygon([(0, 0), (6, 0), (6, 2.5), (3.5, 2.5), (3.5, 5), (0, 5)])


def test_fine_registration_converges_from_any_start_within_45_deg_and_1_m() -> None:
    model, centre, inward = room_model(ring_segments(L_ROOM))
    shell = shell_mask(model, CFG.shell_tol_m)
    assert shell.all()  # the notch's walls look out of the model: shell, though off the convex hull
    faces = polygon_faces(L_ROOM)
    rng = np.random.default_rng(7)
    for _ in range(20):
        start = TRUTH.then(math.radians(rng.uniform(-45, 45)), TRUTH.points(centre)[0], rng.uniform(-1, 1, 2))
        fit = fine_register(model, inward, centre, faces, start, CFG)
        rot, shift = errors(fit.placement, TRUTH, centre)
        assert rot < 1e-4 and shift < 1e-4, (rot, shift)


def test_a_plan_face_drawn_a_degree_off_does_not_turn_the_room() -> None:
    """Room 102's slanted wall vectorized 1 degree off on the plan: the rotation (eq 7.4) comes from the
    walls that agree, the room is not turned by the slanted face's share of the length (0.25 deg)."""
    slanted = Polygon([(0, 0), (6, 0), (6, 4), (1.46, 4)])  # the west wall at about 70 degrees
    model, centre, inward = room_model(ring_segments(slanted))
    faces = polygon_faces(slanted)
    d = np.abs(faces.segments[:, 2:] - faces.segments[:, :2])
    k = int(np.argmax((d > 0.1).all(axis=1)))  # the slanted face
    mid = 0.5 * (faces.segments[k, :2] + faces.segments[k, 2:])
    c, s = math.cos(math.radians(1.0)), math.sin(math.radians(1.0))
    turn = np.array([[c, s], [-s, c]])  # row vectors @ turn: turned by +1 degree
    segments, inward_faces = faces.segments.copy(), faces.inward.copy()
    segments[k] = ((segments[k].reshape(2, 2) - mid) @ turn + mid).reshape(4)
    inward_faces[k] = inward_faces[k] @ turn
    drawn = Faces(segments, inward_faces)
    start = centroid_start(TRUTH.theta + math.radians(5.0), centre, np.array(slanted.centroid.coords[0]))
    fit = fine_register(model, inward, centre, drawn, start, CFG)
    rot, shift = errors(fit.placement, TRUTH, centre)
    assert rot < 0.01 and shift < 0.01, (rot, shift)
    plain = fine_register(model, inward, centre, drawn, start, replace(CFG, rotation_outlier_deg=180.0))
    assert errors(plain.placement, TRUTH, centre)[0] > 0.15  # eq 7.4 over every wall


def test_a_wall_along_collinear_faces_a_plan_drew_apart_follows_the_one_the_others_agree_with() -> None:
    """814's r2: the plan vectorized the room's south wall in two collinear pieces of different thickness
    (0.14 m beside the west corner, 0.30 m over the rest), so the plan room's south face jogs 8 cm at the
    door between them while the room's south wall runs straight. The north, west and east faces put the
    room where it is; the south wall stands for the short piece's face, not the long one's, and the room
    is not pulled 4 cm north (as it is when the wall may only follow the face its midpoint is nearest to)."""
    room = box(0.0, 0.0, 6.0, 5.0)
    # the plan room's outline: the south face at y=0 over x<1 (true), at y=0.08 beyond the door (x>1.9)
    drawn = Polygon([(0, 0), (1.0, 0), (1.0, 0.04), (1.9, 0.04), (1.9, 0.08), (6, 0.08), (6, 5), (0, 5)])
    doors = np.array([[1.0, 0.04, 1.9, 0.04]])
    faces = polygon_faces(drawn, doors=doors, simplify_m=0.0)
    model, centre, inward = room_model(ring_segments(room))
    start = Placement(TRUTH.theta + math.radians(2.0), (TRUTH.t[0] + 0.3, TRUTH.t[1] - 0.2))
    fit = fine_register(model, inward, centre, faces, start, CFG)
    assert errors(fit.placement, TRUTH, centre) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert np.nanmax(np.abs(fit.residual_m)) < 1e-6  # the south wall reports the face it stands on
    # the pieces' faces are 8 cm apart: one wall, two options; pixel jitter (under 4 cm) is one face
    moved = fit.placement.segments(model)
    options = collinear_faces(moved, faces, fit.matched, CFG.max_residual_m, 2 * CFG.plan_simplify_m)
    assert sorted(len(o) for o in options) == [1, 1, 1, 2]
    assert collinear_faces(moved, faces, fit.matched, CFG.max_residual_m, 0.09) == [o[:1] for o in options]


CORRIDOR = box(0.0, 0.0, 15.0, 2.0)


def test_a_corridor_a_percent_long_is_centred_and_a_door_drawn_off_does_not_pull_it() -> None:
    """A corridor model 1% too long (its end walls 7.5 cm out each) is centred between its plan end faces;
    a door pair whose centres lie 0.3 m apart along the wall (found in part, or drawn off) is dropped by
    the gate, one 2 cm off is kept."""
    long = ring_segments(CORRIDOR) * np.array([1.01, 1.0, 1.01, 1.0]) - np.array([0.075, 0, 0.075, 0])
    model, centre, inward = room_model(long)
    faces = polygon_faces(CORRIDOR)
    start = Placement(TRUTH.theta + math.radians(3.0), (TRUTH.t[0] + 0.4, TRUTH.t[1] - 0.2))
    fit = fine_register(model, inward, centre, faces, start, CFG)
    assert errors(fit.placement, TRUTH, centre) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert np.nanmax(np.abs(fit.residual_m)) == pytest.approx(0.075, abs=1e-6)  # the ends, split

    def door(plan_x: float) -> DoorPair:
        # the model's door, at plan (5, 2) when the model is where it truly is
        back = (np.array([5.0, 2.0]) - np.asarray(TRUTH.t)) @ TRUTH.rotation
        return DoorPair(tuple(back), (plan_x, 2.0), (1.0, 0.0), 0.9)

    bad = optimal_fit(model, inward, centre, faces, fit.placement, CFG, [door(5.3)], refine=True)
    assert bad.doors_used == 0 and errors(bad.placement, TRUTH, centre)[1] < 1e-6
    good = optimal_fit(model, inward, centre, faces, fit.placement, CFG, [door(5.02)], refine=True)
    assert good.doors_used == 1
    assert 0.0 < errors(good.placement, TRUTH, centre)[1] < 0.02


def test_the_derived_truth_keeps_walls_parallel_to_a_jogged_face() -> None:
    """truth.refine_on_walls: a corridor whose north face jogs 6.5 cm, modelled straight (at the average):
    the derived placement keeps the model's walls parallel to the true faces (a joint fit of the samples
    tilts it by the jog over the length) and centres it."""
    from tasks.fuse.truth import refine_on_walls

    true_faces = np.array(
        [
            [0.0, 0.0, 15.0, 0.0],
            [15.0, 0.0, 15.0, 1.935],
            [15.0, 1.935, 9.0, 1.935],
            [9.0, 1.935, 9.0, 2.0],
            [9.0, 2.0, 0.0, 2.0],
            [0.0, 2.0, 0.0, 0.0],
        ]
    )
    straight = ring_segments(box(0.0, 0.0, 15.0, 1.97))
    model = to_room_frame(straight, TRUTH)
    start = Placement(TRUTH.theta + math.radians(0.3), (TRUTH.t[0] + 0.03, TRUTH.t[1] - 0.02))
    got = refine_on_walls(model, true_faces, start)
    centre = model.reshape(-1, 2).mean(axis=0)
    rot, shift = errors(got, TRUTH, centre)
    assert rot < 1e-6
    assert shift < 0.01  # the model's north wall between the jog's two levels, its south wall on its face


def test_completeness_leaves_out_the_unseen_face_of_an_added_partition_only() -> None:
    """truth.knowable_samples: a 4 x 4 m room with a new 12 cm partition stub (not in the plan: a true
    "added" change) from the west wall, x 0-1.5 at y 2.0-2.12; the capture saw its south face and its end,
    never its north face. The model holds the shell and the south face. Of the north face only the 5 cm by
    the seen end (and by the west wall) is asked for; over every true face the model misses the north
    face's 1.4 m beyond 10 cm of the west wall, of 4 * 4 + 1.5 + 1.5 + 0.12 m. A planned wall counts
    seen or not (gap filling gives it from the plan)."""
    from tasks.fuse.truth import completeness_on, knowable_samples
    from tasks.lines import point_segment_distances

    shell = ring_segments(box(0.0, 0.0, 4.0, 4.0))
    truth = np.vstack([shell, [[0.0, 2.12, 1.5, 2.12], [1.5, 2.12, 1.5, 2.0], [1.5, 2.0, 0.0, 2.0]]])
    model = np.vstack([shell, [[1.5, 2.0, 0.0, 2.0]]])
    rng = np.random.default_rng(0)
    seen = [(0.0, 4.0, 0.0, 0.0), (4.0, 4.0, 0.0, 4.0), (0.0, 4.0, 4.0, 4.0), (0.0, 0.0, 0.0, 4.0)]
    seen += [(0.0, 1.5, 2.0, 2.0), (1.5, 1.5, 2.0, 2.12)]  # the shell, the south face, the end
    cloud = np.vstack(
        [np.column_stack([rng.uniform(a, b, 4000), rng.uniform(c, d, 4000)]) for a, b, c, d in seen]
    )
    cloud += rng.normal(0.0, 0.003, cloud.shape)
    added = np.array([[0.0, 2.06, 1.5, 2.06]])
    samples, knowable = knowable_samples(truth, cloud, added)
    left_out = samples[~knowable]
    assert np.allclose(left_out[:, 1], 2.12)  # the north face, nothing else
    assert left_out[:, 0].min() > 0.04 and left_out[:, 0].max() < 1.46  # but its ends by seen surfaces
    assert 1.37 <= len(left_out) * 0.01 <= 1.43
    asked = samples[knowable]
    missed = asked[point_segment_distances(asked, model).min(axis=1) > 0.10]
    # the north face by the end and the end's top: the model has no face there
    assert (missed[:, 1] > 2.1).all() and missed[:, 0].min() > 1.44
    assert abs(completeness_on(asked, model) - (1.0 - len(missed) / len(asked))) < 1e-12
    assert len(missed) <= 10  # 9: 6 of the north face, 3 of the end
    assert abs(completeness_on(samples, model) - (1.0 - 1.4 / 19.12)) < 0.005
    # the north face seen: it is asked for
    cloud2 = np.vstack([cloud, np.column_stack([rng.uniform(0.0, 1.5, 4000), np.full(4000, 2.12)])])
    assert knowable_samples(truth, cloud2, added)[1].all()
    # with no added change there (the plan holds the wall) every sample is asked for, seen or not
    assert knowable_samples(truth, cloud, np.zeros((0, 4)))[1].all()


def test_correspondence_prefers_the_face_the_ray_meets_among_parallel_ones() -> None:
    faces = polygon_faces(L_ROOM)
    wall = np.array([[1.0, 4.95, 3.0, 4.95]])  # the top of the tall leg, 5 cm low
    j = correspond(wall, np.array([[0.0, -1.0]]), np.array([2.0, 2.0]), faces, math.radians(10))[0]
    assert np.allclose(faces.segments[j][[1, 3]], 5.0)


WARDROBE_ROOM = box(0.0, 0.0, 5.2, 4.3)
# the TLS room of seed 811: a 2.1 m wardrobe 0.46 m deep along the east wall's north half, whose front the
# wall model took for the wall (the room's corner notched in)
WARDROBE_MODEL = np.array(
    [
        [0.0, 0.0, 5.2, 0.0],
        [5.2, 0.0, 5.2, 2.1],
        [5.2, 2.1, 4.74, 2.1],
        [4.74, 2.1, 4.74, 4.3],
        [4.74, 4.3, 0.0, 4.3],
        [0.0, 4.3, 0.0, 0.0],
    ]
)


def test_a_room_with_one_wall_that_has_no_plan_face_is_still_placed_within_1_cm() -> None:
    """The wardrobe's front (2.2 m of 18.9) has no plan face: the walls that match decide the translation
    and the fit score counts them; a least-squares translation over every wall is dragged 12 cm east
    and the residual gate then drops the west and east walls with it."""
    model, centre, inward = room_model(WARDROBE_MODEL)
    shell = shell_mask(model, CFG.shell_tol_m)
    assert shell.all()  # the wardrobe's walls look out of the model: shell like any notch
    faces = polygon_faces(WARDROBE_ROOM)
    rng = np.random.default_rng(11)
    for _ in range(10):
        start = TRUTH.then(math.radians(rng.uniform(-45, 45)), TRUTH.points(centre)[0], rng.uniform(-1, 1, 2))
        fit = fine_register(model, inward, centre, faces, start, CFG)
        rot, shift = errors(fit.placement, TRUTH, centre)
        assert rot < 0.01 and shift < 0.01, (rot, shift)
        assert fit.score == pytest.approx(1.0 - (2.2 + 0.46) / 18.92, abs=0.01)
    start = TRUTH.then(0.0, TRUTH.points(centre)[0], np.array([0.3, -0.2]))
    plain = fine_register(model, inward, centre, faces, start, replace(CFG, consensus_tol_m=math.inf))
    assert errors(plain.placement, TRUTH, centre)[1] > 0.05  # least squares over every wall


def test_a_partition_inside_the_room_is_not_shell() -> None:
    walls = np.vstack(
        [ring_segments(box(0, 0, 5, 4)), [[0.0, 2.0, 1.5, 2.0], [1.5, 2.0, 1.5, 2.1], [1.5, 2.1, 0.0, 2.1]]]
    )
    assert shell_mask(walls, CFG.shell_tol_m).tolist() == [True] * 4 + [False] * 3


def plan_rooms() -> list[PlanRoom]:
    return [
        PlanRoom("R1", "101", box(0, 0, 4, 3)),
        PlanRoom("R2", "102", box(4.2, 0, 10, 3)),
        PlanRoom("R3", None, Polygon([(0, 3.2), (6, 3.2), (6, 5), (3, 5), (3, 7), (0, 7)])),
    ]


def test_correspondence_sources_and_bad_input() -> None:
    rooms = [
        RoomEvidence("a", "101"),
        RoomEvidence("b", "999", track_xy=np.array([[5.0, 1.0], [6.0, 1.5], [7.0, 2.0]])),
        RoomEvidence("c", None, outline=plan_rooms()[2].polygon, area_m2=plan_rooms()[2].polygon.area * 0.97),
        RoomEvidence("d", "101", area_m2=1.0),
    ]
    got = correspond_rooms(rooms, plan_rooms(), fit_score=lambda r, p: {"a": 0.9, "d": 0.5}.get(r, 0.0))
    assert (got["a"].plan_room, got["a"].source) == ("R1", "label")
    assert (got["b"].plan_room, got["b"].source) == ("R2", "track")
    assert "'999' is not a label read on the plan" in got["b"].notes[0]
    assert (got["c"].plan_room, got["c"].source) == ("R3", "shape")
    assert got["d"].plan_room is None
    assert any("also claimed by room a" in n for n in got["d"].notes)


def test_turning_distance_tells_an_l_from_a_rectangle() -> None:
    l_shape = plan_rooms()[2].polygon
    assert turning_distance(l_shape, l_shape) < 1e-9
    assert turning_distance(box(0, 0, 2, 1), box(5, 5, 9, 7)) < 1e-9  # scale and position do not matter
    assert turning_distance(l_shape, box(0, 0, 6, 4)) > 0.3


def test_place_rooms_reports_empty_and_unknown_rooms_and_places_the_others() -> None:
    truth = Placement(math.radians(90.0), (1.0, 2.0))
    faces_r1 = box(0.0, 0.0, 4.0, 3.0)
    rooms = [
        RoomInput(
            "ok",
            to_room_frame(ring_segments(faces_r1), truth),
            np.full(4, "observed"),
            np.ones(4),
            plan_room="101",
        ),
        RoomInput("empty", np.zeros((0, 4)), np.zeros(0, dtype=str), np.zeros(0), plan_room="102"),
        RoomInput(
            "lost",
            to_room_frame(ring_segments(box(0, 0, 1, 1)), truth),
            np.full(4, "observed"),
            np.ones(4),
            plan_room="777",
        ),
    ]
    placed, _ = place_rooms(rooms, plan_rooms(), np.zeros((0, 4)), np.zeros((0, 4)), None, CFG)
    assert placed["ok"].placement is not None and placed["ok"].correspondence.source == "label"
    centre = np.array([2.0, 1.5])
    p = placed["ok"].placement
    # a 3.8 x 2.8 rectangle: the 180 degree turn fits as well, and is reported as ambiguous
    assert placed["ok"].ambiguous or errors(p, truth, truth.points(centre)[0])[1] < 1e-6
    assert placed["empty"].placement is None and "walls are empty" in placed["empty"].reason
    assert placed["lost"].placement is None and "'777'" in placed["lost"].reason


def test_both_sides_thickness_and_the_thesis_residuals() -> None:
    centre = np.array([[5.0, 0.0, 5.0, 4.0]])  # a wall 0.16 thick between two rooms, drawn 0.20
    left = PlacedWalls("west", np.array([[4.92, 0.0, 4.92, 4.0]]), np.array([[-1.0, 0.0]]))
    right = PlacedWalls("east", np.array([[5.08, 4.0, 5.08, 0.0]]), np.array([[1.0, 0.0]]))
    got = both_sides_thickness(centre, np.array([0.20]), [left, right], (0.05, 0.6), 0.15)
    assert got.thickness_m[0] == pytest.approx(0.16) and got.source[0] == "measured"
    one = both_sides_thickness(centre, np.array([0.20]), [left], (0.05, 0.6), 0.15)
    assert one.thickness_m[0] == pytest.approx(0.20) and one.source[0] == "plan"
    none = both_sides_thickness(centre, np.array([np.nan]), [left], (0.05, 0.6), 0.15)
    assert none.thickness_m[0] == pytest.approx(0.15) and none.source[0] == "default"
    assert room_thickness_from_residuals(left.walls, centre, (0.05, 0.6)) == pytest.approx(0.16)


def test_both_sides_thickness_pairs_the_faces_point_by_point() -> None:
    """A corridor's long face on one side, two rooms' faces on the other (0.16 and 0.18 apart from it,
    over 4 m and 2 m): each point pairs the faces that are there, the median is 0.16."""
    centre = np.array([[0.0, 0.0, 6.0, 0.0]])
    corridor = PlacedWalls("hall", np.array([[-2.0, 0.08, 8.0, 0.08]]), np.array([[0.0, 1.0]]))
    west = PlacedWalls("r3", np.array([[0.0, -0.08, 4.0, -0.08]]), np.array([[0.0, -1.0]]))
    east = PlacedWalls("r4", np.array([[4.0, -0.10, 6.0, -0.10]]), np.array([[0.0, -1.0]]))
    got = both_sides_thickness(centre, np.array([0.2]), [corridor, west, east], (0.05, 0.6), 0.15)
    assert got.thickness_m[0] == pytest.approx(0.16) and got.source[0] == "measured"
    assert got.sides[0] == ("hall", "r3")


def test_an_l_shaped_gap_is_closed_along_the_shell() -> None:
    """The outer corner of an L (both walls' ends near it) was never seen: the gap is filled along the
    shell between the two free ends, and the room closes."""
    cell = Polygon([(0, 0), (6, 0), (6, 3), (3, 3), (3, 6), (0, 6)])
    centrelines = ring_segments(cell)
    shell = shell_polygon(cell.buffer(-0.1, join_style="mitre"), centrelines, np.full(6, 0.2))
    assert shell.area == pytest.approx(cell.buffer(-0.1, join_style="mitre").area, rel=1e-6)
    faces = ring_segments(shell)
    # drop the corner at (5.9, 0.1): cut the bottom wall at x=4.5 and the right wall at y=1.6
    model = []
    for s in faces:
        a, b = s[:2], s[2:]
        if np.isclose(a[1], 0.1) and np.isclose(b[1], 0.1):  # bottom wall, left to right
            model.append([min(a[0], b[0]), 0.1, 4.5, 0.1])
        elif np.isclose(a[0], 5.9) and np.isclose(b[0], 5.9):
            model.append([5.9, 1.6, 5.9, max(a[1], b[1])])
        else:
            model.append(s.tolist())
    got = fill_gaps(np.array(model), shell, CFG.gap_end_tol_m)
    assert got.closed and got.free_ends == 2
    assert got.polygon.area == pytest.approx(shell.area, rel=1e-3)
    filled_len = np.hypot(*(got.walls[:, 2:] - got.walls[:, :2]).T).sum()
    assert filled_len == pytest.approx(1.4 + 1.5, abs=1e-6)
    assert GAP_FILLED == "gap_filled"


def test_a_room_that_cannot_close_says_why() -> None:
    shell = box(0, 0, 4, 3)
    got = fill_gaps(np.array([[0.0, 0.0, 4.0, 0.0]]), shell, CFG.gap_end_tol_m)
    assert got.closed  # one wall on the shell: the path around closes it
    inside = fill_gaps(np.array([[1.0, 1.0, 3.0, 1.0]]), shell, CFG.gap_end_tol_m)
    assert not inside.closed and "inside the room" in inside.reason


def wall_scene(
    rng: np.random.Generator, smear_m: float = 0.005
) -> tuple[np.ndarray, dict[str, tuple[float, float]]]:
    """A 12 m wall along y = 0 seen from the room (y > 0), floor at z = 0, what stands along it (x ranges):
    a door (floor to 2.05 m, the next room's floor seen through it), a window (sill at 0.9 m), a cabinet
    (hides the face, shows its front 0.4 m out), a TV bench (0.5 m high, 0.3 m out) and a stretch the
    camera never looked at (nothing at all). The face's points are spread by smear_m."""
    parts = {
        "door": (1.0, 1.9),
        "window": (3.0, 4.2),
        "cabinet": (5.0, 6.0),
        "bench": (7.0, 8.2),
        "unseen": (9.5, 10.5),
    }

    def inside(x: float, name: str) -> bool:
        return parts[name][0] <= x <= parts[name][1]

    pts = []
    for x in np.arange(0.0, 12.0, 0.02):
        for z in np.arange(0.0, 2.6, 0.04):
            if inside(x, "unseen") or (inside(x, "door") and z < 2.05):
                continue
            if inside(x, "window") and 0.9 <= z <= 2.1:
                continue
            if inside(x, "cabinet") and z < 2.0:
                pts.append([x, 0.4, z])  # its front, not the face behind it
                continue
            if inside(x, "bench") and z < 0.5:
                pts.append([x, 0.3, z])
                continue
            pts.append([x, rng.normal(0.0, smear_m), z])
        for y in np.arange(0.1, 3.0, 0.05):  # the room's floor, everywhere the camera looked
            if not inside(x, "unseen"):
                pts.append([x, y, 0.0])
        if inside(x, "door"):  # the floor of the next room, seen through the door
            for y in np.arange(-1.5, 0.0, 0.05):
                pts.append([x, y, 0.0])
    return np.array(pts), parts


def test_a_door_is_an_opening_seen_through_and_furniture_is_not() -> None:
    """Only the door is found: the window keeps its parapet, the cabinet and the TV bench stand in front
    of the face, and the unseen stretch shows nothing beyond it."""
    pts, parts = wall_scene(np.random.default_rng(1))
    walls = np.array([[0.0, 0.0, 12.0, 0.0]])
    doors = find_doors(pts, 0.0, walls, np.array([[0.0, 1.0]]), (0.6, 1.6))
    assert len(doors) == 1
    x0, x1 = sorted([doors[0].segment[0], doors[0].segment[2]])
    assert x0 == pytest.approx(parts["door"][0], abs=0.05) and x1 == pytest.approx(parts["door"][1], abs=0.05)
    assert doors[0].through_share == pytest.approx(1.0)


def test_the_face_is_read_where_its_points_lie() -> None:
    """A wall modelled 11 cm off its face (a corridor's end wall) still finds the door in it."""
    pts, parts = wall_scene(np.random.default_rng(2))
    walls = np.array([[0.0, -0.11, 12.0, -0.11]])
    cols = wall_columns(pts, 0.0, walls[0], np.array([0.0, 1.0]))
    assert cols.face_offset_m == pytest.approx(0.11, abs=0.01)
    doors = find_doors(pts, 0.0, walls, np.array([[0.0, 1.0]]), (0.6, 1.6))
    assert len(doors) == 1 and doors[0].segment[0] == pytest.approx(parts["door"][0], abs=0.05)


def test_a_closed_span_is_seen_everywhere_and_through_nowhere() -> None:
    """span_state: the door is open, the wall beside it closed, the unseen stretch neither; a smeared face
    (frames 5 cm apart) cannot tell."""
    pts, parts = wall_scene(np.random.default_rng(3))
    wall, inward = np.array([0.0, 0.0, 12.0, 0.0]), np.array([0.0, 1.0])
    door = span_state(pts, 0.0, wall, inward, *parts["door"])
    assert door.face_share == pytest.approx(0.0) and door.through_share >= 0.9
    closed = span_state(pts, 0.0, wall, inward, 2.0, 2.9)
    assert closed.face_share == pytest.approx(1.0) and closed.through_share == 0.0
    assert closed.closed(CFG.closed_door_share, CFG.door_through_share, CFG.crisp_face_m)
    unseen = span_state(pts, 0.0, wall, inward, *parts["unseen"])
    assert unseen.face_share == 0.0 and not unseen.closed(0.9, 0.25, CFG.crisp_face_m)
    smeared, _ = wall_scene(np.random.default_rng(3), smear_m=0.05)
    blurred = span_state(smeared, 0.0, wall, inward, 2.0, 2.9)
    assert blurred.face_spread_m > CFG.crisp_face_m
    assert not blurred.closed(CFG.closed_door_share, CFG.door_through_share, CFG.crisp_face_m)


def test_wall_evidence_a_missed_wall_stands_a_removed_one_is_seen_through_an_unseen_one_is_neither() -> None:
    """A 6 x 4 room in the plan frame whose plan also draws a partition (y = 2, x 0..3) that is gone: its
    cloud shows the floor through the partition's place (open); the wall model misses the east wall
    between y = 1 and 3, whose face the cloud shows (standing); the north wall's face between x = 4 and 5
    was never seen (neither)."""
    from tasks.fuse.correspond import PlanRoom
    from tasks.fuse.floor import fuse_floor

    room_box = box(0.0, 0.0, 6.0, 4.0)
    centre = np.array(
        [[-0.1, -0.1, 6.1, -0.1], [6.1, -0.1, 6.1, 4.1], [6.1, 4.1, -0.1, 4.1], [-0.1, 4.1, -0.1, -0.1]]
    )
    partition = np.array([[-0.1, 2.0, 3.0, 2.0]])
    centrelines = np.vstack([centre, partition])
    thickness = np.array([0.2, 0.2, 0.2, 0.2, 0.1])
    rng = np.random.default_rng(4)
    pts = []
    for x in np.arange(0.0, 6.0, 0.04):
        for y in np.arange(0.0, 4.0, 0.04):
            pts.append([x, y, 0.0])  # the floor, everywhere
    for z in np.arange(0.0, 2.5, 0.05):
        for x in np.arange(0.0, 6.0, 0.03):
            pts.append([x, rng.normal(0, 0.004), z])
            if not 4.0 <= x <= 5.0:
                pts.append([x, 4.0 + rng.normal(0, 0.004), z])
        for y in np.arange(0.0, 4.0, 0.03):
            pts.append([rng.normal(0, 0.004), y, z])
            pts.append([6.0 + rng.normal(0, 0.004), y, z])
    model = np.array(
        [
            [0.0, 0.0, 6.0, 0.0],
            [6.0, 0.0, 6.0, 1.0],
            [6.0, 3.0, 6.0, 4.0],
            [6.0, 4.0, 0.0, 4.0],
            [0.0, 4.0, 0.0, 0.0],
        ]
    )
    room = RoomInput(
        "a",
        model,
        np.full(len(model), "observed"),
        np.ones(len(model)),
        2.5,
        True,
        "101",
        np.array(pts),
        0.0,
        2.5,
    )
    floor = fuse_floor(
        [room], [PlanRoom("R1", "101", room_box)], centrelines, thickness, np.zeros((0, 4)), None, CFG
    )
    assert floor.rooms["a"].in_plan and floor.evidence is not None
    ev = floor.evidence

    def covers(runs: dict, i: int, s0: float, s1: float) -> float:
        got = sum(max(0.0, min(b, s1) - max(a, s0)) for a, b in runs.get(i, []))
        return got / (s1 - s0)

    assert covers(ev.standing, 1, 1.2, 3.0) > 0.9  # the east wall the model missed (y 1..3, from y = -0.1)
    assert covers(ev.seen_through, 1, 1.2, 3.0) == 0.0
    assert covers(ev.seen_through, 4, 0.3, 3.0) > 0.9 and covers(ev.standing, 4, 0.3, 3.0) == 0.0
    north = (6.1 - 5.0 + 0.1, 6.1 - 4.0 - 0.1)  # x 5..4 along the north centreline, which runs west
    assert covers(ev.standing, 2, *north) == 0.0 and covers(ev.seen_through, 2, *north) == 0.0


def test_a_door_seen_through_only_at_its_jambs_is_open_across_its_width() -> None:
    """815's new door in the corridor wall: its face empty over 0.8 m, points beyond it only in the
    columns by its jambs (7 of 16; the corridor's far wall lies out of reach). The whole run is open, as
    the door finder reads a door; so is nothing where too few columns were seen through (a stretch
    never looked at), nor a run wider than a door (there only the columns seen through are open)."""
    from tasks.fuse.floor import door_runs

    empty = np.zeros(40, dtype=bool)
    empty[10:26] = True  # 0.80 m
    beyond = np.zeros(40, dtype=bool)
    beyond[[10, 11, 12, 13, 22, 23, 24]] = True
    assert np.array_equal(door_runs(empty, beyond, CFG), empty)
    beyond[[11, 12, 13, 22, 23]] = False  # 2 of 16 columns: under door_through_share
    assert not door_runs(empty, beyond, CFG).any()
    wide = np.zeros(60, dtype=bool)
    wide[5:45] = True  # 2.0 m: a removed wall, not a door
    assert not door_runs(wide, wide, CFG).any()


def test_a_gap_ending_at_a_junction_is_closed_along_the_shell() -> None:
    """The west wall stops where a partition meets it (a junction, no free end); the north wall's end
    is the gap's only free end: the gap is filled from it along the shell to where the west wall
    resumes, and the room closes."""
    shell = box(0.0, 0.0, 6.0, 4.0)
    walls = np.array(
        [
            [0.0, 0.0, 6.0, 0.0],
            [6.0, 0.0, 6.0, 4.0],
            [6.0, 4.0, 0.05, 4.0],  # the north wall, its west end short of the corner
            [0.0, 0.0, 0.0, 2.5],  # the west wall, up to the partition
            [0.0, 2.5, 1.5, 2.5],  # the partition
        ]
    )
    got = fill_gaps(walls, shell, CFG.gap_end_tol_m)
    assert got.closed
    filled = np.hypot(*(got.walls[:, 2:] - got.walls[:, :2]).T).sum()
    assert filled == pytest.approx(0.05 + 1.5, abs=0.02)


def test_a_wall_end_is_not_extended_across_the_room() -> None:
    """A corridor whose north wall stops 1 m short of its east end and whose south wall stops 1 m short
    too: the gap is filled along the shell round the corner, not straight across the corridor."""
    shell = box(0.0, 0.0, 10.0, 2.0)
    walls = np.array([[0.0, 0.0, 9.0, 0.0], [9.0, 2.0, 0.0, 2.0], [0.0, 2.0, 0.0, 0.0]])
    got = fill_gaps(walls, shell, CFG.gap_end_tol_m)
    assert got.closed and got.polygon.area == pytest.approx(20.0, rel=1e-3)


def test_room_labels_are_read_from_the_plan_raster() -> None:
    """Labels drawn as the survey generator draws them (OpenCV's simplex font), among walls and a green
    arrow, are read per room; a room without text has none; a label printed over the arrow's end (the
    generator's WC) is read whole."""
    import shutil

    import cv2

    from tasks.plan.labels import read_room_labels

    if shutil.which("tesseract") is None:
        pytest.skip("tesseract-ocr is not installed (.ci/setup installs it)")
    s = 0.02
    img = np.full((300, 1000, 3), 255, np.uint8)
    cv2.rectangle(img, (10, 10), (990, 290), (0, 0, 0), 8)
    cv2.line(img, (350, 10), (350, 290), (0, 0, 0), 6)
    cv2.line(img, (670, 10), (670, 290), (0, 0, 0), 6)
    cv2.putText(img, "104", (150, 150), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.arrowedLine(img, (420, 200), (520, 200), (0, 150, 60), 8)
    cv2.arrowedLine(img, (820, 60), (820, 150), (0, 150, 60), 12)
    cv2.putText(img, "WC", (806, 158), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    rooms = [
        box(14 * s, -286 * s, 347 * s, -14 * s),
        box(353 * s, -286 * s, 667 * s, -14 * s),
        box(673 * s, -286 * s, 986 * s, -14 * s),
    ]
    assert read_room_labels(img, rooms, s) == ["104", None, "WC"]


def test_a_room_testifies_only_along_the_stretch_of_a_plan_wall_it_lies_beside() -> None:
    """The plan's north wall runs on past the room's east end (x 6.1..9, the next room's, never captured);
    the room saw the corridor's floor beyond it through its door (x 4..5): beside the room the door is an
    opening in the plan wall, past the room's end nothing testifies (its face empty there only because
    the room cannot see it)."""
    from tasks.fuse.correspond import PlanRoom
    from tasks.fuse.floor import fuse_floor

    rng = np.random.default_rng(5)
    pts = [[x, y, 0.0] for x in np.arange(0.0, 6.0, 0.04) for y in np.arange(0.0, 4.0, 0.04)]
    pts += [[x, y, 0.0] for x in np.arange(3.0, 9.0, 0.04) for y in np.arange(4.3, 5.5, 0.04)]  # beyond
    for z in np.arange(0.0, 2.5, 0.05):
        for x in np.arange(0.0, 6.0, 0.03):
            pts.append([x, rng.normal(0, 0.004), z])
            if not 4.0 <= x <= 5.0 or z > 2.1:
                pts.append([x, 4.0 + rng.normal(0, 0.004), z])
        for y in np.arange(0.0, 4.0, 0.03):
            pts.append([rng.normal(0, 0.004), y, z])
            pts.append([6.0 + rng.normal(0, 0.004), y, z])
    model = ring_segments(box(0.0, 0.0, 6.0, 4.0))
    room = RoomInput(
        "a", model, np.full(4, "observed"), np.ones(4), 2.5, True, "101", np.array(pts), 0.0, 2.5
    )
    centrelines = np.array(
        [[-0.1, -0.1, 6.1, -0.1], [6.1, -0.1, 6.1, 4.1], [-0.1, 4.1, 9.0, 4.1], [-0.1, 4.1, -0.1, -0.1]]
    )
    floor = fuse_floor(
        [room],
        [PlanRoom("R1", "101", box(0.0, 0.0, 6.0, 4.0))],
        centrelines,
        np.full(4, 0.2),
        np.zeros((0, 4)),
        None,
        CFG,
    )
    assert floor.evidence is not None
    runs = floor.evidence.seen_through.get(2, [])
    assert len(runs) == 1 and 4.0 < runs[0][0] < 4.3 and 5.0 < runs[0][1] < 5.3  # the door, x 4..5
    assert all(b <= 6.3 for _, b in floor.evidence.standing.get(2, []))


def test_a_wardrobe_front_modelled_as_a_wall_leaves_the_room_and_the_gap_closes_along_the_plan() -> None:
    """The TLS room of seed 811 in the plan frame: the wardrobe (x 4.74..5.2, y 2.1..4.3, 2.1 m high under
    a 3 m ceiling) hides the east wall's north half below 2.1 m, the scanner sees the wall above it. The
    wall model took the wardrobe's front and side for walls: with no plan face and nothing just below the
    ceiling they leave the model, and gap filling closes the room along the plan's east wall."""
    from tasks.fuse.correspond import PlanRoom
    from tasks.fuse.floor import fuse_floor

    rng = np.random.default_rng(8)
    pts = [
        [x, y, z] for x in np.arange(0.0, 5.2, 0.05) for y in np.arange(0.0, 4.3, 0.05) for z in (0.0, 3.0)
    ]
    for z in np.arange(0.0, 3.0, 0.04):
        for x in np.arange(0.0, 5.2, 0.03):
            pts += [[x, rng.normal(0, 0.003), z], [x, 4.3 + rng.normal(0, 0.003), z]]
        for y in np.arange(0.0, 4.3, 0.03):
            pts.append([rng.normal(0, 0.003), y, z])
            if y < 2.1 or z > 2.1:
                pts.append([5.2 + rng.normal(0, 0.003), y, z])  # the east wall, above the wardrobe
            elif z <= 2.1:
                pts.append([4.74 + rng.normal(0, 0.003), y, z])  # the wardrobe's front
        if z <= 2.1:
            pts += [[x, 2.1 + rng.normal(0, 0.003), z] for x in np.arange(4.74, 5.2, 0.03)]  # its side
    room = RoomInput(
        "r5",
        WARDROBE_MODEL,
        np.full(len(WARDROBE_MODEL), "observed"),
        np.ones(len(WARDROBE_MODEL)),
        3.0,
        True,
        "105",
        np.array(pts),
        0.0,
        3.0,
    )
    centrelines = ring_segments(box(-0.1, -0.1, 5.3, 4.4))
    floor = fuse_floor(
        [room],
        [PlanRoom("R3", "105", WARDROBE_ROOM)],
        centrelines,
        np.full(4, 0.2),
        np.zeros((0, 4)),
        None,
        CFG,
    )
    fused = floor.rooms["r5"]
    assert fused.in_plan and fused.gaps is not None and fused.gaps.closed
    walls = fused.walls
    assert not (np.abs(walls[:, [0, 2]] - 4.74) < 0.02).all(axis=1).any()  # the wardrobe's front is gone
    assert fused.gaps.polygon.area == pytest.approx(5.2 * 4.3, rel=0.01)
    filled = walls[fused.origin == GAP_FILLED]
    east = filled[(np.abs(filled[:, [0, 2]] - 5.2) < 0.02).all(axis=1)]
    assert np.abs(east[:, 3] - east[:, 1]).sum() == pytest.approx(2.2, abs=0.05)


def test_a_wall_along_a_plan_face_drawn_too_thick_does_not_pull_the_room() -> None:
    """data/mini's r4: the plan gave a 2.6 m piece of the south wall 0.575 m instead of 0.32 m, so the
    plan room's face there lies 9.5 cm inside the true one, within every gate. Least squares over the
    walls that agree within the consensus tolerance moved the room 2.5 cm (4.4 cm in data/mini); only
    the walls close to their faces decide the translation now."""
    truth_walls = np.array(
        [
            [0.0, 0.0, 2.6, 0.0],
            [2.6, 0.0, 5.0, 0.0],
            [5.0, 0.0, 5.0, 4.0],
            [5.0, 4.0, 0.0, 4.0],
            [0.0, 4.0, 0.0, 0.0],
        ]
    )
    model, centre, inward = room_model(truth_walls)
    plan_room = Polygon([(0.0, 0.095), (2.6, 0.095), (2.6, 0.0), (5.0, 0.0), (5.0, 4.0), (0.0, 4.0)])
    faces = polygon_faces(plan_room)
    fit = fine_register(model, inward, centre, faces, TRUTH, CFG)
    assert errors(fit.placement, TRUTH, centre)[1] < 0.005
    loose = fine_register(model, inward, centre, faces, TRUTH, replace(CFG, fit_tol_m=0.0))
    assert errors(loose.placement, TRUTH, centre)[1] > 0.015
