"""Synthetic RGB-D and TLS sensors: ray casting against a :class:`SceneMesh` with device error models.

Depth follows the Kinect v1 structured-light chain of the thesis (eq 3.11-3.12 disparity model, eq 6.2
disparity noise, the radial error pattern of section 6.1.2, 1/8 px quantization); Kinect v2 (time of
flight) and RealSense (active stereo) get their own range noise. Colour is procedural texture evaluated at
each ray hit in the material's texture frame, so features are rigidly attached to the surfaces (SfM sees
a consistent world). Cameras use OpenCV axes (x right, y down, z forward) and the plumb_bob model.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from tasks.synth.scene import SceneMesh


@dataclass(frozen=True)
class SensorConfig:
    """Appearance and error-model settings of the synthetic sensors (defaults serve every profile)."""

    radial_error_px: float = 0.1
    """Kinect v1 systematic disparity error at the image corners (px); grows as radius^2 (thesis 6.1.2)."""
    no_return_kinds: tuple[str, ...] = ("glass", "dark")
    """Material kinds that give no depth return (specular glass, IR-absorbing black)."""
    paint_contrast: float = 0.4
    """Relative amplitude of the multi-octave value noise on paint."""
    texture_poor_contrast: float = 0.03
    """Paint noise amplitude in texture-poor captures (the hallway), where SfM should struggle."""
    light_falloff_m: float = 7.0
    """Distance at which the soft light falloff halves the brightness (m)."""
    exposure_sigma: float = 0.05
    """Standard deviation of the per-frame log exposure change."""
    pixel_noise_dn: float = 1.0
    """Gaussian read noise of the colour camera (digital numbers)."""
    glass_tint: float = 0.3
    """Share of the pale glass tint mixed into what is seen through glass."""
    sky_rgb: tuple[int, int, int] = (205, 220, 235)
    """Sky colour of rays that leave the building (through windows), above a procedural skyline."""
    tls_sigma_m: float = 0.002
    """TLS range noise (m), Leica HDS3000-class surface accuracy."""
    tls_min_range_m: float = 0.4
    """TLS near blind zone (m)."""
    tls_max_range_m: float = 50.0
    """TLS maximum range (m)."""
    tls_elevation_min_deg: float = -60.0
    """Lowest elevation scanned (the tripod hides what is below)."""


_PALETTE = np.array(
    [
        [200, 40, 40],
        [40, 90, 190],
        [240, 200, 40],
        [30, 140, 70],
        [240, 240, 235],
        [25, 25, 30],
        [230, 120, 30],
        [120, 60, 150],
        [90, 190, 210],
        [160, 110, 70],
    ],
    dtype=np.float64,
)


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with plumb_bob distortion, at the rendered image size."""

    K: NDArray[np.float64]
    """(3, 3) intrinsic matrix in pixels."""
    dist: NDArray[np.float64]
    """(5,) k1 k2 p1 p2 k3."""
    width: int
    """Image width (px)."""
    height: int
    """Image height (px)."""


def camera_model(profile: dict, stream: str, size: str) -> CameraModel:
    """The intrinsics of `stream` ("ir" or "rgb") of a sensor profile at `size`.

    "full" is the profile's own size; "mini" halves the image size and fx, fy, cx, cy (distortion is in
    normalised coordinates and does not change)."""
    if stream not in ("ir", "rgb"):
        raise ValueError(f"camera stream must be 'ir' or 'rgb', got {stream!r}")
    if size not in ("mini", "full"):
        raise ValueError(f"size must be 'mini' or 'full', got {size!r}")
    if stream not in profile:
        raise ValueError(f"sensor profile {profile.get('name')!r} has no {stream!r} camera")
    cam = profile[stream]
    K = np.array(cam["K"], dtype=np.float64)
    dist = np.array(cam["dist"], dtype=np.float64)
    w, h = (int(v) for v in cam["size"])
    if size == "mini":
        K[:2] /= 2.0
        w, h = w // 2, h // 2
    return CameraModel(K=K, dist=dist, width=w, height=h)


