"""The IMU-track fallback's check of each frame against the other frames' depth (`check_with_neighbours`):
known answers on a synthetic 14 m x 2 m corridor whose frames see its walls within 4 m."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.register.config import RegisterConfig
from tasks.register.plan_icp import PlanFit
from tasks.register.track_fallback import _PlanPlacement, agreement, icp_to_points, wall_band_xy

LENGTH, WIDTH = 14.0, 2.0


def _pose(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """(4, 4) camera → plan: a camera 1.4 m above the floor turned by `yaw_deg` about the vertical."""
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = [x, y, 1.4]
    return T


def _turned(T: np.ndarray, yaw_deg: float, shift_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """T turned by `yaw_deg` about the vertical through its camera and shifted by `shift_m`."""
    out = T.copy()
    out[:3, :3] = _pose(0.0, 0.0, yaw_deg)[:3, :3] @ T[:3, :3]
    out[:2, 3] += shift_m
    return out


def _corridor_points(step_m: float = 0.01) -> np.ndarray:
    """(N, 3) points on the corridor's four inner faces, every `step_m` along them, at three heights."""
    xs = np.arange(0.0, LENGTH + 1e-9, step_m)
    ys = np.arange(0.0, WIDTH + 1e-9, step_m)
    lines = [
        np.column_stack([xs, np.zeros_like(xs)]),
        np.column_stack([xs, np.full_like(xs, WIDTH)]),
        np.column_stack([np.zeros_like(ys), ys]),
        np.column_stack([np.full_like(ys, LENGTH), ys]),
    ]
    xy = np.vstack(lines)
    return np.vstack([np.column_stack([xy, np.full(len(xy), z)]) for z in (0.5, 1.0, 1.6)])


def _seen_from(T: np.ndarray, world: np.ndarray, radius_m: float = 4.0) -> np.ndarray:
    """The corridor's points within `radius_m` of the camera, in its own frame."""
    near = world[np.linalg.norm(world[:, :2] - T[:2, 3], axis=1) < radius_m]
    return ((near - T[:3, 3]) @ T[:3, :3]).astype(np.float32)


def _placement(truth: dict[int, np.ndarray], placed: dict[int, np.ndarray]) -> _PlanPlacement:
    """A fallback placement of frames seeing the corridor from `truth`, placed at `placed`."""
    world = _corridor_points()
    plan = object.__new__(_PlanPlacement)
    plan.cfg = RegisterConfig()
    plan.walls = np.array(  # the corridor's plan: centrelines and thickness, inner faces on its box
        [
            [-0.1, -0.1, LENGTH + 0.1, -0.1, 0.2],
            [-0.1, WIDTH + 0.1, LENGTH + 0.1, WIDTH + 0.1, 0.2],
            [-0.1, -0.1, -0.1, WIDTH + 0.1, 0.2],
            [LENGTH + 0.1, -0.1, LENGTH + 0.1, WIDTH + 0.1, 0.2],
        ]
    )
    plan.order = sorted(truth)
    plan.cam_points = {f: _seen_from(T, world) for f, T in truth.items()}
    plan.fit = {f: PlanFit(placed[f], 0.0, 0.0, 0.0, np.zeros((2, 2))) for f in truth}
    plan.starts = dict.fromkeys(truth, 0.0)
    return plan


def _sparse(cam: np.ndarray) -> np.ndarray:
    """A frame's points at one height, 2 cm apart: under `line_min_count` in every 3 cm line cell, so no wall
    line (a frame far from its walls)."""
    return cam[np.abs(cam[:, 2] - (1.0 - 1.4)) < 1e-6][::2]


def test_agreement_counts_the_points_near_the_others():
    x = np.linspace(0.0, 4.0, 101)
    line = np.column_stack([x, np.zeros_like(x)])
    assert agreement(line, line + np.array([0.0, 0.03]), 0.05) == 1.0
    assert agreement(line, line + np.array([0.0, 0.10]), 0.05) == 0.0
    half = line[x < 2.0]  # the others saw only the first half of the wall
    assert agreement(line, half, 0.05) == pytest.approx(51 / 101, abs=1e-9)
    assert agreement(line, np.zeros((0, 2)), 0.05) == 0.0


def test_icp_to_points_puts_a_frame_back_onto_the_others_walls():
    world = _corridor_points()
    true_T = _pose(12.5, 0.7, 20.0)
    cam = _seen_from(true_T, world)
    others = np.vstack(
        [
            wall_band_xy(_pose(x, 1.0, 0.0), _seen_from(_pose(x, 1.0, 0.0), world), RegisterConfig())
            for x in (9.0, 11.0, 13.0)
        ]
    )
    start = _pose(12.62, 0.62, 24.0)  # 14 cm and 4 degrees off
    T = icp_to_points(start, cam, others, RegisterConfig())
    rel = T[:3, :3] @ true_T[:3, :3].T
    assert abs(np.degrees(np.arctan2(rel[1, 0], rel[0, 0]))) < 0.3
    assert abs(T[1, 3] - 0.7) < 0.01  # across the corridor its two walls pin it
    # along it only the end wall pins it, against the side walls' nearest points (the matching's friction):
    # within the check's 5 cm tolerance, which is what the turn search asks of it
    assert abs(T[0, 3] - 12.5) < 0.06


