"""Scale stage (eq 3.16, appendix A): Horn's closed form, RANSAC, per-frame scales from depth, metric poses,
on the analytic box room of tasks/synth/box_views.py and a canned SfM reconstruction of it."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from tasks.camera import Calibration, CameraModel, RigidPose
from tasks.cloud import DegenerateInputError
from tasks.register.config import ScaleConfig
from tasks.register.scale import (
    ROOM_FROM_CAMERA_AXES,
    FrameScale,
    apply_scale,
    combine_scales,
    estimate_scale,
    horn_similarity,
    ransac_similarity,
)
from tasks.register.sfm import SfmResult
from tasks.synth.box_views import BOX, box_hits, look_pose
from tests.scenes import small_camera


def scene_points(n: int, rng: np.random.Generator, box=BOX) -> NDArray[np.float64]:
    """n points spread over the box's six faces."""
    lo, hi = box
    p = rng.uniform(lo, hi, size=(n, 3))
    face = rng.integers(0, 6, n)
    axis, side = face // 2, face % 2
    p[np.arange(n), axis] = np.where(side == 0, lo[axis], hi[axis])
    return p


def fake_sfm(
    poses_world_from_cam: list[NDArray],
    camera: CameraModel,
    sfm_from_world_scale: float,
    rng: np.random.Generator,
    noise_px: float = 0.3,
    box=BOX,
) -> tuple[SfmResult, NDArray]:
    """A canned SfM reconstruction: world points seen by the cameras, expressed in an SfM frame that is
    the world rotated, shifted and scaled by `sfm_from_world_scale`, with noisy observations."""
    R_s = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    t_s = np.array([0.5, -1.0, 2.0])
    world = scene_points(4000, rng, box)
    sfm_pts = sfm_from_world_scale * world @ R_s.T + t_s
    names = [f"{k:06d}.png" for k in range(len(poses_world_from_cam))]
    cam_from_world, obs, errs = {}, {}, {}
    w, h = camera.size
    for name, T in zip(names, poses_world_from_cam, strict=True):
        cam_from_w = np.linalg.inv(T)
        pc = world @ cam_from_w[:3, :3].T + cam_from_w[:3, 3]
        uv, z = camera.project(pc)
        # visible: in front, inside, and not hidden (the box is convex, so only the in-box test matters)
        ok = (z > 0.2) & (uv[:, 0] >= 1) & (uv[:, 0] <= w - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= h - 2)
        rows = np.flatnonzero(ok)
        obs[name] = (rows, uv[rows] + rng.normal(0, noise_px, (len(rows), 2)))
        errs[name] = noise_px
        # the same camera in the SfM frame: X_cam = R_c (X_world) + t_c, X_world = R_s^T (X_sfm - t_s) / k
        k = sfm_from_world_scale
        Tc = np.eye(4)
        Tc[:3, :3] = cam_from_w[:3, :3] @ R_s.T
        Tc[:3, 3] = k * cam_from_w[:3, 3] - Tc[:3, :3] @ t_s
        cam_from_world[name] = Tc  # in SfM units: X_cam_sfm = k * X_cam
    result = SfmResult(
        names,
        np.ones(len(names), bool),
        cam_from_world,
        errs,
        sfm_pts,
        np.arange(len(sfm_pts), dtype=np.int64),
        obs,
        camera,
    )
    return result, world


def ring_poses(n: int) -> list[NDArray]:
    return [
        look_pose(np.array([0.3, 0.2, 1.4]) + 0.4 * np.array([np.cos(a), np.sin(a), 0]), a + 0.3)
        for a in np.linspace(0, 2 * np.pi, n, endpoint=False)
    ]


# ------------------------------------------------------------------------------------------------ tests


def test_horn_similarity_recovers_a_known_similarity(rng):
    local = rng.normal(size=(40, 3))
    R = Rotation.from_rotvec([0.4, -1.1, 2.0]).as_matrix()
    obj = 3.7 * local @ R.T + np.array([1.0, -2.0, 0.5])
    lam, R_est, T = horn_similarity(local, obj)
    assert lam == pytest.approx(3.7, rel=1e-12)
    assert np.allclose(R_est, R, atol=1e-10)
    assert np.allclose(T, [1.0, -2.0, 0.5], atol=1e-10)
    assert np.linalg.det(R_est) == pytest.approx(1.0)


def test_horn_similarity_rejects_degenerate_sets():
    with pytest.raises(DegenerateInputError, match="coincide"):
        horn_similarity(np.ones((5, 3)), np.zeros((5, 3)))
    with pytest.raises(DegenerateInputError, match="N>=3"):
        horn_similarity(np.zeros((2, 3)), np.zeros((2, 3)))