def ir_to_rgb_transform(profile: dict) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pose of the RGB camera in the IR camera frame (thesis table 6.2): X_ir = R @ X_rgb + t.

    Heading turns about the camera's y axis (down), elevation about x, roll about the optical axis z;
    R = Ry(heading) @ Rx(elevation) @ Rz(roll). The OpenCV stereo convention (X_rgb = R' X_ir + t') is
    R' = R.T, t' = -R.T @ t."""
    rel = profile["ir_to_rgb"]
    heading, elevation, roll = np.radians(np.asarray(rel["heading_elevation_roll_deg"], dtype=np.float64))
    ch, sh = np.cos(heading), np.sin(heading)
    ce, se = np.cos(elevation), np.sin(elevation)
    cr, sr = np.cos(roll), np.sin(roll)
    ry = np.array([[ch, 0, sh], [0, 1, 0], [-sh, 0, ch]])
    rx = np.array([[1, 0, 0], [0, ce, -se], [0, se, ce]])
    rz = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return ry @ rx @ rz, np.asarray(rel["t_m"], dtype=np.float64)


def rgb_pose(pose_ir_to_plan: NDArray[np.float64], profile: dict) -> NDArray[np.float64]:
    """Camera-to-plan pose (4, 4) of the RGB camera given the IR camera's."""
    R, t = ir_to_rgb_transform(profile)
    rel = np.eye(4)
    rel[:3, :3] = R
    rel[:3, 3] = t
    return np.asarray(pose_ir_to_plan, dtype=np.float64) @ rel


def undistort_pixels(
    cam: CameraModel, pixels: NDArray[np.float64], iterations: int = 60
) -> NDArray[np.float64]:
    """Normalised undistorted coordinates (N, 2) of distorted pixel positions (N, 2), i.e. each pixel's
    ray direction is (x, y, 1). Iterated to convergence (OpenCV's default 5 iterations leave residuals of
    a few hundredths of a pixel at the corners for the Kinect's distortion)."""
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, 1e-12)
    pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, cam.K, cam.dist, criteria=crit).reshape(-1, 2)


@lru_cache(maxsize=16)
def _pixel_rays_cached(key: bytes, w: int, h: int) -> NDArray[np.float64]:
    params = np.frombuffer(key, dtype=np.float64)
    cam = CameraModel(K=params[:9].reshape(3, 3), dist=params[9:], width=w, height=h)
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = undistort_pixels(cam, np.stack([uu.ravel(), vv.ravel()], axis=1))
    rays = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    rays.setflags(write=False)
    return rays


def pixel_rays(cam: CameraModel) -> NDArray[np.float64]:
    """Camera-frame ray directions (H*W, 3) with z = 1, one per pixel centre in row-major order, through
    the distortion (so a ray parameter equals the z-depth)."""
    key = np.concatenate([cam.K.ravel(), cam.dist.ravel()]).astype(np.float64).tobytes()
    return _pixel_rays_cached(key, cam.width, cam.height)


_SCENES: dict[int, tuple[weakref.ref, o3d.t.geometry.RaycastingScene]] = {}


def raycasting_scene(scene_mesh: SceneMesh) -> o3d.t.geometry.RaycastingScene:
    """An open3d ray casting scene of the mesh, built once per mesh object."""
    key = id(scene_mesh)
    hit = _SCENES.get(key)
    if hit is not None and hit[0]() is scene_mesh:
        return hit[1]
    verts = np.asarray(scene_mesh.vertices, dtype=np.float32)
    tris = np.asarray(scene_mesh.triangles)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(tris) == 0:
        raise ValueError(f"scene mesh needs (V, 3) vertices and triangles, got {verts.shape}, {tris.shape}")
    if len(scene_mesh.material) != len(tris):
        raise ValueError(f"scene mesh has {len(tris)} triangles but {len(scene_mesh.material)} material ids")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris.astype(np.uint32)))
    for dead in [k for k, (ref, _) in _SCENES.items() if ref() is None]:
        del _SCENES[dead]
    _SCENES[key] = (weakref.ref(scene_mesh), scene)
    return scene


def _cast(scene: o3d.t.geometry.RaycastingScene, origins: NDArray, dirs: NDArray) -> dict[str, NDArray]:
    rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
    ans = scene.cast_rays(o3d.core.Tensor(rays), nthreads=0)
    return {
        "t": ans["t_hit"].numpy().astype(np.float64),
        "prim": ans["primitive_ids"].numpy().astype(np.int64),
        "normal": ans["primitive_normals"].numpy().astype(np.float64),
    }


# ---------------------------------------------------------------------------------------------------
# Kinect v1 disparity model (eq 3.11, 3.12, 6.2) and other range noise models
# ---------------------------------------------------------------------------------------------------

INVALID_DISPARITY = 2047
"""Raw 11-bit disparity value that marks "no measurement"."""


def raw_disparity_from_depth(z_m: NDArray[np.float64], depth: dict) -> NDArray[np.float64]:
    """Unquantized raw Kinect disparity d_k (1/8 px units) of z-depths, inverting eq 3.11-3.12:
    d_k = offset - 8 * b*c / H."""
    return float(depth["disparity_offset"]) - 8.0 * float(depth["disparity_bc_m_px"]) / np.asarray(z_m)


