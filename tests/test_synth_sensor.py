"""Synthetic sensors (issue 3, SENSOR half): depth error model, rendering geometry, walks, MCAP capture,
calibration set, TLS cloud. Inputs are box rooms built here with known answers. That SfM registers the
rendered frames of a walked room is tested on data/mini's rooms (test_register.py, on the session's run)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from shapely.geometry import Polygon, box

from tasks.synth.calibration_set import CalibrationSetConfig
from tasks.synth.capture import write_capture_mcap
from tasks.synth.scene import Material, SceneMesh
from tasks.synth.sensor import (
    INVALID_DISPARITY,
    camera_model,
    depth_from_raw_disparity,
    depth_sigma_m,
    pixel_rays,
    render_depth_mm,
    render_rgbd,
    render_tls_cloud,
    rgb_pose,
)
from tasks.synth.walk import plan_walk

REPO = Path(__file__).resolve().parents[1]


def _profile(name: str) -> dict:
    return yaml.safe_load((REPO / "configs" / "sensors" / f"{name}.yaml").read_text())


def _quad(p0, u, v) -> np.ndarray:
    p0, u, v = (np.asarray(x, dtype=np.float64) for x in (p0, u, v))
    return np.array([p0, p0 + u, p0 + u + v, p0 + v])


def box_room(
    w: float = 5.0, d: float = 4.0, h: float = 2.7, seed: int = 0, extras: list | None = None
) -> SceneMesh:
    """A w x d x h box room (x in [0, w], y in [0, d]) with painted walls, a floor, a ceiling, two posters;
    `extras` adds (kind, p0, u, v) quads."""
    quads: list[tuple[np.ndarray, int]] = []
    mats: list[Material] = []

    def add(kind, rgb, p0, u, v, scale):
        un = np.asarray(u, float) / np.linalg.norm(u)
        vn = np.asarray(v, float) / np.linalg.norm(v)
        mats.append(Material(kind, rgb, seed + 7 * len(mats), tuple(p0), tuple(un), tuple(vn), scale))
        quads.append((_quad(p0, u, v), len(mats) - 1))

    ez = (0, 0, h)
    add("paint", (200, 190, 170), (0, 0, 0), (w, 0, 0), ez, 0.25)
    add("paint", (180, 200, 190), (w, 0, 0), (0, d, 0), ez, 0.25)
    add("paint", (190, 180, 200), (w, d, 0), (-w, 0, 0), ez, 0.25)
    add("paint", (210, 200, 180), (0, d, 0), (0, -d, 0), ez, 0.25)
    add("floor", (150, 120, 90), (0, 0, 0), (w, 0, 0), (0, d, 0), 0.4)
    add("ceiling", (235, 235, 230), (0, 0, h), (w, 0, 0), (0, d, 0), 0.5)
    add("poster", (240, 240, 240), (1.0, 0.01, 0.9), (1.2, 0, 0), (0, 0, 0.9), 0.3)
    add("poster", (240, 240, 240), (w - 0.01, 1.0, 0.8), (0, 1.4, 0), (0, 0, 1.0), 0.35)
    for kind, p0, u, v in extras or []:
        add(kind, (30, 30, 30) if kind == "dark" else (200, 225, 235), p0, u, v, 0.5)
    verts = np.concatenate([q for q, _ in quads])
    tris = np.array(
        [[4 * k, 4 * k + 1, 4 * k + 2] for k in range(len(quads))]
        + [[4 * k, 4 * k + 2, 4 * k + 3] for k in range(len(quads))],
        dtype=np.int32,
    )
    mat = np.array([m for _, m in quads] * 2, dtype=np.int32)
    return SceneMesh(vertices=verts, triangles=tris, material=mat, materials=tuple(mats))


def look_at(eye, target) -> np.ndarray:
    """Camera-to-plan pose of an OpenCV camera at `eye` looking at `target` with no roll."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, (0, 0, 1))
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = eye
    return pose


