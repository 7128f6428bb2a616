"""Synthetic calibration set of an RGB-D sensor (thesis 6.1): chessboard views through both cameras and
flat-target raw disparity frames at known distances, with the true calibration.

Each chessboard image is an inverse-mapped warp: every output pixel is undistorted to a ray through the camera's true K and distortion, intersected with the board plane and
a high-res board texture, pre-filtered to the pixel footprint, is sampled there. IR and RGB views are synchronized (one board pose, seen by
both cameras through the true IR->RGB pose).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from tasks.synth.sensor import (
    INVALID_DISPARITY,
    CameraModel,
    SensorConfig,
    _radial_weight,
    camera_model,
    ir_to_rgb_transform,
    kinect_raw_disparity,
    pixel_rays,
)


@dataclass(frozen=True)
class CalibrationSetConfig:
    """The synthetic calibration target and views."""

    inner_corners: tuple[int, int] = (9, 6)
    """Chessboard inner corners (columns, rows)."""
    square_m: float = 0.04
    """Chessboard square size (m)."""
    n_views: int = 14
    """Number of synchronized IR + RGB chessboard views with the whole board in both images (at least 8)."""
    n_rgb_edge_views: int = 8
    """Further synchronized views with the board pushed into the RGB image's corners (each corner twice, then the
    edge middles), where the narrower IR image mostly sees it only partly: they fill the RGB image format (thesis 3.1.2) so its distortion is
    measured there, not extrapolated; the calibration rejects their IR images as partial."""
    edge_distance_range_m: tuple[float, float] = (0.55, 1.15)
    """Board distances of the edge views (m). The first round of corners takes the near half (the IR image
    often sees those boards whole: complete pairs near the IR corners), the next the far half (smaller squares
    come closer to the RGB corners)."""
    edge_margin_px: float = 3.0
    """Least gap between the image border and the board's outer squares plus `edge_white_squares` of white
    around them in the views pushed into corners and edges (px at the rendered size)."""
    edge_white_squares: float = 0.3
    """White border (in squares) kept in view around the outer squares: the detector needs them whole."""
    edge_min_square_px: float = 7.0
    """Least side of a projected square in the RGB image of the edge views (px at the rendered size): smaller
    squares of a far, tilted board are not found reliably."""
    edge_min_ir_corners: float = 0.25
    """Least share of the inner corners an edge view shows the IR camera (so its IR image holds a partial
    target, which the calibration rejects as partial, never an empty one, which it treats as an error)."""
    distance_range_m: tuple[float, float] = (0.55, 1.1)
    """Board distances from the IR camera (m)."""
    max_tilt_deg: float = 40.0
    """Largest board tilt of the oblique views (deg)."""
    flat_distances_m: tuple[float, ...] = (0.7, 0.9, 1.2, 1.5, 1.9, 2.4, 3.0, 3.6)
    """Distances of the flat-target disparity frames (m), perpendicular to the optical axis."""
    image_noise_dn: float = 2.0
    """Gaussian image noise of the chessboard views (digital numbers)."""
    blur_sigma_px: float = 0.5
    """Optical blur of the chessboard views (px)."""


def board_pose(
    roll_deg: float,
    tilt_x_deg: float,
    tilt_y_deg: float,
    centre_m: NDArray[np.float64],
    board_centre: NDArray,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Board-to-camera rotation and translation (X_cam = R X_board + t) placing the board's centre point
    `board_centre` (board frame, z = 0) at camera point `centre_m`, rotated about the optical axis by
    roll and tilted about the board's x and y axes."""
    r, a, b = np.radians([roll_deg, tilt_x_deg, tilt_y_deg])
    rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    R = rz @ rx @ ry
    t = np.asarray(centre_m, dtype=np.float64) - R @ np.array([board_centre[0], board_centre[1], 0.0])
    return R, t


_TEXEL_M = 0.0005
"""Resolution of the high-res board texture (m per texel)."""