def depth_from_raw_disparity(d_k: NDArray, depth: dict) -> NDArray[np.float64]:
    """Depth H (m) of raw disparities (eq 3.12): H = b*c / ((offset - d_k) / 8); NaN where invalid."""
    d = (float(depth["disparity_offset"]) - np.asarray(d_k, dtype=np.float64)) / 8.0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = float(depth["disparity_bc_m_px"]) / d
    return np.where((d > 0) & (np.asarray(d_k) != INVALID_DISPARITY), z, np.nan)


def depth_sigma_m(z_m: NDArray[np.float64], profile: dict) -> NDArray[np.float64]:
    """Model standard deviation (m) of a single depth measurement at z-depth z_m, image centre.

    Kinect v1: eq 6.2, sigma_H = H^2 / (b*c) * sigma_d, with sigma_d combining the profile's Gaussian
    disparity noise and the uniform 1/8 px quantization (variance (1/8)^2 / 12). Kinect v2 (time of
    flight): linear in range; active stereo (RealSense): quadratic."""
    depth = profile["depth"]
    z = np.asarray(z_m, dtype=np.float64)
    if depth.get("convention") == "disparity":
        sigma_d = np.hypot(float(depth["sigma_disparity_px"]), (1.0 / 8.0) / np.sqrt(12.0))
        return z**2 / float(depth["disparity_bc_m_px"]) * sigma_d
    # plus the 1 mm output step (uniform, variance 1/12 mm^2)
    return np.hypot(float(depth["sigma_m_at_1m"]) * z ** _range_noise_power(profile), 0.001 / np.sqrt(12.0))


def _range_noise_power(profile: dict) -> int:
    """1 for time-of-flight sensors (noise linear in range), 2 for triangulating ones."""
    growth = profile["depth"].get("noise_growth")
    if growth is not None:
        return {"linear": 1, "quadratic": 2}[growth]
    name = str(profile.get("name", "")).lower()
    return 1 if ("kinect_v2" in name or "azure" in name or "tof" in name) else 2


def _radial_weight(cam: CameraModel) -> NDArray[np.float64]:
    """(H*W,) squared pixel radius from the image centre, 1 at the corners."""
    uu, vv = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    cx, cy = (cam.width - 1) / 2.0, (cam.height - 1) / 2.0
    return (((uu - cx) ** 2 + (vv - cy) ** 2) / (cx**2 + cy**2)).ravel()


def kinect_raw_disparity(
    z_m: NDArray[np.float64],
    depth: dict,
    rng: np.random.Generator | None,
    radial_weight: NDArray[np.float64] | float = 0.0,
    radial_error_px: float = 0.0,
) -> NDArray[np.uint16]:
    """Quantized raw 11-bit Kinect disparities of true z-depths (NaN or inf = no return).

    Eq 3.11-3.12 give the ideal d_k; the disparity (px) receives Gaussian noise sigma_disparity_px
    (eq 6.2 makes that H^2-growing range noise) and the radial pattern radial_error_px * weight of thesis
    6.1.2 (weight = squared image radius, 1 at the corners), then d_k is rounded to an integer (1/8 px).
    Out-of-range or invalid pixels are INVALID_DISPARITY. rng None means no random noise."""
    z = np.asarray(z_m, dtype=np.float64)
    valid = np.isfinite(z) & (z >= float(depth["min_range_m"])) & (z <= float(depth["max_range_m"]))
    zz = np.where(valid, z, 1.0)
    disp_px = float(depth["disparity_bc_m_px"]) / zz + radial_error_px * np.asarray(radial_weight)
    if rng is not None:
        disp_px = disp_px + rng.normal(0.0, float(depth["sigma_disparity_px"]), size=z.shape)
    d_k = np.rint(float(depth["disparity_offset"]) - 8.0 * disp_px)
    valid &= (d_k >= 0) & (d_k < INVALID_DISPARITY)
    return np.where(valid, d_k, INVALID_DISPARITY).astype(np.uint16)