def _analytic_z_to_plane(pose: np.ndarray, cam, normal, offset) -> np.ndarray:
    """z-depth (H, W) of each pixel's ray to the plane normal . X = offset."""
    rays = pixel_rays(cam) @ pose[:3, :3].T
    t = (offset - normal @ pose[:3, 3]) / (rays @ normal)
    return t.reshape(cam.height, cam.width)


# ------------------------------------------------------------------------------------------------ depth


def test_pixel_rays_reproject_to_their_pixels():
    prof = _profile("kinect_v1")
    for stream in ("ir", "rgb"):
        cam = camera_model(prof, stream, "mini")
        rays = pixel_rays(cam)
        uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), cam.K, cam.dist)
        uu, vv = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
        err = np.linalg.norm(uv.reshape(-1, 2) - np.stack([uu.ravel(), vv.ravel()], axis=1), axis=1)
        assert err.max() < 1e-3, f"{stream}: undistorted rays reproject {err.max():.2e} px off"


@pytest.mark.parametrize("size", ["mini", "full"])
def test_noise_free_depth_matches_analytic_wall_distance(size):
    """Perpendicular and oblique views of a wall: every depth pixel equals the analytic z-depth within half
    a disparity quantization step (eq 3.12) plus the 1 mm output rounding."""
    prof = _profile("kinect_v1")
    dm = prof["depth"]
    mesh = box_room(w=8.0, d=6.0, h=3.0)
    cam = camera_model(prof, "ir", size)
    for eye, target in [((4.0, 2.0, 1.5), (4.0, 0.0, 1.5)), ((5.5, 3.0, 1.4), (4.0, 0.0, 1.0))]:
        pose = look_at(eye, target)
        depth = render_depth_mm(mesh, pose, prof, size, np.random.default_rng(0), noise=False)
        z = _analytic_z_to_plane(pose, cam, np.array([0.0, 1.0, 0.0]), 0.0)
        # pixels whose ray reaches the y = 0 wall inside the room (not the floor, the ceiling or a poster)
        hit = pose[:3, 3] + (pixel_rays(cam) @ pose[:3, :3].T) * z.reshape(-1, 1)
        on_wall = ((hit[:, 0] > 0.05) & (hit[:, 0] < 7.95) & (hit[:, 2] > 0.05) & (hit[:, 2] < 2.95)).reshape(
            z.shape
        )
        on_wall &= ~(
            ((hit[:, 0] > 0.95) & (hit[:, 0] < 2.25) & (hit[:, 2] > 0.85) & (hit[:, 2] < 1.85)).reshape(
                z.shape
            )
        )
        assert on_wall.mean() > 0.5
        measured = depth[on_wall].astype(float) / 1000.0
        truth = z[on_wall]
        half_step = truth**2 / (8.0 * dm["disparity_bc_m_px"]) / 2.0
        err = np.abs(measured - truth)
        assert np.all(measured > 0), "no-return pixels on a plain painted wall"
        assert np.all(err <= half_step * 1.02 + 0.0006), f"max error {err.max() * 1000:.1f} mm"