@lru_cache(maxsize=4)
def _board_texture(cols: int, rows: int, square_m: float) -> NDArray[np.float32]:
    """High-res reflectance texture (0..1) of the board: squares, one white square of margin; texel (0, 0)
    sits at board point (-2 s, -2 s), the first inner corner is the board origin."""
    s = square_m
    n_u = round((cols + 3) * s / _TEXEL_M)
    n_v = round((rows + 3) * s / _TEXEL_M)
    bx = -2 * s + (np.arange(n_u) + 0.5) * _TEXEL_M
    by = -2 * s + (np.arange(n_v) + 0.5) * _TEXEL_M
    i, j = np.floor(bx / s)[None, :], np.floor(by / s)[:, None]
    on_squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
    tex = np.where(on_squares, np.where((i + j) % 2 == 0, 0.08, 0.92), 0.92)
    return tex.astype(np.float32)


def render_board_view(
    cam: CameraModel,
    R_board: NDArray[np.float64],
    t_board: NDArray[np.float64],
    rng: np.random.Generator,
    cfg: CalibrationSetConfig,
    gain: float = 230.0,
) -> NDArray[np.float64]:
    """Grey image (H, W) 0..255 float of the board at pose X_cam = R_board X_board + t_board.

    Inverse-mapped warp: each pixel is undistorted to its ray, intersected with the board plane and the
    high-res board texture is sampled there, pre-filtered to the pixel footprint (anti-aliasing)."""
    cols, rows = cfg.inner_corners
    tex = _board_texture(cols, rows, cfg.square_m)
    rays = pixel_rays(cam)
    n = R_board[:, 2]
    denom = np.einsum("ij,j->i", rays, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = float(n @ t_board) / denom
    pts = rays * lam[:, None] - t_board
    board = np.einsum("ij,jk->ik", pts, R_board)[:, :2]  # = R_board.T @ (X - t)
    ok = np.isfinite(lam) & (lam > 0)
    tex_uv = (board + 2 * cfg.square_m) / _TEXEL_M - 0.5
    tex_uv[~ok] = -1e4
    grid = tex_uv.reshape(cam.height, cam.width, 2)
    step = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    inside = (grid[:, 1:, 0] > 0) & (grid[:, 1:, 0] < tex.shape[1]) & (grid[:, 1:, 1] > 0)
    inside &= grid[:, 1:, 1] < tex.shape[0]
    footprint = float(np.median(step[inside])) if np.any(inside) else 0.0
    sigma = 0.5 * footprint
    src = cv2.GaussianBlur(tex, (0, 0), sigma) if sigma > 0.3 else tex
    img = cv2.remap(
        src,
        grid[:, :, 0].astype(np.float32),
        grid[:, :, 1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0.45,
    ).astype(np.float64)
    # soft illumination falloff towards the image corners
    uu, vv = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    r2 = ((uu - cam.width / 2) ** 2 + (vv - cam.height / 2) ** 2) / (
        (cam.width / 2) ** 2 + (cam.height / 2) ** 2
    )
    img = gain * img * (1.0 - 0.2 * r2)
    if cfg.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), cfg.blur_sigma_px)
    return img + rng.normal(0.0, cfg.image_noise_dn, size=img.shape)