def simulate_depth_mm(
    z_m: NDArray[np.float64],
    profile: dict,
    rng: np.random.Generator | None,
    radial_weight: NDArray[np.float64] | float = 0.0,
    cfg: SensorConfig = SensorConfig(),
) -> NDArray[np.uint16]:
    """What the sensor's driver outputs (uint16 mm, 0 = no return) for true z-depths z_m (NaN = none).

    Kinect v1: through the raw disparity (see `kinect_raw_disparity`) and back with eq 3.12. Other
    profiles: Gaussian range noise sigma_m_at_1m * z^p (p = 1 time of flight, 2 stereo), 1 mm steps.
    rng None switches all noise (and the radial pattern) off; the device quantization stays."""
    depth = profile["depth"]
    z = np.asarray(z_m, dtype=np.float64)
    if depth.get("convention") == "disparity":
        radial_px = cfg.radial_error_px if rng is not None else 0.0
        d_k = kinect_raw_disparity(z, depth, rng, radial_weight, radial_px)
        zq = depth_from_raw_disparity(d_k, depth)
        out = np.where(np.isfinite(zq), np.rint(zq * 1000.0), 0.0)
        return np.clip(out, 0, 65535).astype(np.uint16)
    valid = np.isfinite(z) & (z >= float(depth["min_range_m"])) & (z <= float(depth["max_range_m"]))
    zz = np.where(valid, z, 0.0)
    if rng is not None:
        zz = zz + rng.normal(0.0, 1.0, size=z.shape) * float(
            depth["sigma_m_at_1m"]
        ) * zz ** _range_noise_power(profile)
    out = np.where(valid, np.rint(zz * 1000.0), 0.0)
    return np.clip(out, 0, 65535).astype(np.uint16)


# ---------------------------------------------------------------------------------------------------
# Procedural textures
# ---------------------------------------------------------------------------------------------------

_M1 = np.uint64(0x9E3779B97F4A7C15)
_M2 = np.uint64(0xBF58476D1CE4E5B9)
_M3 = np.uint64(0x94D049BB133111EB)


def _hash01(i: NDArray, j: NDArray, seed: NDArray | int) -> NDArray[np.float64]:
    """Deterministic uniform [0, 1) per integer lattice point (splitmix64 finaliser)."""
    with np.errstate(over="ignore"):
        h = (
            np.asarray(i, dtype=np.int64).astype(np.uint64) * _M1
            ^ np.asarray(j, dtype=np.int64).astype(np.uint64) * _M2
            ^ (np.asarray(seed, dtype=np.int64).astype(np.uint64) + np.uint64(0x632BE59BD9B4E019)) * _M3
        )
        h ^= h >> np.uint64(30)
        h *= _M2
        h ^= h >> np.uint64(27)
        h *= _M3
        h ^= h >> np.uint64(31)
    return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def value_noise(s: NDArray, t: NDArray, seed: NDArray | int) -> NDArray[np.float64]:
    """Smooth lattice value noise in [0, 1] at texture coordinates (s, t) (lattice spacing 1)."""
    i0, j0 = np.floor(s), np.floor(t)
    fs, ft = s - i0, t - j0
    fs = fs * fs * (3 - 2 * fs)
    ft = ft * ft * (3 - 2 * ft)
    i0, j0 = i0.astype(np.int64), j0.astype(np.int64)
    a = _hash01(i0, j0, seed)
    b = _hash01(i0 + 1, j0, seed)
    c = _hash01(i0, j0 + 1, seed)
    d = _hash01(i0 + 1, j0 + 1, seed)
    return (a * (1 - fs) + b * fs) * (1 - ft) + (c * (1 - fs) + d * fs) * ft


def fbm(s: NDArray, t: NDArray, seed: NDArray | int, octaves: int = 4) -> NDArray[np.float64]:
    """Multi-octave value noise in about [-1, 1], coarsest lattice spacing 1."""
    total = np.zeros_like(s, dtype=np.float64)
    amp, norm = 1.0, 0.0
    for k in range(octaves):
        f = 2.0**k
        total += amp * (
            2.0 * value_noise(s * f + 17.3 * k, t * f - 5.1 * k, np.asarray(seed) + 101 * k) - 1.0
        )
        norm += amp
        amp *= 0.55
    return total / norm


def _texture(kind: str, st: NDArray, base: NDArray, seed: NDArray, contrast: float) -> NDArray[np.float64]:
    """Linear RGB (N, 3) in 0..255 of material `kind` at texture coordinates st (N, 2) in feature units."""
    s, t = st[:, 0], st[:, 1]
    if kind in ("paint", "ceiling", "dark"):
        amp = contrast if kind == "paint" else 0.04 if kind == "ceiling" else 0.2
        g = 1.0 + amp * fbm(s, t, seed, 5) + 0.3 * amp * (2 * value_noise(8 * s, 8 * t, seed + 7) - 1)
        if kind == "paint":
            g = g - 0.9 * amp * _spots(4.0 * s, 4.0 * t, seed + 19)
        return base * g[:, None]
    if kind == "poster":
        return _poster(s, t, base, seed)
    if kind == "floor":
        return np.where(
            (_hash01(0, 0, seed) < 0.5)[:, None], _tiles(s, t, base, seed), _planks(s, t, base, seed)
        )
    if kind == "wood":
        return _planks(s, t, base, seed)
    if kind == "plant":
        leaf = value_noise(3 * s, 3 * t, seed)
        g = 0.45 + 1.0 * (leaf > 0.5) * leaf + 0.2 * fbm(6 * s, 6 * t, seed + 3, 3)
        return base * g[:, None]
    if kind == "metal":
        g = 1.0 + 0.12 * (2 * value_noise(0.3 * s, 30 * t, seed) - 1) + 0.05 * fbm(s, t, seed + 1, 3)
        return base * g[:, None]
    # glass and unknown kinds: the base colour with a little noise
    return base * (1.0 + 0.05 * fbm(s, t, seed, 3))[:, None]