def test_a_frame_fitted_to_the_plan_a_quarter_turn_off_is_turned_back_by_the_other_frames():
    """The frame at the corridor's end sees its end wall and both side walls (a U): turned by 90 degrees about
    its camera it agrees with none of the others, and only its true heading puts its U on theirs."""
    truth = {k: _pose(1.5 + 1.5 * k, 1.0, 10.0 * k) for k in range(8)}
    truth[8] = _pose(12.8, 0.7, 35.0)
    placed = {**truth, 8: _turned(truth[8], 90.0, (0.05, -0.04))}
    plan = _placement(truth, placed)
    metrics = plan.check_with_neighbours()
    assert metrics["unplaced"] == []
    assert list(metrics["turned_deg"]) == ["8"]
    assert metrics["turned_deg"]["8"] == pytest.approx(-90.0, abs=1.0)
    T = plan.fit[8].T
    assert np.linalg.norm(T[:2, 3] - truth[8][:2, 3]) < 0.02
    assert metrics["agreement_after"][-1] > 0.95
    for k in range(8):  # the frames that agreed are left where they were
        assert np.array_equal(plan.fit[k].T, truth[k])


def test_a_frame_no_placement_confirms_is_left_unplaced():
    """In the corridor's plain middle a frame sees two parallel walls: turned by a quarter it agrees with none
    of the others, and turned back it fits as well either way round (a half turn): it is left unplaced."""
    truth = {k: _pose(1.5 + 1.5 * k, 1.0, 0.0) for k in range(9)}
    placed = {**truth, 4: _turned(truth[4], 90.0)}
    plan = _placement(truth, placed)
    plan.cam_points[4] = _seen_from(truth[4], _corridor_points(), radius_m=2.5)
    metrics = plan.check_with_neighbours()
    assert metrics["unplaced"] == [4]
    assert metrics["turned_deg"] == {}
    assert metrics["median_agreement"] > 0.95


def test_a_frame_another_placement_refutes_is_left_unplaced_without_wall_lines():
    """The frame at the corridor's end, its depth too sparse for a wall line (too far from its walls), fitted
    to the plan 20 degrees off: the others' faces are smeared over some centimetres (a Kinect's at 3-4 m), so
    part of its U still lands on them and the share rule keeps it, but its true placement, found by the turn
    search, agrees with the others more than twice as well. Without a wall line that placement cannot be
    checked against the plan's directions, so the frame is not turned but left unplaced: its points would
    draw a diagonal wall nobody else saw."""
    truth = {k: _pose(1.5 + 1.5 * k, 1.0, 10.0 * k) for k in range(8)}
    truth[8] = _pose(13.0, 1.0, 20.0)
    placed = {**truth, 8: _turned(truth[8], -20.0, (0.03, 0.02))}
    plan = _placement(truth, placed)
    rng = np.random.default_rng(0)
    for k in range(8):
        plan.cam_points[k] = plan.cam_points[k] + np.array([1.0, 1.0, 0.0], np.float32) * rng.normal(
            0.0, 0.05, (len(plan.cam_points[k]), 1)
        ).astype(np.float32)
    plan.cam_points[8] = _sparse(plan.cam_points[8])
    assert not plan.parallel_to_plan(8, truth[8])
    metrics = plan.check_with_neighbours()
    typical = metrics["median_agreement"]
    assert 0.25 * typical <= metrics["agreement_before"][-1] < 0.5 * typical  # the share rule alone keeps it
    assert metrics["turned_deg"] == {}
    assert metrics["refuted"] == [8]
    assert metrics["unplaced"] == [8]
    assert np.array_equal(plan.fit[8].T, placed[8])


def test_a_frame_seeing_more_than_the_others_is_kept():
    """A frame placed right whose wall points mostly lie where no other frame looked (the others see 1.6 m
    around them, it sees 4 m beyond their last) agrees little, but no other placement agrees twice as well:
    it stays where it is."""
    truth = {k: _pose(1.0 + 0.8 * k, 1.0, 0.0) for k in range(8)}
    truth[8] = _pose(9.0, 1.0, 0.0)
    plan = _placement(truth, truth)
    world = _corridor_points()
    for k in range(8):
        plan.cam_points[k] = _seen_from(truth[k], world, radius_m=1.6)
    plan.cam_points[8] = _sparse(_seen_from(truth[8], world, radius_m=4.0))
    metrics = plan.check_with_neighbours()
    assert (
        0.25 * metrics["median_agreement"]
        <= metrics["agreement_before"][-1]
        < 0.5 * metrics["median_agreement"]
    )
    assert metrics["unplaced"] == []
    assert metrics["refuted"] == []
    assert metrics["turned_deg"] == {}
    assert np.array_equal(plan.fit[8].T, truth[8])