def test_ransac_similarity_ignores_outliers(rng):
    local = rng.uniform(-1, 1, size=(60, 3))
    R = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    obj = 0.42 * local @ R.T + np.array([0.0, 0.0, 2.0])
    obj[:15] += rng.uniform(-0.5, 0.5, size=(15, 3))
    lam, _R, _T, inl = ransac_similarity(local, obj, ScaleConfig(), rng)
    assert lam == pytest.approx(0.42, rel=1e-9)
    assert inl[15:].all() and inl[:15].sum() <= 1


def _ransac_one_by_one(local, obj, cfg, rng):
    """The RANSAC of eq 3.16 written as a plain loop over the hypotheses (the batched one must agree)."""
    n = len(local)
    thr = cfg.inlier_threshold_m + cfg.inlier_threshold_rel * np.linalg.norm(obj, axis=1)
    best, best_count = None, 2
    for _ in range(cfg.ransac_iterations):
        idx = rng.choice(n, 3, replace=False)
        a, b, c = obj[idx]
        if np.linalg.norm(np.cross(b - a, c - a)) < 1e-4:
            continue
        lam, R, T = horn_similarity(local[idx], obj[idx])
        inl = np.linalg.norm(obj - (lam * local @ R.T + T), axis=1) < thr
        if inl.sum() > best_count:
            best, best_count = inl, int(inl.sum())
            if best_count == n:
                break
    if best is None:
        return None
    for _ in range(2):
        lam, R, T = horn_similarity(local[best], obj[best])
        new = np.linalg.norm(obj - (lam * local @ R.T + T), axis=1) < thr
        if new.sum() < 3:
            break
        best = new
    return horn_similarity(local[best], obj[best])[0], best


@pytest.mark.parametrize("outliers", [0.0, 0.3, 0.8])
def test_ransac_similarity_scores_its_hypotheses_as_a_loop_would(outliers):
    """The batched hypotheses give the loop's best sample, and leave the generator where the loop (which
    stops at a hypothesis explaining every point) leaves it: the next frame's samples are the same."""
    g = np.random.default_rng(3)
    cfg = ScaleConfig()
    for n in (3, 40, 700):
        local = g.normal(size=(n, 3))
        R = Rotation.from_rotvec(g.normal(size=3)).as_matrix()
        obj = 1.3 * local @ R.T + np.array([0.2, -0.1, 2.5]) + g.normal(scale=0.004, size=(n, 3))
        bad = g.random(n) < outliers
        obj[bad] += g.normal(scale=0.6, size=(int(bad.sum()), 3))
        ra, rb = np.random.default_rng(n), np.random.default_rng(n)
        want = _ransac_one_by_one(local, obj, cfg, ra)
        fit = ransac_similarity(local, obj, cfg, rb)
        assert (want is None) == (fit is None)
        if want is not None:
            assert fit[0] == pytest.approx(want[0], rel=1e-12)
            assert np.array_equal(fit[3], want[1])
        assert ra.random() == rb.random()


def test_combine_scales_is_robust_and_reports_spread():
    frames = [
        FrameScale(f"f{k}", s, np.eye(3), np.zeros(3), 50, 40, 0.01)
        for k, s in enumerate([2.0, 2.02, 1.98, 2.01, 9.0])
    ]
    rep = combine_scales(frames, ScaleConfig())
    assert rep.scale == pytest.approx(2.01)
    assert 0 < rep.mad < 0.05 and rep.iqr == pytest.approx(0.02)
    assert len(rep.frames_used) == 5
    with pytest.raises(DegenerateInputError, match="at least 1 frames"):
        combine_scales([], ScaleConfig())


def test_scale_trend_tells_a_bent_map_from_noisy_frames(rng):
    """Per-frame scales 2.0 with 1.3 % noise and no trend (real Kinect frames), and the same drifting
    linearly by -5 % from the first frame to the last (a bent map), with one wild frame each: the trend is
    about 0 and -0.05 of the scale, whatever the wild frame, while both spread over 1 %."""

    def report(values):
        frames = [FrameScale(f"f{k}", s, np.eye(3), np.zeros(3), 50, 40, 0.01) for k, s in enumerate(values)]
        return combine_scales(frames, ScaleConfig())

    noise = rng.normal(0.0, 0.013 * 2.0, 60)
    flat = 2.0 + noise
    bent = 2.0 * (1.0 + np.linspace(0.025, -0.025, 60)) + noise
    flat[7] = bent[7] = 9.0
    assert abs(report(flat).relative_trend) < 0.01
    assert report(bent).relative_trend == pytest.approx(-0.05, abs=0.01)
    assert report(flat).relative_spread > 0.01  # spread alone would call the noisy frames bent