def _spots(s: NDArray, t: NDArray, seed: NDArray) -> NDArray[np.float64]:
    """Sparse soft round spots (0..1) on a lattice of spacing 1: blobs for SIFT on painted walls."""
    ci, cj = np.floor(s), np.floor(t)
    present = _hash01(ci, cj, seed) < 0.3
    cx = 0.25 + 0.5 * _hash01(ci, cj, seed + 1)
    cy = 0.25 + 0.5 * _hash01(ci, cj, seed + 2)
    radius = 0.1 + 0.15 * _hash01(ci, cj, seed + 3)
    r = np.hypot(s - ci - cx, t - cj - cy) / radius
    return np.where(present, np.clip(1.5 - r, 0.0, 1.0), 0.0)


def _poster(s: NDArray, t: NDArray, base: NDArray, seed: NDArray) -> NDArray[np.float64]:
    """A collage of random rectangles (two nested grids), discs and stripes: strong SIFT features."""
    out = base.copy()
    for level, cell in enumerate((1.0, 0.37)):
        ci, cj = np.floor(s / cell + 0.31 * level), np.floor(t / cell + 0.57 * level)
        h = _hash01(ci, cj, seed + 13 * level)
        keep = h < (0.85 if level == 0 else 0.45)
        colour = _PALETTE[(_hash01(ci, cj, seed + 29 + level) * len(_PALETTE)).astype(np.int64)]
        fs, ft = s / cell + 0.31 * level - ci, t / cell + 0.57 * level - cj
        kind = (h * 1000).astype(np.int64) % 3
        second = _PALETTE[(_hash01(ci, cj, seed + 31 + level) * len(_PALETTE)).astype(np.int64)]
        cx, cy = 0.3 + 0.4 * _hash01(ci, cj, seed + 37), 0.3 + 0.4 * _hash01(ci, cj, seed + 41)
        radius = 0.15 + 0.2 * _hash01(ci, cj, seed + 43)
        disc = (fs - cx) ** 2 + (ft - cy) ** 2 < radius**2
        angle = np.pi * _hash01(ci, cj, seed + 47)
        stripes = np.sin((fs * np.cos(angle) + ft * np.sin(angle)) * 2 * np.pi * 3.0) > 0
        inner = np.where(kind == 1, disc, np.where(kind == 2, stripes, False))
        margin = (fs > 0.06) & (fs < 0.94) & (ft > 0.06) & (ft < 0.94)
        pick = np.where(inner[:, None], second, colour)
        out = np.where((keep & margin)[:, None], pick, out)
    return out * (1.0 + 0.05 * fbm(4 * s, 4 * t, seed + 3, 2))[:, None]


def _tiles(s: NDArray, t: NDArray, base: NDArray, seed: NDArray) -> NDArray[np.float64]:
    ci, cj = np.floor(s), np.floor(t)
    fs, ft = s - ci, t - cj
    grout = (fs < 0.04) | (ft < 0.04)
    jitter = 0.8 + 0.4 * _hash01(ci, cj, seed + 5)
    marble = 1.0 + 0.15 * fbm(3 * s, 3 * t, seed + 9, 4)
    g = np.where(grout, 0.45, jitter * marble)
    return base * g[:, None]


def _planks(s: NDArray, t: NDArray, base: NDArray, seed: NDArray) -> NDArray[np.float64]:
    """Planks of width 1 along s with staggered joints, grain along the plank."""
    row = np.floor(t * 4.0)
    offset = _hash01(row, 0, seed + 3) * 6.0
    col = np.floor((s + offset) / 6.0)
    ft = t * 4.0 - row
    fs = (s + offset) / 6.0 - col
    joint = (ft < 0.05) | (fs < 0.008)
    tone = 0.8 + 0.4 * _hash01(row, col, seed + 11)
    grain = 1.0 + 0.12 * np.sin(2 * np.pi * (ft * 5 + 0.6 * fbm(0.5 * s, 4 * t, seed + 17, 3)))
    knots = 1.0 - 0.25 * (value_noise(2 * s, 8 * t, seed + 23) > 0.88)
    g = np.where(joint, 0.5, tone * grain * knots)
    return base * g[:, None]


