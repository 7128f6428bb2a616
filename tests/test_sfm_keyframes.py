"""SfM with key frames (issue #18): key frames chosen from the verified matches are mapped, every other frame
is posed against their map."""

from __future__ import annotations

import numpy as np
import pytest

from tasks.camera import CameraModel
from tasks.register.config import SfmConfig
from tasks.register.sfm import run_sfm, select_keyframes
from tasks.synth.box_views import look_pose, render
from tests.scenes import ate_after_similarity


def _decaying(n: int, per_frame: float, full: int = 1000, broken: tuple[int, ...] = ()):
    """inliers(i, j) of a walk whose overlap falls by `per_frame` of the features per frame of separation;
    a pair across one of `broken` (a frame index i whose link to i + 1 is cut) has none."""

    def inliers(i: int, j: int) -> int:
        if any(i <= b < j for b in broken):
            return 0
        return max(int(full * (1 - per_frame * (j - i))), 0)

    return inliers


def test_key_frames_follow_the_tracked_share():
    # 10 % lost per frame: k+1 keeps 900, the segment runs while >= 450 are kept (j - k <= 5)
    keys = select_keyframes(21, _decaying(21, 0.1), 0.5, 15, window=10)
    assert keys == [0, 5, 10, 15, 20]
    # a window of 3 frames ends the segments earlier, the last frame is always a key frame
    assert select_keyframes(11, _decaying(11, 0.1), 0.5, 15, window=3) == [0, 3, 6, 9, 10]
    # a broken chain (no match from 7 on to 8) makes 8 a key frame, 7 the last of its segment
    keys = select_keyframes(21, _decaying(21, 0.1, broken=(7,)), 0.5, 15, window=10)
    assert 7 in keys and 8 in keys and keys[0] == 0 and keys[-1] == 20
    # fast motion (60 % lost per frame): every frame is a key frame
    assert select_keyframes(6, _decaying(6, 0.6), 0.5, 15, window=5) == list(range(6))
    assert select_keyframes(1, _decaying(1, 0.1), 0.5, 15, window=5) == [0]


@pytest.mark.slow
def test_walk_maps_key_frames_and_localizes_the_rest(tmp_path):
    """A slow 320x240 turn (0.04 rad and 4 cm per frame): fewer key frames than frames, every frame posed,
    the localized frames as accurate as the mapped ones, their observations real pixels of map points,
    and a second run repeats the first to the bit."""
    w, h, f = 320, 240, 260.0
    cam = CameraModel(np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]]), np.zeros(5), (w, h))
    poses = [
        look_pose(np.array([0.2 + 0.04 * k, -0.3, 1.3]), 0.5 + 0.04 * k, pitch_rad=-0.2) for k in range(24)
    ]
    images = [(f"v{k:02d}.png", render(cam, T)[1]) for k, T in enumerate(poses)]
    cfg = SfmConfig(matching="sequential")
    res = run_sfm(images, cam, cfg, tmp_path / "a")
    m = res.metrics
    assert m["keyframes"] < len(images) and m["localized"] == len(images) - m["keyframes"]
    assert res.registered.all()
    centres = res.camera_centres()
    A = np.array([centres[n] for n, _ in images])
    B = np.array([T[:3, 3] for T in poses])
    assert ate_after_similarity(A, B)[0] < 0.015  # 7.3 mm (mapping every frame: 12.6 mm)
    assert len(res.keyframes) == m["keyframes"] and res.keyframes[0] == "v00.png"
    # a localized frame's observations reproject onto its pixels like a mapped frame's
    localized = [n for n, _ in images if n not in res.keyframes]
    assert len(localized) == m["localized"]
    for name in localized:
        rows, uv = res.observations[name]
        T = res.cam_from_world[name]
        proj, _ = cam.project(res.points[rows] @ T[:3, :3].T + T[:3, 3])
        assert len(rows) >= cfg.localize_min_inliers
        assert np.median(np.linalg.norm(proj - uv, axis=1)) < 1.0
    again = run_sfm(images, cam, cfg, tmp_path / "b")
    for n, _ in images:
        assert np.array_equal(again.cam_from_world[n], res.cam_from_world[n])
    assert np.array_equal(again.points, res.points)