def test_estimate_scale_and_apply_scale_on_a_rendered_box_room(rng):
    cam = small_camera()
    poses = ring_poses(8)
    sfm, _world = fake_sfm(poses, cam, 0.37, rng)
    # depth camera 2.5 cm beside the colour camera, as on a Kinect
    ir_to_rgb = RigidPose(Rotation.from_rotvec([0.0, 0.01, 0.0]).as_matrix(), np.array([-0.025, 0.0, 0.0]))
    calib = Calibration(cam, cam, ir_to_rgb)
    rgb_from_ir = ir_to_rgb.matrix
    depth_frames = []
    for name, T_rgb in zip(sfm.names, poses, strict=True):
        world_from_ir = T_rgb @ rgb_from_ir
        z, _ = box_hits(cam, world_from_ir)
        depth_frames.append((name, z))
    report = estimate_scale(sfm, iter(depth_frames), calib, ScaleConfig())
    # metres per SfM unit = 1 / 0.37
    assert report.scale == pytest.approx(1 / 0.37, rel=0.005)
    assert len(report.frames_used) == 8
    assert report.relative_spread < 0.01
    metric = apply_scale(sfm, report.scale, calib)
    # room frame: anchored at the first depth camera, z up; distances between cameras are metric
    first = metric[sfm.names[0]]
    assert np.allclose(first[:3, :3], ROOM_FROM_CAMERA_AXES, atol=1e-9) and np.allclose(
        first[:3, 3], 0, atol=1e-9
    )
    for k in range(1, 8):
        truth = np.linalg.inv(poses[0] @ rgb_from_ir) @ (poses[k] @ rgb_from_ir)
        est = np.linalg.inv(first) @ metric[sfm.names[k]]
        assert np.linalg.norm(est[:3, 3] - truth[:3, 3]) < 0.01
        assert np.allclose(est[:3, :3], truth[:3, :3], atol=1e-6)


def test_estimate_scale_fails_clearly_without_depth(rng):
    cam = small_camera()
    sfm, _ = fake_sfm(ring_poses(4), cam, 1.0, rng)
    empty = [(n, np.zeros((120, 160))) for n in sfm.names]
    with pytest.raises(DegenerateInputError, match="depth-matched SfM points"):
        estimate_scale(
            sfm, iter(empty), Calibration(cam, cam, RigidPose(np.eye(3), np.zeros(3))), ScaleConfig()
        )


def test_sfm_result_tables(rng):
    cam = small_camera()
    sfm, _ = fake_sfm(ring_poses(3), cam, 1.0, rng)
    cols = sfm.poses_columns()
    assert list(cols["name"]) == sfm.names and cols["registered"].all()
    R = Rotation.from_quat(np.column_stack([cols["qx"], cols["qy"], cols["qz"], cols["qw"]])).as_matrix()
    assert np.allclose(R[1], sfm.cam_from_world[sfm.names[1]][:3, :3])
    obs = sfm.observation_columns()
    assert len(obs["point"]) == sum(len(r) for r, _ in sfm.observations.values())


def test_apply_scale_rejects_bad_scale(rng):
    cam = small_camera()
    sfm, _ = fake_sfm(ring_poses(3), cam, 1.0, rng)
    with pytest.raises(DegenerateInputError, match="positive"):
        apply_scale(sfm, float("nan"), Calibration(cam))


# ------------------------------------------------------------------ known answer with Kinect v1 depth noise