@dataclass(frozen=True)
class _MaterialTable:
    kinds: tuple[str, ...]
    base: NDArray[np.float64]
    seed: NDArray[np.int64]
    origin: NDArray[np.float64]
    u: NDArray[np.float64]
    v: NDArray[np.float64]
    scale: NDArray[np.float64]


def _material_table(scene_mesh: SceneMesh) -> _MaterialTable:
    mats = scene_mesh.materials
    if not mats:
        raise ValueError("scene mesh has no materials")
    return _MaterialTable(
        kinds=tuple(m.kind for m in mats),
        base=np.array([m.base_rgb for m in mats], dtype=np.float64),
        seed=np.array([m.seed for m in mats], dtype=np.int64),
        origin=np.array([m.origin for m in mats], dtype=np.float64),
        u=np.array([m.u_axis for m in mats], dtype=np.float64),
        v=np.array([m.v_axis for m in mats], dtype=np.float64),
        scale=np.maximum(np.array([m.texture_scale_m for m in mats], dtype=np.float64), 1e-3),
    )


def surface_colour(
    points: NDArray[np.float64], mat_ids: NDArray[np.int64], table: _MaterialTable, paint_contrast: float
) -> NDArray[np.float64]:
    """Unlit texture colour (N, 3), 0..255 float, of surface points (N, 3) with material ids (N,)."""
    out = np.zeros((len(points), 3))
    rel = points - table.origin[mat_ids]
    st = (
        np.stack(
            [np.einsum("ij,ij->i", rel, table.u[mat_ids]), np.einsum("ij,ij->i", rel, table.v[mat_ids])],
            axis=1,
        )
        / table.scale[mat_ids, None]
    )
    names = sorted(set(table.kinds))
    code_of_material = np.array([names.index(k) for k in table.kinds])
    codes = code_of_material[mat_ids]
    for code in np.unique(codes):
        sel = codes == code
        ids = mat_ids[sel]
        out[sel] = _texture(names[code], st[sel], table.base[ids], table.seed[ids], paint_contrast)
    return out


# ---------------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------------


def environment_colour(dirs: NDArray[np.float64], sky_rgb: tuple[int, int, int]) -> NDArray[np.float64]:
    """Colour (N, 3) of rays (unit, plan frame) that leave the building: a distant skyline of buildings
    and trees with lit windows under a cloudy sky, a function of direction only (at infinity)."""
    az = np.arctan2(dirs[:, 1], dirs[:, 0])
    el = np.arcsin(np.clip(dirs[:, 2], -1.0, 1.0))
    # periodic in azimuth: evaluate the noise on a circle
    cs, sn = 6.0 * np.cos(az), 6.0 * np.sin(az)
    skyline = 0.08 + 0.22 * value_noise(cs + 40.0, sn + 40.0, 7) + 0.06 * value_noise(4 * cs, 4 * sn, 8)
    sky = (
        np.asarray(sky_rgb, dtype=np.float64)
        * (1.0 + 0.08 * fbm(3 * cs + 9.0, 12 * el, 9, 4) - 0.15 * np.clip(el, 0, 1))[:, None]
    )
    block = np.floor(az / 0.07)
    facade = 90.0 + 100.0 * _hash01(block, 0, 11)
    lit = (
        (np.sin(az * 500.0) > 0.2)
        & (np.sin(el * 180.0) > 0.0)
        & (_hash01(np.floor(az * 80), np.floor(el * 28), 13) < 0.5)
    )
    building = np.stack([facade, facade * 0.95, facade * 0.9], axis=1) * np.where(lit, 1.4, 1.0)[:, None]
    tree = (value_noise(3 * cs + 20.0, 3 * sn, 14) > 0.55)[:, None]
    leaves = np.array([60.0, 110.0, 50.0]) * (0.7 + 0.6 * value_noise(60 * az, 60 * el, 15))[:, None]
    ground = np.where(tree & (el < skyline[:, None].ravel() * 0.7)[:, None], leaves, building)
    return np.where((el < skyline)[:, None], ground, sky)


def _world_rays(cam: CameraModel, pose: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    # einsum: a (N, 3) x (3, 3) BLAS matmul is ten times slower here (thread start-up on a busy machine)
    dirs = np.einsum("ij,kj->ik", pixel_rays(cam), pose[:3, :3])
    origins = np.broadcast_to(pose[:3, 3], dirs.shape)
    return origins, dirs


def _check_pose(pose: NDArray) -> NDArray[np.float64]:
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"camera pose must be a finite 4x4 matrix, got shape {pose.shape}")
    if abs(np.linalg.det(pose[:3, :3]) - 1.0) > 1e-3:
        raise ValueError("camera pose rotation is not a proper rotation (det != 1)")
    return pose