def _board_fits(
    cam: CameraModel,
    R: NDArray,
    t: NDArray,
    cfg: CalibrationSetConfig,
    margin: float,
    margin_px: float = 0.0,
    white: float = 0.3,
) -> bool:
    """Whether the board's squares (and `white` squares of white around them) project inside the image,
    `margin` (fraction of the image size) plus `margin_px` away from its border."""
    cols, rows = cfg.inner_corners
    s = cfg.square_m
    # the squares must be in view; the white margin around them may leave the image. The outline is sampled
    # along its edges: distortion bends them, so the four corners alone do not bound it
    lo, hx, hy = -(1 + white) * s, (cols + white) * s, (rows + white) * s
    a = np.linspace(0.0, 1.0, 9)[:, None]
    corners = np.concatenate(
        [
            np.column_stack([lo + (hx - lo) * a[:, 0], np.full(9, lo)]),
            np.column_stack([lo + (hx - lo) * a[:, 0], np.full(9, hy)]),
            np.column_stack([np.full(9, lo), lo + (hy - lo) * a[:, 0]]),
            np.column_stack([np.full(9, hx), lo + (hy - lo) * a[:, 0]]),
        ]
    )
    corners = np.column_stack([corners, np.zeros(len(corners))])
    cam_pts = corners @ R.T + t
    if np.any(cam_pts[:, 2] < 0.2):
        return False
    # far outside the field of view the distortion polynomial folds back into the image: the pinhole projection
    # must be near the image too
    pin = cam_pts[:, :2] / cam_pts[:, 2:] @ cam.K[:2, :2].T + cam.K[:2, 2]
    if np.any(np.abs(pin - [cam.width / 2, cam.height / 2]) > 0.6 * np.array([cam.width, cam.height])):
        return False
    uv, _ = cv2.projectPoints(cam_pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    uv = uv.reshape(-1, 2)
    mw, mh = margin * cam.width + margin_px, margin * cam.height + margin_px
    return bool(
        np.all((uv[:, 0] > mw) & (uv[:, 0] < cam.width - mw) & (uv[:, 1] > mh) & (uv[:, 1] < cam.height - mh))
    )


def _smallest_square_px(cam: CameraModel, R: NDArray, t: NDArray, cfg: CalibrationSetConfig) -> float:
    """Shortest distance between neighbouring inner corners of the board in the image (px)."""
    cols, rows = cfg.inner_corners
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * cfg.square_m
    uv, _ = cv2.projectPoints(
        np.column_stack([grid, np.zeros(len(grid))]) @ R.T + t, np.zeros(3), np.zeros(3), cam.K, cam.dist
    )
    uv = uv.reshape(rows, cols, 2)
    dx = np.linalg.norm(np.diff(uv, axis=1), axis=2)
    dy = np.linalg.norm(np.diff(uv, axis=0), axis=2)
    return float(min(dx.min(), dy.min()))


def _inner_corners_seen(cam: CameraModel, R: NDArray, t: NDArray, cfg: CalibrationSetConfig) -> float:
    """Share of the board's inner corners that project into the image at least one square from its border."""
    cols, rows = cfg.inner_corners
    s = cfg.square_m
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * s
    cam_pts = np.column_stack([grid, np.zeros(len(grid))]) @ R.T + t
    if np.any(cam_pts[:, 2] < 0.2):
        return 0.0
    uv, _ = cv2.projectPoints(cam_pts, np.zeros(3), np.zeros(3), cam.K, cam.dist)
    uv = uv.reshape(-1, 2)
    pad = s * cam.K[0, 0] / float(np.median(cam_pts[:, 2]))
    inside = (
        (uv[:, 0] > pad) & (uv[:, 0] < cam.width - pad) & (uv[:, 1] > pad) & (uv[:, 1] < cam.height - pad)
    )
    return float(np.mean(inside))


def _push_to_spot(
    fits: Callable[[NDArray[np.float64]], bool], size: tuple[int, int], spot: tuple[float, float]
) -> NDArray[np.float64] | None:
    """The pixel (u, v) nearest the image spot (fractions of width and height; 0 or 1 is the border) at which
    the board centre can sit with `fits(uv)` true, found by bisection along u and v in turn from the image centre
    (so that a board stopped by one border still slides along it into a corner); None when the board does not
    fit even at the centre."""
    w, h = size
    uv = np.array([w / 2, h / 2])
    if not fits(uv):
        return None
    goal = np.array(
        [w * (0.5 + 1.6 * (spot[0] - 0.5)), h * (0.5 + 1.6 * (spot[1] - 0.5))]
    )  # beyond the border
    axes = [a for a in (0, 1) if abs(spot[a] - 0.5) >= 0.25]
    pushes = [a for _round in range(4) for a in axes]
    for n, axis in enumerate(pushes):
        lo, hi = uv[axis], goal[axis]
        for _ in range(20):
            trial = uv.copy()
            trial[axis] = 0.5 * (lo + hi)
            lo, hi = (trial[axis], hi) if fits(trial) else (lo, trial[axis])
        # a board flush with one border cannot slide along it (perspective and distortion bend its outline):
        # step back a little before pushing along the other axis
        back = (
            0.0
            if n == len(pushes) - 1
            else min(0.004 * (w + h), abs(lo - w / 2 * (axis == 0) - h / 2 * (axis == 1)))
        )
        uv[axis] = lo - back * np.sign(goal[axis] - lo)
    return uv


def _view_poses(
    ir: CameraModel,
    rgb: CameraModel,
    R_rel: NDArray,
    t_rel: NDArray,
    rng: np.random.Generator,
    cfg: CalibrationSetConfig,
) -> list[tuple[NDArray, NDArray]]:
    """Board poses in the IR frame (X_cam = R X_board + t): frontal, oblique (tilted about either axis), and
    rotated by 90 deg. The first `n_views` show the whole board in both cameras, centred or pushed into the IR
    image's corners and edges (the narrower image); the `n_rgb_edge_views` after them are pushed into the RGB
    image's corners and edges and the IR image sees them only partly. X_ir = R_rel X_rgb + t_rel."""
    cols, rows = cfg.inner_corners
    centre = np.array([(cols - 1) * cfg.square_m / 2, (rows - 1) * cfg.square_m / 2])
    # board centres spread over the image (corners and edges too), so the fitted distortion holds everywhere
    spots = [(0.5, 0.5), (0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0), (0.5, 0.0), (0.5, 1.0), (0.0, 0.5)]
    spots += [(1.0, 0.5)]
    corner_spots = [(0.0, 0.0), (1.0, 1.0), (1.0, 0.0), (0.0, 1.0)]
    edge_spots = [(0.5, 0.0), (1.0, 0.5), (0.5, 1.0), (0.0, 0.5)]
    # the corners twice (they bound the distortion's extrapolation), then the edge middles
    rgb_spots = corner_spots + corner_spots[::-1] + edge_spots

    def ir_pose(cam: CameraModel, uv: NDArray, dist: float, angles: tuple[float, float, float]):
        c = dist * (np.linalg.solve(cam.K, np.array([uv[0], uv[1], 1.0])))
        R, t = board_pose(*angles, c, centre)
        return (R, t) if cam is ir else (R_rel @ R, R_rel @ t + t_rel)

    def in_both(R: NDArray, t: NDArray) -> bool:
        R_rgb, t_rgb = R_rel.T @ R, R_rel.T @ (t - t_rel)
        m, w = cfg.edge_margin_px, cfg.edge_white_squares
        return _board_fits(ir, R, t, cfg, 0.0, m, w) and _board_fits(rgb, R_rgb, t_rgb, cfg, 0.0, m, w)

    def in_rgb(R: NDArray, t: NDArray) -> bool:
        R_rgb, t_rgb = R_rel.T @ R, R_rel.T @ (t - t_rel)
        return _board_fits(rgb, R_rgb, t_rgb, cfg, 0.0, cfg.edge_margin_px, cfg.edge_white_squares)

    poses: list[tuple[NDArray, NDArray]] = []
    n_total = cfg.n_views + cfg.n_rgb_edge_views
    for k in range(n_total):
        paired = k < cfg.n_views
        j = k if paired else k - cfg.n_views
        kind = j % 4  # 0 frontal, 1 tilted about x, 2 tilted about y, 3 rotated 90 deg
        cam, spot = (ir, spots[j % len(spots)]) if paired else (rgb, rgb_spots[j % len(rgb_spots)])
        lo, hi = cfg.distance_range_m if paired else cfg.edge_distance_range_m
        if not paired:
            mid_m = 0.5 * (lo + hi)
            lo, hi = (lo, mid_m) if (j // 4) % 2 == 0 else (mid_m, hi)
        fits = in_both if paired else in_rgb
        for _attempt in range(200):
            dist = rng.uniform(lo, hi)
            # edge views stay nearly square to the image so the board slides into the corner
            roll = (90.0 if kind == 3 else 0.0) + rng.uniform(-8, 8) * (1.0 if paired else 0.4)
            tilt = cfg.max_tilt_deg * rng.uniform(0.55, 1.0) * rng.choice([-1, 1])
            tx = tilt if kind == 1 else rng.uniform(-6, 6)
            ty = tilt if kind == 2 else rng.uniform(-6, 6)
            if kind == 3 and paired:
                tx = rng.uniform(-20, 20)
            angles = (roll, tx, ty)
            jitter = rng.uniform(-0.04, 0.04, size=2) if spot == (0.5, 0.5) else np.zeros(2)
            target = (spot[0] + jitter[0], spot[1] + jitter[1])
            uv = _push_to_spot(
                lambda uv, cam=cam, fits=fits, dist=dist, angles=angles: fits(
                    *ir_pose(cam, uv, dist, angles)
                ),
                (cam.width, cam.height),
                target,
            )
            if uv is None:
                continue
            R, t = ir_pose(cam, uv, dist, angles)
            sharp = paired or (
                _smallest_square_px(rgb, R_rel.T @ R, R_rel.T @ (t - t_rel), cfg) >= cfg.edge_min_square_px
            )
            if sharp and (paired or _inner_corners_seen(ir, R, t, cfg) >= cfg.edge_min_ir_corners):
                poses.append((R, t))
                break
        else:
            raise ValueError(f"no chessboard pose fits the cameras for view {k} (board too large?)")
    return poses


def _png_bytes(img: NDArray) -> bytes:
    # the noisy views compress best with PNG's per-row filters and full effort (about 10 % below level 4)
    params = [cv2.IMWRITE_PNG_COMPRESSION, 9, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_FILTERED]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def truth_calibration(profile: dict, size: str) -> dict:
    """The true calibration of a profile at `size`, in the calibrate stage's calibration.json schema
    (ir_to_rgb maps points X_rgb = R X_ir + t_m, the OpenCV stereo convention)."""
    ir = camera_model(profile, "ir", size)
    rgb = camera_model(profile, "rgb", size)
    R, t = ir_to_rgb_transform(profile)  # RGB pose in the IR frame
    out = {
        "ir": {"K": ir.K.tolist(), "dist": ir.dist.tolist(), "size": [ir.width, ir.height], "rms_px": 0.0},
        "rgb": {
            "K": rgb.K.tolist(),
            "dist": rgb.dist.tolist(),
            "size": [rgb.width, rgb.height],
            "rms_px": 0.0,
        },
        "ir_to_rgb": {"R": R.T.tolist(), "t_m": (-R.T @ t).tolist()},
        "stereo_rms_px": 0.0,
        "depth_model": None,
    }
    depth = profile.get("depth", {})
    if depth.get("convention") == "disparity":
        shift = float(depth.get("disparity_shift_px", 4)) / (2.0 if size == "mini" else 1.0)
        out["depth_model"] = {
            "offset": float(depth["disparity_offset"]),
            # raw disparities are in native device pixels whatever the image size: b*c does not scale
            "bc_m_px": float(depth["disparity_bc_m_px"]),
            "shift_px": shift,
            "shift_x_px": shift,
            "focal_px": float(profile["ir"]["K"][0][0]),
            "subpixel_scale": 0.125,
            "invalid_raw": INVALID_DISPARITY,
        }
    return out


def flat_raw_disparity(
    distance_m: float,
    profile: dict,
    size: str,
    rng: np.random.Generator,
    sensor_cfg: SensorConfig | None = None,
) -> NDArray[np.uint16]:
    """Raw 11-bit disparity image (H, W) of a flat target perpendicular to the optical axis at distance_m
    (eq 3.11: d_k = offset - 8 b c / H, with noise, the radial pattern and quantization), shifted against
    the IR image as the device does: IR column = disparity column + shift (the last columns are invalid)."""
    depth = profile["depth"]
    ir = camera_model(profile, "ir", size)
    z = np.full(ir.width * ir.height, float(distance_m))
    radial_px = (sensor_cfg or SensorConfig()).radial_error_px
    raw = kinect_raw_disparity(z, depth, rng, _radial_weight(ir), radial_px)
    raw = raw.reshape(ir.height, ir.width)
    shift = round(float(depth.get("disparity_shift_px", 4)) / (2.0 if size == "mini" else 1.0))
    out = np.full_like(raw, INVALID_DISPARITY)
    if shift > 0:
        out[:, :-shift] = raw[:, shift:]
    else:
        out[:] = raw
    return out


def write_calibration_set(
    folder: str | Path,
    profile: dict,
    size: str,
    rng: np.random.Generator,
    cfg: CalibrationSetConfig = CalibrationSetConfig(),
) -> dict:
    """Write `folder`/target.yaml (the pattern), ir/NN.png (8-bit grey), rgb/NN.png (colour) chessboard views, and for Kinect v1
    flat/NN.png (uint16 raw disparity) with flat.yaml (distances in metres, in file order). Returns the
    true calibration (see `truth_calibration`).

    At size "mini" the flat frames are the native-resolution raw disparities decimated by 2: their values
    (and so offset and b*c) are those of the device, while the 4 px shift becomes 2 px."""
    if cfg.n_views < 8:
        raise ValueError(f"a calibration set needs at least 8 chessboard views, got {cfg.n_views}")
    folder = Path(folder)
    ir = camera_model(profile, "ir", size)
    rgb = camera_model(profile, "rgb", size)
    R_rel, t_rel = ir_to_rgb_transform(profile)
    views = _view_poses(ir, rgb, R_rel, t_rel, rng, cfg)
    (folder / "ir").mkdir(parents=True, exist_ok=True)
    (folder / "rgb").mkdir(parents=True, exist_ok=True)
    for k, (R, t) in enumerate(views):
        ir_img = render_board_view(ir, R, t, rng, cfg, gain=200.0)
        (folder / "ir" / f"{k:02d}.png").write_bytes(
            _png_bytes(np.clip(np.rint(ir_img), 0, 255).astype(np.uint8))
        )
        R_rgb, t_rgb = R_rel.T @ R, R_rel.T @ (t - t_rel)
        grey = render_board_view(rgb, R_rgb, t_rgb, rng, cfg, gain=235.0)
        tint = np.array([1.0, 0.97, 0.92])  # warm indoor light, BGR order for OpenCV
        bgr = np.clip(np.rint(grey[:, :, None] * tint), 0, 255).astype(np.uint8)
        (folder / "rgb" / f"{k:02d}.png").write_bytes(_png_bytes(bgr))
    cols, rows = cfg.inner_corners
    target = {"pattern": f"chessboard:{cols}x{rows}:{cfg.square_m:g}"}
    (folder / "target.yaml").write_text(yaml.safe_dump(target, sort_keys=False))
    truth = truth_calibration(profile, size)
    if profile.get("depth", {}).get("convention") == "disparity":
        (folder / "flat").mkdir(parents=True, exist_ok=True)
        # the raw disparity of a native-resolution device: simulate at full size, keep every other pixel
        for k, dist in enumerate(cfg.flat_distances_m):
            raw = flat_raw_disparity(dist, profile, "full", rng)
            if size == "mini":
                raw = raw[::2, ::2]
            (folder / "flat" / f"{k:02d}.png").write_bytes(_png_bytes(raw))
        meta = {
            "distances_m": [float(d) for d in cfg.flat_distances_m],
            "files": [f"{k:02d}.png" for k in range(len(cfg.flat_distances_m))],
            "shift_px": truth["depth_model"]["shift_px"],
            "note": "raw 11-bit Kinect disparity d_k (eq 3.11), 2047 = no measurement; IR column = disparity column + shift_px",
        }
        (folder / "flat.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return truth