def kinect_box_capture(
    seed: int, half_widths: tuple[float, float] = (1.5, 3.0)
) -> tuple[SfmResult, Calibration, list[tuple[str, NDArray]], float]:
    """A random box room seen from a ring of 10 poses by the Kinect v1 profile at 320x240 (its own
    intrinsics, lens distortion and IR→RGB pose), depth through the synthetic sensor's whole disparity
    chain (eq 6.2 Gaussian disparity noise, the radial pattern of thesis 6.1.2, 1/8 px and 1 mm
    quantization), and a canned SfM of the colour camera in units of `k` SfM units per metre. The box
    reaches `half_widths` (range of its half sizes, m) from the middle.
    Returns (sfm, calibration, (name, depth in metres) per frame, k)."""
    from tasks.camera import profile_calibration
    from tasks.config import load_sensor_profile
    from tasks.synth import sensor

    local = np.random.default_rng(seed)
    profile = load_sensor_profile("kinect_v1")
    full = profile_calibration(profile)
    calib = Calibration(full.ir.scaled((320, 240)), full.rgb.scaled((320, 240)), full.ir_to_rgb)
    a, b = half_widths
    lo = np.array([-local.uniform(a, b), -local.uniform(a, b - 0.5), 0.0])
    hi = np.array([local.uniform(a, b), local.uniform(a, b - 0.5), local.uniform(2.4, 3.0)])
    centre = np.array([local.uniform(-0.3, 0.3), local.uniform(-0.3, 0.3), 1.4])
    radius = local.uniform(0.3, 0.6)
    start = local.uniform(0, 2 * np.pi)
    rgb_from_ir = calib.ir_to_rgb.matrix
    poses_rgb = []
    for a in start + np.linspace(0, 2 * np.pi, 10, endpoint=False):
        world_from_ir = look_pose(centre + radius * np.array([np.cos(a), np.sin(a), 0.0]), a + 0.4)
        poses_rgb.append(world_from_ir @ np.linalg.inv(rgb_from_ir))
    k = local.uniform(0.2, 3.0)
    sfm, _world = fake_sfm(poses_rgb, calib.rgb, k, local, box=(lo, hi))
    weight = sensor._radial_weight(sensor.camera_model(profile, "ir", "mini"))
    frames = []
    for name, T_rgb in zip(sfm.names, poses_rgb, strict=True):
        z, _ = box_hits(calib.ir, T_rgb @ rgb_from_ir, (lo, hi))
        mm = sensor.simulate_depth_mm(z.ravel(), profile, local, weight).reshape(z.shape)
        frames.append((name, mm.astype(np.float64) / 1000.0))
    return sfm, calib, frames, k


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12, 13, 14])
def test_scale_from_kinect_v1_depth_is_unbiased(seed):
    """Known poses (true metric poses scaled by a known factor) and Kinect v1 depth with all its errors:
    the scale is the true one within 0.1 %, with the radial error estimated on the frames themselves.
    Left in, that error alone makes the scale short by more than 0.1 % (it grows towards the corners and
    with the range, so every frame reads short)."""
    from tasks.register.config import RegisterConfig
    from tasks.register.fusion import estimate_radial_depth_error

    sfm, calib, frames, k = kinect_box_capture(seed)
    radial = estimate_radial_depth_error(
        ((i, d, None) for i, (_n, d) in enumerate(frames)), calib, RegisterConfig()
    )
    assert radial.applied
    # the sensor's pattern: 0.1 px of disparity at the corners = 0.1 / b·c in inverse depth
    assert radial.k_inv_m == pytest.approx(0.1 / 43.93, rel=0.15)
    report = estimate_scale(sfm, iter(frames), calib, ScaleConfig(), radial.k_inv_m)
    assert report.scale * k == pytest.approx(1.0, abs=0.001)
    assert report.radial_k_inv_m == radial.k_inv_m
    assert report.to_json()["radial_k_inv_m"] == radial.k_inv_m
    uncorrected = estimate_scale(sfm, iter(frames), calib, ScaleConfig())
    assert uncorrected.scale * k < 0.999


def test_depth_in_rgb_averages_one_surface_in_inverse_depth_and_lets_the_nearest_win():
    """Two depth pixels landing on one colour pixel: readings of one surface (2.00 and 2.04 m) are averaged
    in inverse depth (2 / (1/2.00 + 1/2.04)), not the nearer taken; a surface farther than
    max_depth_step_m behind (2.50 m) is hidden by the nearer one."""
    from tasks.register.scale import depth_in_rgb

    ir = CameraModel(np.array([[100.0, 0, 1.5], [0, 100.0, 1.5], [0, 0, 1]]), np.zeros(5), (4, 4))
    rgb = CameraModel(np.array([[50.0, 0, 0.5], [0, 50.0, 0.5], [0, 0, 1]]), np.zeros(5), (2, 2))
    calib = Calibration(ir, rgb, RigidPose(np.eye(3), np.zeros(3)))
    cfg = ScaleConfig(depth_stride=1, max_depth_step_m=0.05)
    depth = np.zeros((4, 4))
    # IR pixels (row 1, col 1) and (row 1, col 0) project to colour pixel (0, 0) (both round there)
    depth[1, 1], depth[1, 0] = 2.0, 2.04
    depth[2, 2], depth[2, 3] = 2.5, 1.5  # colour pixel (1, 1): the 1.5 m surface hides the 2.5 m one
    z = depth_in_rgb(depth, calib, rgb, cfg)
    assert z[0, 0] == pytest.approx(2.0 / (1 / 2.0 + 1 / 2.04), rel=1e-6)
    assert z[1, 1] == pytest.approx(1.5, rel=1e-6)
    assert np.isnan(z[0, 1]) and np.isnan(z[1, 0])