def render_depth_z(
    scene_mesh: SceneMesh, pose_ir_to_plan: NDArray, cam: CameraModel, cfg: SensorConfig = SensorConfig()
) -> NDArray[np.float64]:
    """True z-depth (H, W) in metres along the optical axis of the IR camera; NaN where there is no return
    (miss, or a no-return material such as glass or dark)."""
    pose = _check_pose(pose_ir_to_plan)
    scene = raycasting_scene(scene_mesh)
    origins, dirs = _world_rays(cam, pose)
    hit = _cast(scene, origins, dirs)
    z = hit["t"]
    ok = np.isfinite(z)
    kinds = np.array([m.kind for m in scene_mesh.materials])
    mat = np.asarray(scene_mesh.material)[np.where(ok, hit["prim"], 0)]
    ok &= ~np.isin(kinds[mat], cfg.no_return_kinds)
    return np.where(ok, z, np.nan).reshape(cam.height, cam.width)


def render_colour(
    scene_mesh: SceneMesh,
    pose_cam_to_plan: NDArray,
    cam: CameraModel,
    rng: np.random.Generator | None,
    texture_poor: bool = False,
    cfg: SensorConfig = SensorConfig(),
) -> NDArray[np.uint8]:
    """RGB image (H, W, 3) uint8 seen by a camera at `pose_cam_to_plan` (camera-to-plan, OpenCV axes).

    Lighting: a soft falloff with distance, brighter facing surfaces, a per-frame exposure change and
    read noise (all random parts off when rng is None). Glass shows what is behind it with a pale tint."""
    pose = _check_pose(pose_cam_to_plan)
    scene = raycasting_scene(scene_mesh)
    table = _material_table(scene_mesh)
    origins, dirs = _world_rays(cam, pose)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    n = len(unit)
    colour = np.zeros((n, 3))
    escaped = np.zeros(n, dtype=bool)
    tint = np.ones(n)
    travelled = np.zeros(n)
    active = np.arange(n)
    orig = np.asarray(origins, dtype=np.float64).copy()
    contrast = cfg.texture_poor_contrast if texture_poor else cfg.paint_contrast
    mesh_mat = np.asarray(scene_mesh.material)
    is_glass = np.array([k == "glass" for k in table.kinds])
    for _ in range(4):  # a ray may pass through a few glass panes
        if len(active) == 0:
            break
        hit = _cast(scene, orig[active], unit[active])
        t = hit["t"]
        found = np.isfinite(t)
        escaped[active[~found]] = True
        idx = active[found]
        t = t[found]
        mats = mesh_mat[hit["prim"][found]]
        pts = orig[idx] + unit[idx] * t[:, None]
        travelled[idx] += t
        glass = is_glass[mats]
        solid = ~glass
        sidx = idx[solid]
        if len(sidx):
            albedo = surface_colour(pts[solid], mats[solid], table, contrast)
            normal = hit["normal"][found][solid]
            facing = np.abs(np.einsum("ij,ij->i", normal, unit[sidx]))
            falloff = 1.0 / (1.0 + (travelled[sidx] / cfg.light_falloff_m) ** 2)
            height = np.clip(pts[solid, 2] / 3.0, 0.0, 1.0)
            light = (0.55 + 0.45 * facing) * falloff * (0.9 + 0.15 * height) * 1.15
            colour[sidx] = albedo * light[:, None]
        tint[idx[glass]] *= 1.0 - cfg.glass_tint
        # continue through glass just beyond the pane
        orig[idx[glass]] = pts[glass] + unit[idx[glass]] * 1e-3
        active = idx[glass]
    if np.any(escaped):
        colour[escaped] = environment_colour(unit[escaped], cfg.sky_rgb)
    pale = np.array([225.0, 238.0, 240.0])
    colour = colour * tint[:, None] + pale * (1.0 - tint[:, None])
    img = colour.reshape(cam.height, cam.width, 3)
    uu, vv = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    r2 = ((uu - cam.width / 2) ** 2 + (vv - cam.height / 2) ** 2) / (
        (cam.width / 2) ** 2 + (cam.height / 2) ** 2
    )
    img = img * (1.0 - 0.15 * r2)[:, :, None]  # lens vignetting
    if rng is not None:
        img = img * float(np.exp(rng.normal(0.0, cfg.exposure_sigma)))
        img = img + rng.normal(0.0, cfg.pixel_noise_dn, size=img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def render_rgbd(
    scene_mesh: SceneMesh,
    pose_ir_to_plan: NDArray[np.float64],
    profile: dict,
    size: str,
    rng: np.random.Generator,
    *,
    noise: bool = True,
    texture_poor: bool = False,
    cfg: SensorConfig = SensorConfig(),
) -> tuple[NDArray[np.uint8], NDArray[np.uint16]]:
    """One synchronized RGB-D frame of an RGB-D sensor profile.

    pose_ir_to_plan: (4, 4) IR/depth camera-to-plan pose (OpenCV axes). Returns rgb (H, W, 3) uint8 from
    the RGB camera (at the profile's ir_to_rgb offset, own K and distortion) and depth_mm (H', W') uint16
    z-depth registered to the IR camera, 0 = no return (glass, dark, beyond max range, too near).
    noise=False turns off every random and systematic error (the device quantization stays);
    texture_poor makes paint nearly uniform (the hallway)."""
    depth_mm = render_depth_mm(scene_mesh, pose_ir_to_plan, profile, size, rng, noise=noise, cfg=cfg)
    rgb_cam = camera_model(profile, "rgb", size)
    rgb = render_colour(
        scene_mesh,
        rgb_pose(pose_ir_to_plan, profile),
        rgb_cam,
        rng if noise else None,
        texture_poor=texture_poor,
        cfg=cfg,
    )
    return rgb, depth_mm


def render_depth_mm(
    scene_mesh: SceneMesh,
    pose_ir_to_plan: NDArray[np.float64],
    profile: dict,
    size: str,
    rng: np.random.Generator,
    *,
    noise: bool = True,
    cfg: SensorConfig = SensorConfig(),
) -> NDArray[np.uint16]:
    """The depth image (H, W) uint16 mm of `render_rgbd` alone (0 = no return)."""
    if profile.get("kind") != "rgbd":
        raise ValueError(
            f"sensor profile {profile.get('name')!r} is not an RGB-D camera (kind {profile.get('kind')!r})"
        )
    ir = camera_model(profile, "ir", size)
    z = render_depth_z(scene_mesh, pose_ir_to_plan, ir, cfg)
    noise_rng = rng if noise else None
    return simulate_depth_mm(z.ravel(), profile, noise_rng, _radial_weight(ir), cfg).reshape(z.shape)


def render_tls_cloud(
    scene_mesh: SceneMesh,
    scanner_positions: NDArray[np.float64],
    rng: np.random.Generator,
    step_deg: float = 0.8,
    cfg: SensorConfig = SensorConfig(),
) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
    """A TLS-like registered cloud: a spherical scan (azimuth 0-360 deg, elevation from
    tls_elevation_min_deg to 90 deg, both in steps of step_deg) from each scanner position (S, 3), range
    noise tls_sigma_m along the beam, no return from glass or beyond range.

    Returns points (N, 3) float64 metres in the plan frame and colours (N, 3) uint8 (texture under even
    lighting). About 80 k points per position at the default step."""
    pos = np.asarray(scanner_positions, dtype=np.float64).reshape(-1, 3)
    if len(pos) == 0 or not np.all(np.isfinite(pos)):
        raise ValueError("TLS scanner positions must be a non-empty finite (S, 3) array")
    if not 0.01 <= step_deg <= 10.0:
        raise ValueError(f"TLS step_deg must be within 0.01..10, got {step_deg}")
    scene = raycasting_scene(scene_mesh)
    table = _material_table(scene_mesh)
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    el = np.radians(np.arange(cfg.tls_elevation_min_deg, 90.0, step_deg))
    aa, ee = np.meshgrid(az, el)
    dirs = np.stack([np.cos(ee) * np.cos(aa), np.cos(ee) * np.sin(aa), np.sin(ee)], axis=-1).reshape(-1, 3)
    kinds = np.array(table.kinds)
    mesh_mat = np.asarray(scene_mesh.material)
    all_pts, all_cols = [], []
    for p in pos:
        hit = _cast(scene, np.broadcast_to(p, dirs.shape), dirs)
        t = hit["t"]
        ok = np.isfinite(t) & (t >= cfg.tls_min_range_m) & (t <= cfg.tls_max_range_m)
        mats = mesh_mat[np.where(ok, hit["prim"], 0)]
        ok &= kinds[mats] != "glass"
        t, d, mats, normal = t[ok], dirs[ok], mats[ok], hit["normal"][ok]
        true_pts = p + d * t[:, None]
        albedo = surface_colour(true_pts, mats, table, cfg.paint_contrast)
        facing = np.abs(np.einsum("ij,ij->i", normal, d))
        col = albedo * (0.75 + 0.25 * facing)[:, None]
        noisy = p + d * (t + rng.normal(0.0, cfg.tls_sigma_m, size=t.shape))[:, None]
        all_pts.append(noisy)
        all_cols.append(np.clip(np.rint(col), 0, 255).astype(np.uint8))
    return np.concatenate(all_pts), np.concatenate(all_cols)