@pytest.mark.parametrize("name", ["kinect_v2", "realsense_d435"])
def test_noise_free_depth_other_profiles_is_exact_to_the_mm(name):
    prof = _profile(name)
    mesh = box_room(w=8.0, d=6.0, h=3.0)
    cam = camera_model(prof, "ir", "mini")
    pose = look_at((4.0, 2.2, 1.5), (4.0, 0.0, 1.5))
    depth = render_depth_mm(mesh, pose, prof, "mini", np.random.default_rng(0), noise=False)
    z = _analytic_z_to_plane(pose, cam, np.array([0.0, 1.0, 0.0]), 0.0)
    centre = (slice(cam.height // 3, 2 * cam.height // 3), slice(cam.width // 3, 2 * cam.width // 3))
    assert np.abs(depth[centre] / 1000.0 - z[centre]).max() <= 0.0005 + 1e-9


def _plane_fit_rms(depth_mm: np.ndarray, frac: float = 0.3) -> float:
    """RMS (m) of the residuals of a least-squares plane z = a u + b v + c over the central region."""
    h, w = depth_mm.shape
    r0, r1 = int(h * (0.5 - frac / 2)), int(h * (0.5 + frac / 2))
    c0, c1 = int(w * (0.5 - frac / 2)), int(w * (0.5 + frac / 2))
    z = depth_mm[r0:r1, c0:c1].astype(float) / 1000.0
    vv, uu = np.mgrid[r0:r1, c0:c1]
    ok = z > 0
    A = np.stack([uu[ok], vv[ok], np.ones(ok.sum())], axis=1).astype(float)
    coef, *_ = np.linalg.lstsq(A, z[ok], rcond=None)
    return float(np.sqrt(np.mean((z[ok] - A @ coef) ** 2)))


@pytest.mark.parametrize("name", ["kinect_v1", "kinect_v2", "realsense_d435"])
def test_depth_noise_per_distance_matches_the_model(name):
    """Plane fit on the centre of flat perpendicular walls at 1, 2 and 3 m (thesis figure 6.4 protocol):
    the RMS matches the model sigma (eq 6.2 with 1/8 px quantization for Kinect v1) within 20 %."""
    prof = _profile(name)
    rng = np.random.default_rng(42)
    mesh = box_room(w=10.0, d=8.0, h=4.0)
    measured, model = [], []
    for dist in (1.0, 2.0, 3.0):
        pose = look_at((5.0, dist, 2.0), (5.0, 0.0, 2.0))
        rms = [_plane_fit_rms(render_depth_mm(mesh, pose, prof, "full", rng)) for _ in range(2)]
        measured.append(float(np.mean(rms)))
        model.append(float(depth_sigma_m(dist, prof)))
    ratio = np.array(measured) / np.array(model)
    assert np.all(np.abs(ratio - 1.0) < 0.2), (
        f"measured {np.round(measured, 4)} m vs model {np.round(model, 4)} m"
    )
    if name == "kinect_v1":
        # eq 6.2: quadratic growth, sigma(3 m) / sigma(1 m) = 9
        assert 7.0 < measured[2] / measured[0] < 11.0


def test_kinect_radial_error_grows_towards_the_corners():
    """Thesis 6.1.2: a flat wall looks bowl-shaped, the corners nearer by about radial_error_px in disparity."""
    prof = _profile("kinect_v1")
    bc = prof["depth"]["disparity_bc_m_px"]
    mesh = box_room(w=10.0, d=8.0, h=4.0)
    pose = look_at((5.0, 2.0, 2.0), (5.0, 0.0, 2.0))
    rng = np.random.default_rng(1)
    frames = [render_depth_mm(mesh, pose, prof, "full", rng).astype(float) for _ in range(4)]
    diff = np.mean(frames, axis=0) - 2000.0  # mm, against the true 2 m z-depth
    corner = np.concatenate([diff[:40, :40].ravel(), diff[-40:, -40:].ravel()])
    centre = diff[220:260, 300:340]
    expected_mm = 4.0 / bc * 0.1 * 0.88 * 1000  # H^2/bc * radial_error_px * mean weight of the corner patch
    assert abs(centre.mean()) < 1.5
    assert -corner.mean() == pytest.approx(expected_mm, rel=0.3)


def test_disparity_quantization_levels_follow_eq_3_12():
    """A wall seen obliquely from 1-5 m: every depth value is a level of eq 3.12 (integer raw disparity),
    and consecutive levels are spaced H^2 / (8 b c) apart."""
    prof = _profile("kinect_v1")
    dm = prof["depth"]
    mesh = box_room(w=12.0, d=4.0, h=3.0)
    pose = look_at((0.6, 2.0, 1.5), (11.0, 0.3, 1.5))
    levels_mm = np.rint(depth_from_raw_disparity(np.arange(0, INVALID_DISPARITY), dm) * 1000.0)
    level_set = set(levels_mm[np.isfinite(levels_mm)].astype(int).tolist())
    for noise in (False, True):
        depth = render_depth_mm(mesh, pose, prof, "full", np.random.default_rng(3), noise=noise)
        values = np.unique(depth[depth > 0]).astype(int)
        assert len(values) > 50
        assert set(values.tolist()) <= level_set, "depth values off the eq 3.12 levels"
    values = values[(values > 1000) & (values < 5000)].astype(float)
    gaps = np.diff(values)
    mid = (values[1:] + values[:-1]) / 2000.0
    predicted = mid**2 / (8.0 * dm["disparity_bc_m_px"]) * 1000.0
    # adjacent levels (noise fills every level between 1 and 5 m)
    adjacent = gaps < 1.5 * predicted
    assert adjacent.mean() > 0.95
    assert np.all(np.abs(gaps[adjacent] - predicted[adjacent]) <= 0.02 * predicted[adjacent] + 1.0)
    # at 5.5 m the thesis expects a resolution above 8 cm
    assert 5.5**2 / (8.0 * dm["disparity_bc_m_px"]) > 0.08


def test_no_return_from_glass_dark_and_beyond_max_range():
    prof = _profile("kinect_v1")
    extras = [
        ("glass", (3.0, 0.3, 0.8), (1.5, 0, 0), (0, 0, 1.2)),  # a pane in front of the y = 0 wall
        ("dark", (5.0, 0.02, 0.5), (1.0, 0, 0), (0, 0, 1.5)),  # a black panel on the wall
    ]
    mesh = box_room(w=9.0, d=12.0, h=3.0, extras=extras)
    cam = camera_model(prof, "ir", "mini")
    rng = np.random.default_rng(0)
    pose = look_at((4.5, 2.5, 1.4), (4.5, 0.0, 1.4))
    rgb, depth = render_rgbd(mesh, pose, prof, "mini", rng)

    def pixel(x, z, y=0.02):
        p = np.linalg.inv(pose) @ np.array([x, y, z, 1.0])
        uv, _ = cv2.projectPoints(p[None, :3], np.zeros(3), np.zeros(3), cam.K, cam.dist)
        return int(np.rint(uv[0, 0, 1])), int(np.rint(uv[0, 0, 0]))

    assert depth[pixel(3.75, 1.4, 0.3)] == 0, "depth from glass"
    assert depth[pixel(5.5, 1.2)] == 0, "depth from a dark surface"
    assert depth[pixel(4.5, 2.3)] > 0
    # glass shows what is behind it (the painted wall), paler; dark has a colour
    assert rgb.reshape(-1, 3).std(axis=0).max() > 10
    # the far wall at 11.5 m is beyond 6 m: no return; the near wall is measured
    _, far = render_rgbd(mesh, look_at((4.5, 0.5, 1.4), (4.5, 12.0, 1.4)), prof, "mini", rng)
    centre = far[100:140, 140:180]
    assert np.all(centre == 0)


def test_rendering_is_deterministic_and_rgb_sits_at_the_ir_to_rgb_offset():
    prof = _profile("kinect_v1")
    mesh = box_room()
    pose = look_at((2.5, 3.0, 1.4), (2.0, 0.0, 1.2))
    a = render_rgbd(mesh, pose, prof, "mini", np.random.default_rng(9))
    b = render_rgbd(mesh, pose, prof, "mini", np.random.default_rng(9))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert a[0].shape == (240, 320, 3) and a[1].shape == (240, 320) and a[1].dtype == np.uint16
    rel = np.linalg.inv(pose) @ rgb_pose(pose, prof)
    assert rel[:3, 3] == pytest.approx([0.0239, 0.0012, 0.0007], abs=1e-9)
    # enough texture for SIFT on a painted wall with a poster
    sift = cv2.SIFT_create()
    assert len(sift.detect(cv2.cvtColor(a[0], cv2.COLOR_RGB2GRAY))) > 150


def test_render_rejects_bad_input():
    prof = _profile("kinect_v1")
    mesh = box_room()
    with pytest.raises(ValueError, match="size"):
        render_rgbd(mesh, np.eye(4), prof, "huge", np.random.default_rng(0))
    with pytest.raises(ValueError, match="4x4"):
        render_rgbd(mesh, np.eye(3), prof, "mini", np.random.default_rng(0))
    with pytest.raises(ValueError, match="RGB-D"):
        render_rgbd(mesh, np.eye(4), _profile("tls"), "mini", np.random.default_rng(0))


# ------------------------------------------------------------------------------------------------ TLS


def test_tls_cloud_has_mm_noise_and_no_glass_returns():
    extras = [("glass", (4.99, 1.0, 0.9), (0, 1.5, 0), (0, 0, 1.2))]
    mesh = box_room(w=5.0, d=4.0, h=2.7, extras=extras)
    pts, cols = render_tls_cloud(mesh, np.array([[2.0, 2.0, 1.5], [3.5, 1.5, 1.5]]), np.random.default_rng(0))
    assert pts.dtype == np.float64 and cols.dtype == np.uint8 and len(pts) == len(cols)
    assert 60_000 < len(pts) < 250_000
    on_x0 = np.abs(pts[:, 0]) < 0.02
    sigma = np.std(pts[on_x0, 0])
    assert sigma == pytest.approx(0.002, rel=0.2)
    # the glass pane sits 1 cm in front of the x = 5 wall: nothing measured on it
    pane = (np.abs(pts[:, 0] - 4.99) < 0.004) & (pts[:, 1] > 1.05) & (pts[:, 1] < 2.45) & (pts[:, 2] > 1.0)
    pane &= pts[:, 2] < 2.0
    wall_behind = (np.abs(pts[:, 0] - 5.0) < 0.008) & (pts[:, 1] > 1.05) & (pts[:, 1] < 2.45)
    assert wall_behind.sum() > 100
    assert pane.sum() < 0.5 * wall_behind.sum()


# ------------------------------------------------------------------------------------------------ walk


ROOMS = {
    "rectangular": box(0, 0, 5, 4),
    "l_shaped": Polygon([(0, 0), (6, 0), (6, 3), (3, 3), (3, 6), (0, 6)]),
    "slanted": Polygon([(0, 0), (5, 0), (5 + 4 / np.tan(np.radians(70)), 4), (0, 4)]),
    "corridor": box(0, 0, 14, 1.8),
}


@pytest.mark.parametrize("name", list(ROOMS))
def test_walk_stays_inside_looks_level_and_turns_smoothly(name):
    poly = ROOMS[name]
    corridor = name == "corridor"
    poses, t_ns = plan_walk(poly, 2.7, 30, np.random.default_rng(4), texture_poor=corridor)
    assert poses.shape == (30, 4, 4) and t_ns.dtype == np.int64 and np.all(np.diff(t_ns) > 0)
    inner = poly.buffer(-0.5)
    assert all(inner.contains(__import__("shapely").Point(p[0, 3], p[1, 3])) for p in poses)
    assert np.all((poses[:, 2, 3] >= 1.2) & (poses[:, 2, 3] <= 1.6))
    forward = poses[:, :3, 2]
    pitch = np.degrees(np.arcsin(forward[:, 2]))
    assert np.all(np.abs(pitch) < 20)
    right = poses[:, :3, 0]
    roll = np.degrees(np.arcsin(right[:, 2]))
    assert np.all(np.abs(roll) < 8)
    R = poses[:, :3, :3]
    steps = np.degrees([np.arccos(np.clip((np.trace(R[i].T @ R[i + 1]) - 1) / 2, -1, 1)) for i in range(29)])
    if not corridor:
        assert steps.max() < 35 and steps.mean() < 20  # a hand-held sweep, still fine for sequential SfM
        # the facing direction goes once around: every wall direction is looked at
        yaw = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
        assert abs(yaw[-1] - yaw[0]) > np.radians(300)
    det = np.linalg.det(R)
    assert np.allclose(det, 1.0)
    again, _ = plan_walk(poly, 2.7, 30, np.random.default_rng(4), texture_poor=corridor)
    assert np.array_equal(poses, again)


def test_walk_rejects_a_room_too_narrow():
    with pytest.raises(ValueError, match="too narrow"):
        plan_walk(box(0, 0, 5, 1.0), 2.7, 20, np.random.default_rng(0))


# ------------------------------------------------------------------------------------------------ MCAP


def test_capture_mcap_round_trip_and_determinism(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    prof = _profile("kinect_v1")
    mesh = box_room()
    poses, t_ns = plan_walk(box(0, 0, 5, 4), 2.7, 4, np.random.default_rng(2))
    consumed = []

    def frames(seed):
        rng = np.random.default_rng(seed)
        for pose, t in zip(poses, t_ns, strict=True):
            rgb, depth = render_rgbd(mesh, pose, prof, "mini", rng)
            consumed.append(t)
            yield int(t), rgb, depth

    imu = [
        (int(t_ns[0]) + k * 10_000_000, np.array([0.0, 0.01, 0.0]), np.array([0.0, 0.0, 9.81]))
        for k in range(5)
    ]
    write_capture_mcap(tmp_path / "a.mcap", frames(1), prof, "mini", imu=imu)
    write_capture_mcap(tmp_path / "b.mcap", frames(1), prof, "mini", imu=imu)
    digest = [hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in ("a.mcap", "b.mcap")]
    assert digest[0] == digest[1]
    rng = np.random.default_rng(1)
    first_rgb, first_depth = render_rgbd(mesh, poses[0], prof, "mini", rng)
    topics = prof["topics"]
    seen: dict[str, int] = {}
    with open(tmp_path / "a.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            if channel.topic == topics["depth"] and seen[channel.topic] == 1:
                assert schema.name == "sensor_msgs/msg/Image" and msg.encoding == "16UC1"
                depth = np.frombuffer(msg.data, dtype="<u2").reshape(msg.height, msg.width)
                assert np.array_equal(depth, first_depth)
                assert message.log_time == t_ns[0]
            if channel.topic == topics["rgb_compressed"] and seen[channel.topic] == 1:
                assert msg.format == "jpeg"
                img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
                assert np.abs(img.astype(int) - first_rgb.astype(int)).mean() < 4
            if channel.topic == topics["depth_info"]:
                assert msg.distortion_model == "plumb_bob" and msg.width == 320
                assert list(msg.k) == pytest.approx(np.ravel(camera_model(prof, "ir", "mini").K).tolist())
                assert list(msg.d) == pytest.approx(prof["ir"]["dist"])
            if channel.topic == topics["rgb_info"]:
                assert list(msg.d) == pytest.approx(prof["rgb"]["dist"])
    assert seen == {
        topics["rgb_compressed"]: 4,
        topics["depth"]: 4,
        topics["rgb_info"]: 1,
        topics["depth_info"]: 1,
        topics["imu"]: 5,
    }


def test_capture_rejects_wrong_frame_sizes(tmp_path):
    prof = _profile("kinect_v1")
    bad = [(1, np.zeros((480, 640, 3), np.uint8), np.zeros((240, 320), np.uint16))]
    with pytest.raises(ValueError, match="colour frame"):
        write_capture_mcap(tmp_path / "x.mcap", bad, prof, "mini")
    with pytest.raises(ValueError, match="no frames"):
        write_capture_mcap(tmp_path / "y.mcap", [], prof, "mini")


# ------------------------------------------------------------------------------------------------ calibration set


@pytest.mark.slow
def test_calibration_set_recovers_its_truth(generator_calibration_set):
    """The chessboard views calibrate (OpenCV) to the true intrinsics, and the flat-target raw disparities
    fit eq 3.11-3.12 to the true offset and b*c. The session's full-size set (tests/conftest.py), its first
    `n_views` views: those hold the whole board in both images (OpenCV needs whole views; the RGB edge
    views after them do not)."""
    folder, truth = generator_calibration_set("full")
    cfg = CalibrationSetConfig()
    cols, rows = cfg.inner_corners
    obj = np.zeros((cols * rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * cfg.square_m
    for stream in ("ir", "rgb"):
        files = sorted((folder / stream).glob("*.png"))[: cfg.n_views]
        assert len(files) >= 8
        img_pts = []
        for f in files:
            g = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            ok, corners = cv2.findChessboardCorners(g, (cols, rows))
            assert ok, f"no chessboard found in {f.name}"
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
            img_pts.append(cv2.cornerSubPix(g, corners, (5, 5), (-1, -1), crit))
        size = tuple(truth[stream]["size"])
        rms, K, dist, *_ = cv2.calibrateCamera([obj] * len(img_pts), img_pts, size, None, None)
        K_true = np.array(truth[stream]["K"])
        assert rms < 0.15
        assert K[0, 0] == pytest.approx(K_true[0, 0], rel=0.005)
        assert K[1, 2] == pytest.approx(K_true[1, 2], abs=2.0)
        # distortion: the true and the fitted model map image points alike (within 0.3 px) wherever the
        # views put corners (the set covers the image to within a few squares of its corners)
        hull = cv2.convexHull(np.concatenate(img_pts).reshape(-1, 2))
        assert cv2.contourArea(hull) > 0.5 * size[0] * size[1]
        uu, vv = np.meshgrid(np.linspace(0, size[0] - 1, 32), np.linspace(0, size[1] - 1, 24))
        grid = np.stack([uu.ravel(), vv.ravel()], axis=1)
        inside = [cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in grid]
        pix = grid[np.array(inside)].reshape(-1, 1, 2)
        # the distortion alone: the same ideal rays through the true and the fitted polynomial
        rays = cv2.undistortPoints(pix, K_true, np.array(truth[stream]["dist"])).reshape(-1, 2)
        rays3 = np.concatenate([rays, np.ones((len(rays), 1))], axis=1)
        a, _ = cv2.projectPoints(rays3, np.zeros(3), np.zeros(3), K_true, np.array(truth[stream]["dist"]))
        b, _ = cv2.projectPoints(rays3, np.zeros(3), np.zeros(3), K_true, dist)
        assert np.abs(a - b).max() < 0.3
    meta = yaml.safe_load((folder / "flat.yaml").read_text())
    dk, inv_h = [], []
    for name, dist in zip(meta["files"], meta["distances_m"], strict=True):
        raw = cv2.imread(str(folder / "flat" / name), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16 and raw.max() <= INVALID_DISPARITY
        shift = int(meta["shift_px"])
        assert np.all(raw[:, -shift:] == INVALID_DISPARITY) and np.all(raw[:, :-shift] < INVALID_DISPARITY)
        dk.append(raw[200:280, 280:360].mean())
        inv_h.append(1.0 / dist)
    # eq 3.11-3.12: d_k = offset - 8 b c / H, linear in 1/H
    slope, offset = np.polyfit(inv_h, dk, 1)
    model = truth["depth_model"]
    assert offset == pytest.approx(model["offset"], rel=0.01)
    assert -slope / 8.0 == pytest.approx(model["bc_m_px"], rel=0.01)