def test_depth_noise_coefficient_known_spread():
    """Readings alternating ±δ about 2 m in a checkerboard: every complete 3x3 window spreads 2δ, so the
    coefficient is 2δ / 2²; windows touching a missing reading or the border do not count."""
    from tasks.register.scale import depth_noise_coefficient, step_tolerance

    delta = 0.01
    i, j = np.mgrid[0:12, 0:16]
    depth = 2.0 + delta * np.where((i + j) % 2 == 0, 1.0, -1.0)
    depth[5, 5] = np.nan
    depth[0, :] = 0.0
    assert depth_noise_coefficient(depth) == pytest.approx(2 * delta / 4.0, rel=0.02)
    assert depth_noise_coefficient(np.full((5, 5), np.nan)) == 0.0
    cfg = ScaleConfig(max_depth_step_m=0.05, step_noise_factor=3.0)
    tol = step_tolerance(np.array([1.0, 3.0]), cfg, 0.01)
    assert tol == pytest.approx([0.05, 0.27])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [11, 12, 13, 14])
def test_scale_from_far_kinect_v1_walls_is_unbiased(seed):
    """SfM points mostly lie on far textured walls (in the synthetic surveys 95 % beyond 3 m), where a Kinect's
    depth steps are 3-4 cm: known poses and only observations beyond 2.8 m give the true scale within
    0.05 % from every frame. A fixed 5 cm edge test dropped the windows whose noise spread far and kept the
    nearer-reading ones (-0.075 % on seed 11, and frames lost on three seeds)."""
    from dataclasses import replace

    from tasks.register.config import RegisterConfig
    from tasks.register.fusion import estimate_radial_depth_error

    sfm, calib, frames, k = kinect_box_capture(seed, (3.8, 4.8))
    far_obs = {}
    for name, (rows, uv) in sfm.observations.items():
        T = sfm.cam_from_world[name]
        far = (sfm.points[rows] @ T[2, :3] + T[2, 3]) / k > 2.8
        far_obs[name] = (rows[far], uv[far])
    assert min(len(r) for r, _ in far_obs.values()) > 300
    radial = estimate_radial_depth_error(
        ((i, d, None) for i, (_n, d) in enumerate(frames)), calib, RegisterConfig()
    )
    report = estimate_scale(
        replace(sfm, observations=far_obs), iter(frames), calib, ScaleConfig(), radial.k_inv_m
    )
    assert report.scale * k == pytest.approx(1.0, abs=0.0005)
    assert len(report.frames_used) == len(frames)
    # 9 readings of a Kinect spread about 3 raw disparity steps of 1/8 px: 3 · 0.125 / b·c per m²
    assert report.depth_noise_m_at_1m == pytest.approx(3 * 0.125 / 43.93, rel=0.3)
    assert report.to_json()["depth_noise_m_at_1m"] == report.depth_noise_m_at_1m


def test_scale_error_is_the_similarity_scale_not_the_path_length():
    """metrics.json's scale error (`tasks.benchmark.similarity_scale`): a handheld trajectory (24 frames,
    0.2-0.6 m steps) made 0.3 % large, turned and moved, gives 1.003 exactly; with 3 mm of position noise
    and the first camera 3.6 cm off along its step (the case of data/mini r2) it stays within the 0.15 %
    the scale must meet on each of 8 draws, while the path-length ratio is off by more on every one."""
    from tasks.benchmark import similarity_scale

    def path(p: NDArray[np.float64]) -> float:
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    R = Rotation.from_euler("zyx", [40, 3, -2], degrees=True).as_matrix()
    for seed in range(8):
        rng = np.random.default_rng(seed)
        heading = np.linspace(0, 5, 24)
        dirs = np.column_stack([np.cos(heading), np.sin(heading), 0.05 * rng.standard_normal(24)])
        steps = rng.uniform(0.2, 0.6, 24)[:, None] * dirs
        true = np.cumsum(steps, axis=0)
        exact = 1.003 * true @ R.T + np.array([5.0, -2.0, 0.3])
        assert similarity_scale(exact, true) == pytest.approx(1.003, abs=1e-9)
        noisy = exact + 0.003 * rng.standard_normal(exact.shape)
        noisy[0] += 0.036 * steps[0] / np.linalg.norm(steps[0])
        sim_error = abs(similarity_scale(noisy, true) - 1.003)
        assert sim_error < 0.0015
        assert abs(path(noisy) / path(true) - 1.003) > max(sim_error, 0.0015)
    assert np.isnan(similarity_scale(true[:1], true[:1]))
