"""The camera library of the RGB-D pipeline (thesis 3.1.2, 3.1.3, 6.1): what calibrate produces and sfm, scale,
register and the sensor simulator use.

- `CameraModel` (pinhole + Brown distortion in OpenCV's form), `RigidPose`, the Kinect v1 `DepthModel`
  (eq 3.11-3.12) and the survey's `Calibration` with the small reports it serialises.
- Depth → 3D points (eq 3.13) through the undistorted IR rays, for raw disparity, mm, m and TUM/5000 depth.
- Colouring (eq 3.14-3.15): IR→RGB, projection with the RGB intrinsics and distortion, bilinear sampling. Points
  outside the RGB image or hidden from the RGB camera (z-buffer) are flagged uncoloured, never given a colour.
- The thesis' Kinect v1 (tables 6.1, 6.2) and a sensor profile's values as a `Calibration`.

Conventions
- Camera frames are the computer-vision ones (x right, y down, z forward, metres), not the photogrammetric
  ones of eq 3.1-3.13 (y up, looking down -z); `thesis_kinect_v1()` converts the thesis tables.
- `ir_to_rgb` maps points: X_rgb = R · X_ir + t_m (eq 3.14); it is what OpenCV's stereo calibration returns.
- Reprojection RMS is the root mean square of the 2D residual length over all points (OpenCV's definition).
- Pixel centres are at integer coordinates (OpenCV).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

DepthKind = Literal["disparity", "mm", "m", "tum5000"]
DEPTH_KINDS: tuple[str, ...] = ("disparity", "mm", "m", "tum5000")
RejectKind = Literal["no_target", "partial", "blurred", "high_residual"]


# ---------------------------------------------------------------------------------------------------------
# Data


def _frozen_array(a: Any, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    arr = np.array(a, dtype=np.float64).reshape(-1)
    if arr.size != int(np.prod(shape)):
        raise ValueError(f"{what} must have {int(np.prod(shape))} values, got {arr.size}")
    arr = arr.reshape(shape)
    if not np.isfinite(arr).all():
        raise ValueError(f"{what} has non-finite values")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class CameraModel:
    """Pinhole camera with Brown distortion in OpenCV's form."""

    K: NDArray[np.float64]
    """(3, 3) calibration matrix in pixels."""
    dist: NDArray[np.float64]
    """(5,) k1 k2 p1 p2 k3 (OpenCV order; normalized image coordinates)."""
    size: tuple[int, int]
    """(width, height) in pixels."""
    rms_px: float | None = None
    """Reprojection RMS of the adjustment that produced it (None for profile values)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _frozen_array(self.K, (3, 3), "K"))
        dist = np.zeros(5)
        given = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if given.size > 5:
            raise ValueError(f"dist must have at most 5 values (k1 k2 p1 p2 k3), got {given.size}")
        dist[: given.size] = given
        object.__setattr__(self, "dist", _frozen_array(dist, (5,), "dist"))
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise ValueError(f"camera size must be positive, got {self.size}")
        object.__setattr__(self, "size", (w, h))
        if self.rms_px is not None:
            object.__setattr__(self, "rms_px", float(self.rms_px))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraModel):
            return NotImplemented
        return (
            np.array_equal(self.K, other.K)
            and np.array_equal(self.dist, other.dist)
            and self.size == other.size
            and self.rms_px == other.rms_px
        )

    __hash__ = object.__hash__

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    def distort(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) ideal normalized coordinates → distorted normalized coordinates (Brown model)."""
        k1, k2, p1, p2, k3 = self.dist
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.stack([xd, yd], axis=1)

    @functools.cached_property
    def max_valid_radius(self) -> float:
        """Normalized radius where the radial polynomial folds back (d(r·radial)/dr = 0), inf if never: beyond
        it the model maps rays far outside the field of view back into the image, so `project` refuses them."""
        k1, k2, _p1, _p2, k3 = self.dist
        roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]) if (k1, k2, k3) != (0, 0, 0) else []
        s = [float(r.real) for r in roots if abs(r.imag) < 1e-12 and r.real > 0]
        return float(np.sqrt(min(s))) if s else float("inf")

    def project(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(N, 3) points in this camera's frame → ((N, 2) pixel u v with distortion, (N,) depth z).
        Points with z <= 0, or so far off-axis that the distortion model folds (`max_valid_radius`), get NaN."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        z = pts[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pts[:, :2] / np.where(z > 0, z, np.nan)[:, None]
        xy[np.hypot(xy[:, 0], xy[:, 1]) >= self.max_valid_radius] = np.nan
        xd = self.distort(xy)
        uv = np.empty_like(xd)
        uv[:, 0] = self.K[0, 0] * xd[:, 0] + self.K[0, 1] * xd[:, 1] + self.K[0, 2]
        uv[:, 1] = self.K[1, 1] * xd[:, 1] + self.K[1, 2]
        return uv, z

    def pixels(
        self, points: NDArray[np.float64]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
        """(N, 3) points in this camera's frame → the column u, row v (rounded to the nearest pixel) and depth z
        of those that land inside the image in front of the camera, in their order."""
        uv, z = self.project(points)
        ok = np.isfinite(uv).all(axis=1) & (np.abs(uv) < 1e6).all(axis=1) & (z > 0)
        ui = np.rint(uv[ok, 0]).astype(np.intp)
        vi = np.rint(uv[ok, 1]).astype(np.intp)
        w, h = self.size
        inside = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
        return ui[inside], vi[inside], z[ok][inside]

    def undistort_pixels(self, uv: NDArray[np.float64], iterations: int = 20) -> NDArray[np.float64]:
        """(N, 2) distorted pixels → (N, 2) ideal normalized coordinates (Newton's method on the Brown
        model). Pixels where the model does not invert (far outside its fitted domain) get NaN."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        fx, s, cx = self.K[0]
        fy, cy = self.K[1, 1], self.K[1, 2]
        yd = (uv[:, 1] - cy) / fy
        xd = (uv[:, 0] - cx - s * yd) / fx
        k1, k2, p1, p2, k3 = self.dist
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
            fxv = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            fyv = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
            b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
            d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
            det = a * d - b * b
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (d * fxv - b * fyv) / det
                dy = (a * fyv - b * fxv) / det
            x = x - dx
            y = y - dy
            if np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) < 1e-12:
                break
        out = np.stack([x, y], axis=1)
        back = self.distort(out)
        bad = ~(np.abs(back - np.stack([xd, yd], axis=1)).max(axis=1) < 1e-9)
        out[bad] = np.nan
        return out

    def pixel_rays(self, shift_x_px: float = 0.0) -> NDArray[np.float64]:
        """(h, w, 2) ideal normalized coordinates of every pixel centre, the column shifted by `shift_x_px`
        first (cached; read-only)."""
        return _pixel_rays_cached(self.K.tobytes(), self.dist.tobytes(), self.size, float(shift_x_px))

    def scaled(self, size: tuple[int, int]) -> CameraModel:
        """The same camera at another resolution of the same aspect (binned or upsampled stream)."""
        sx, sy = size[0] / self.size[0], size[1] / self.size[1]
        if abs(sx - sy) > 1e-6:
            raise ValueError(f"cannot scale a {self.size[0]}x{self.size[1]} camera to {size[0]}x{size[1]}")
        K = self.K.copy()
        K[0] *= sx
        K[1] *= sy
        K[0, 2] = (self.cx + 0.5) * sx - 0.5
        K[1, 2] = (self.cy + 0.5) * sy - 0.5
        return CameraModel(K, self.dist, size, self.rms_px)

    def to_json(self) -> dict[str, Any]:
        return {
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "size": list(self.size),
            "rms_px": self.rms_px,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CameraModel:
        return cls(np.array(d["K"]), np.array(d["dist"]), tuple(d["size"]), d.get("rms_px"))


@functools.lru_cache(maxsize=8)
def _pixel_rays_cached(K_bytes: bytes, dist_bytes: bytes, size: tuple[int, int], shift: float) -> NDArray:
    cam = CameraModel(np.frombuffer(K_bytes).reshape(3, 3), np.frombuffer(dist_bytes), size)
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64) + shift, np.arange(h, dtype=np.float64))
    rays = cam.undistort_pixels(np.stack([u.ravel(), v.ravel()], axis=1)).reshape(h, w, 2)
    rays.setflags(write=False)
    return rays


@dataclass(frozen=True, eq=False)
class RigidPose:
    """A rigid transform of points: X' = R · X + t_m."""

    R: NDArray[np.float64]
    """(3, 3) rotation."""
    t_m: NDArray[np.float64]
    """(3,) translation in metres."""

    def __post_init__(self) -> None:
        R = _frozen_array(self.R, (3, 3), "R")
        if abs(np.linalg.det(R) - 1.0) > 1e-6 or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError("R is not a rotation matrix")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t_m", _frozen_array(self.t_m, (3,), "t_m"))

    def apply(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 3) → (N, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        # written out rather than a BLAS matmul: a (N, 3) x (3, 3) product gains nothing from threads and
        # suffers badly when the cores are busy
        R, t = self.R, self.t_m
        return np.stack(
            [
                R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0],
                R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1],
                R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2],
            ],
            axis=1,
        )

    @property
    def matrix(self) -> NDArray[np.float64]:
        """(4, 4) homogeneous form (H_IR→RGB of eq 3.14)."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t_m
        return m

    def inverse(self) -> RigidPose:
        return RigidPose(self.R.T, -self.R.T @ self.t_m)

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(Rotation.from_matrix(self.R).as_rotvec())))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RigidPose):
            return NotImplemented
        return np.array_equal(self.R, other.R) and np.array_equal(self.t_m, other.t_m)

    __hash__ = object.__hash__


@dataclass(frozen=True)
class FlatTargetResidual:
    """How one flat-target disparity frame fits the disparity model."""

    name: str
    distance_m: float
    """Known distance (mean over the used pixels when a per-pixel distance was given)."""
    n_pixels: int
    mean_raw: float
    """Mean raw Kinect disparity d_k over the used pixels."""
    residual_raw: float
    """Observed minus modelled mean d_k."""
    depth_error_m: float
    """Depth from the model at the observed mean d_k minus the known distance."""


@dataclass(frozen=True)
class DepthModel:
    """Kinect v1 raw disparity → depth (eq 3.11-3.12): H = b·c / ((offset − d_k) · subpixel_scale)."""

    offset: float
    """Raw disparity offset (d_k units)."""
    bc_m_px: float
    """Baseline times IR focal length, b·c, in metre-pixels."""
    focal_px: float | None = None
    """IR focal length c used to split b·c (None when no IR calibration was at hand)."""
    shift_x_px: float = 4.0
    """IR column = disparity column + shift_x_px (correlation window of the Kinect, thesis 6.1.1)."""
    subpixel_scale: float = 0.125
    """The 1/8 of eq 3.11: raw units per pixel of disparity."""
    invalid_raw: int = 2047
    """Raw values at or above this mark pixels without a measurement."""
    rms_raw: float | None = None
    """RMS of the per-pixel d_k residuals of the fit (includes the sensor noise)."""
    rms_depth_m: float | None = None
    """RMS over frames of the depth error at each frame's mean disparity."""
    residuals: tuple[FlatTargetResidual, ...] = ()

    @property
    def baseline_m(self) -> float | None:
        return None if not self.focal_px else self.bc_m_px / self.focal_px

    def depth_from_raw(self, raw: NDArray) -> NDArray[np.float64]:
        """Raw d_k (any shape) → depth H in metres; NaN where invalid or at/behind the reference singularity."""
        dk = np.asarray(raw, dtype=np.float64)
        denom = (self.offset - dk) * self.subpixel_scale
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = self.bc_m_px / denom
        return np.where((dk < self.invalid_raw) & (denom > 0), depth, np.nan)

    def raw_from_depth(self, depth_m: NDArray, quantize: bool = True) -> NDArray:
        """Depth in metres → raw d_k (the inverse of eq 3.12, for simulators); invalid where depth is not
        positive and finite or d_k falls outside [0, invalid_raw)."""
        depth = np.asarray(depth_m, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            dk = self.offset - self.bc_m_px / (depth * self.subpixel_scale)
        ok = np.isfinite(dk) & (depth > 0)
        if quantize:
            dk = np.rint(dk)
        ok &= (dk >= 0) & (dk < self.invalid_raw)
        if quantize:
            return np.where(ok, dk, self.invalid_raw).astype(np.uint16)
        return np.where(ok, dk, np.nan)

    def to_json(self) -> dict[str, Any]:
        return {
            "offset": self.offset,
            "bc_m_px": self.bc_m_px,
            "baseline_m": self.baseline_m,
            "focal_px": self.focal_px,
            "shift_x_px": self.shift_x_px,
            "subpixel_scale": self.subpixel_scale,
            "invalid_raw": self.invalid_raw,
            "rms_raw": self.rms_raw,
            "rms_depth_m": self.rms_depth_m,
            "residuals": [r.__dict__ for r in self.residuals],
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> DepthModel:
        focal = d.get("focal_px")
        bc = d.get("bc_m_px")
        if bc is None:
            if d.get("baseline_m") is None or not focal:
                raise ValueError("depth model needs bc_m_px, or baseline_m together with focal_px")
            bc = float(d["baseline_m"]) * float(focal)
        return cls(
            offset=float(d["offset"]),
            bc_m_px=float(bc),
            focal_px=None if focal is None else float(focal),
            shift_x_px=float(d.get("shift_x_px", 4.0)),
            subpixel_scale=float(d.get("subpixel_scale", 0.125)),
            invalid_raw=int(d.get("invalid_raw", 2047)),
            rms_raw=d.get("rms_raw"),
            rms_depth_m=d.get("rms_depth_m"),
            residuals=tuple(FlatTargetResidual(**r) for r in d.get("residuals", ())),
        )


@dataclass(frozen=True)
class Reject:
    """A calibration image left out, and why."""

    file: str
    camera: str
    """"ir" or "rgb"."""
    kind: RejectKind
    reason: str

    def __str__(self) -> str:
        return f"{self.file} ({self.kind}: {self.reason})"


@dataclass(frozen=True)
class Redetection:
    """A target point found again where the first adjustment put it: its detection sat `shift_px` away
    (a corner refinement stuck at a wrong start), its residual went from `before_px` to `after_px`."""

    file: str
    camera: str
    point: int
    """Index of the point in the pattern's order."""
    shift_px: float
    before_px: float
    after_px: float


@dataclass(frozen=True)
class ViewResidual:
    """Reprojection RMS of one view (or synchronized pair) in the final adjustment; None for the camera whose
    image of the pair was not used."""

    ir: str | None
    rms_ir_px: float | None
    rgb: str | None = None
    rms_rgb_px: float | None = None


@dataclass(frozen=True)
class Calibration:
    """The survey's sensor calibration: one artefact used by every room."""

    ir: CameraModel
    """The depth/IR camera (the camera the depth image is registered to)."""
    rgb: CameraModel | None = None
    ir_to_rgb: RigidPose | None = None
    """X_rgb = R · X_ir + t_m (eq 3.14)."""
    stereo_rms_px: float | None = None
    depth_model: DepthModel | None = None
    source: Literal["targets", "profile"] = "targets"
    """Where the values come from: the survey's calibration images, or the sensor profile (fallback)."""
    rejects: tuple[Reject, ...] = ()
    views: tuple[ViewResidual, ...] = ()
    pattern: str | None = None
    profile_name: str | None = None
    coverage: tuple[tuple[str, float], ...] = ()
    """(camera, share of image cells with target points) per calibrated camera."""
    redetected: tuple[Redetection, ...] = ()
    """Target points detected again at their reprojection (see `tasks.calibrate.bundle.redetect_outliers`)."""

    def __post_init__(self) -> None:
        if (self.rgb is None) != (self.ir_to_rgb is None):
            raise ValueError("an RGB camera and the IR→RGB pose go together: give both or neither")

    @property
    def baseline_mm(self) -> float | None:
        """IR–RGB distance in millimetres (length of the RGB camera centre in the IR frame)."""
        return None if self.ir_to_rgb is None else float(np.linalg.norm(self.ir_to_rgb.t_m) * 1000.0)

    def to_json(self) -> dict[str, Any]:
        """Exactly the calibration.json schema: ir, [rgb, ir_to_rgb], stereo_rms_px, depth_model."""
        out: dict[str, Any] = {"ir": self.ir.to_json()}
        if self.rgb is not None and self.ir_to_rgb is not None:
            out["rgb"] = self.rgb.to_json()
            out["ir_to_rgb"] = {"R": self.ir_to_rgb.R.tolist(), "t_m": self.ir_to_rgb.t_m.tolist()}
        out["stereo_rms_px"] = self.stereo_rms_px
        out["depth_model"] = None if self.depth_model is None else self.depth_model.to_json()
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any], source: Literal["targets", "profile"] | None = None) -> Calibration:
        """Inverse of `to_json` (rejects and per-view residuals live in the residuals file, not here)."""
        rgb = CameraModel.from_json(d["rgb"]) if d.get("rgb") is not None else None
        pose = None
        if d.get("ir_to_rgb") is not None:
            pose = RigidPose(np.array(d["ir_to_rgb"]["R"]), np.array(d["ir_to_rgb"]["t_m"]))
        dm = d.get("depth_model")
        return cls(
            ir=CameraModel.from_json(d["ir"]),
            rgb=rgb,
            ir_to_rgb=pose,
            stereo_rms_px=d.get("stereo_rms_px"),
            depth_model=None if dm is None else DepthModel.from_json(dm),
            source=source or d.get("source", "targets"),
        )

    def residuals_json(self) -> dict[str, Any]:
        """The companion report: where the values come from, per-view residuals, rejects with reasons."""
        return {
            "source": self.source,
            "profile": self.profile_name,
            "pattern": self.pattern,
            "baseline_mm": self.baseline_mm,
            "rms_px": {
                "ir": self.ir.rms_px,
                "rgb": None if self.rgb is None else self.rgb.rms_px,
                "stereo": self.stereo_rms_px,
            },
            "views": [v.__dict__ for v in self.views],
            "coverage": dict(self.coverage),
            "rejects": [r.__dict__ for r in self.rejects],
            "redetected": [r.__dict__ for r in self.redetected],
            "depth_model": None if self.depth_model is None else self.depth_model.to_json(),
        }


# ---------------------------------------------------------------------------------------------------------
# Depth → points → colour


def depth_to_metres(
    depth: NDArray, kind: DepthKind, depth_model: DepthModel | None = None
) -> NDArray[np.float64]:
    """Any depth convention → depth z in metres, NaN where there is no measurement."""
    d = np.asarray(depth)
    if kind == "disparity":
        if depth_model is None:
            raise ValueError(
                "raw Kinect disparity needs a depth model (offset, b·c): calibrate or use a profile"
            )
        return depth_model.depth_from_raw(d)
    if kind == "mm":
        f = d.astype(np.float64)
        bad = (f <= 0) | (f >= 65535) | ~np.isfinite(f)
        return np.where(bad, np.nan, f / 1000.0)
    if kind == "tum5000":
        f = d.astype(np.float64)
        return np.where((f <= 0) | ~np.isfinite(f), np.nan, f / 5000.0)
    if kind == "m":
        f = d.astype(np.float64)
        return np.where((f <= 0) | ~np.isfinite(f), np.nan, f)
    raise ValueError(f"unknown depth kind {kind!r}: expected one of {', '.join(DEPTH_KINDS)}")


def depth_to_points(
    depth: NDArray,
    kind: DepthKind,
    camera: CameraModel,
    depth_model: DepthModel | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Depth image → 3D points in the depth (IR) camera frame (eq 3.13 through undistorted rays).

    depth: (H, W) in the convention `kind` — "disparity" raw Kinect v1 11-bit d_k (needs `depth_model`; its
    `shift_x_px` moves each disparity column onto the IR column it belongs to), "mm" (0 and 65535 invalid),
    "m" (float), "tum5000" (uint16 / 5000). The image must be registered to `camera` and have its size.
    Returns ((N, 3) points in metres, x right y down z forward; (N, 2) their (row, col) in `depth`)."""
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth image must be (H, W), got shape {d.shape}")
    if (d.shape[1], d.shape[0]) != camera.size:
        raise ValueError(
            f"depth image is {d.shape[1]}x{d.shape[0]} but the camera is {camera.size[0]}x{camera.size[1]}"
        )
    z = depth_to_metres(d, kind, depth_model)
    shift = depth_model.shift_x_px if kind == "disparity" and depth_model is not None else 0.0
    rays = camera.pixel_rays(shift)
    valid = np.isfinite(z) & np.isfinite(rays).all(axis=2)
    rows, cols = np.nonzero(valid)
    zz = z[rows, cols]
    xy = rays[rows, cols]
    points = np.stack([xy[:, 0] * zz, xy[:, 1] * zz, zz], axis=1)
    return points, np.stack([rows, cols], axis=1).astype(np.intp)


def strided_depth_points(
    depth_m: NDArray[np.floating], camera: CameraModel, stride: int
) -> NDArray[np.float64]:
    """`depth_to_points` of a depth image in metres (0/NaN = none) on every `stride`-th pixel of every
    `stride`-th row only, in the same order: (N, 3) points in the camera frame."""
    d = np.asarray(depth_m)
    if d.ndim != 2 or (d.shape[1], d.shape[0]) != camera.size:
        raise ValueError(
            f"depth image of shape {d.shape} does not fit the {camera.size[0]}x{camera.size[1]} camera"
        )
    z = d[::stride, ::stride].astype(np.float64)
    rays = camera.pixel_rays()[::stride, ::stride]
    with np.errstate(invalid="ignore"):
        keep = (z > 0) & np.isfinite(z) & np.isfinite(rays).all(axis=2)
    zz = z[keep]
    return np.column_stack([rays[keep] * zz[:, None], zz])


def _bilinear(img: NDArray, u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.uint8]:
    """(N, C) bilinear samples of an (H, W, C) uint8 image at pixel coordinates inside [0, W-1] × [0, H-1]
    (cv2.remap over the points laid out in rows of 4096, under its 32767-pixel limit)."""
    n = u.size
    width = 4096
    rows = max(1, -(-n // width))
    mx = np.zeros(rows * width, np.float32)
    my = np.zeros(rows * width, np.float32)
    mx[:n] = u
    my[:n] = v
    out = cv2.remap(
        np.ascontiguousarray(img),
        mx.reshape(rows, width),
        my.reshape(rows, width),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape(rows * width, -1)[:n]


def colour_points(
    points_ir: NDArray[np.float64],
    rgb_image: NDArray,
    calib: Calibration,
    occlusion_tol_m: float = 0.02,
    occlusion_tol_rel: float = 0.02,
    zbuffer_splat_px: int = 3,
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Colour for each IR-frame point from the RGB image (eq 3.14 IR→RGB, eq 3.15 projection with the RGB
    intrinsics and distortion, bilinear sampling).

    rgb_image: (H, W, 3) uint8 (colours come back in its channel order) or (H, W) grey, of the calibrated RGB
    size. Returns ((N, 3) uint8 colours, zero where uncoloured; (N,) valid mask). A point is uncoloured when it
    is not finite, behind the RGB camera, projects outside the image, or is hidden from the RGB camera by a
    nearer point (z-buffer over the projected cloud, each point splatted over `zbuffer_splat_px`, odd, so
    that background points cannot show through the gaps between projected foreground points): farther
    than `occlusion_tol_m` plus `occlusion_tol_rel` times its depth behind the nearest point there."""
    if calib.rgb is None or calib.ir_to_rgb is None:
        raise ValueError(
            "the calibration has no RGB camera: calibrate with --rgb images or use a sensor profile"
        )
    img = np.asarray(rgb_image)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ValueError(f"RGB image must be (H, W, 3), got shape {img.shape}")
    img = img[:, :, :3]
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    if (w, h) != calib.rgb.size:
        raise ValueError(
            f"RGB image is {w}x{h} but the calibration's RGB camera is {calib.rgb.size[0]}x{calib.rgb.size[1]}"
        )
    pts = np.asarray(points_ir, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    colors = np.zeros((n, 3), np.uint8)
    finite = np.isfinite(pts).all(axis=1)
    p_rgb = calib.ir_to_rgb.apply(np.where(finite[:, None], pts, 0.0))
    uv, z = calib.rgb.project(p_rgb)
    ok = finite & (z > 1e-6) & np.isfinite(uv).all(axis=1)
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return colors, ok
    ui = np.rint(uv[idx, 0]).astype(np.intp)
    vi = np.rint(uv[idx, 1]).astype(np.intp)
    zbuf = np.full((h, w), np.inf, np.float32)
    np.minimum.at(zbuf, (vi, ui), z[idx].astype(np.float32))
    k = max(1, int(zbuffer_splat_px) | 1)
    if k > 1:
        zbuf = cv2.erode(zbuf, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    tol = occlusion_tol_m + occlusion_tol_rel * z[idx]
    visible = z[idx] <= zbuf[vi, ui] + tol
    ok[idx[~visible]] = False
    idx = idx[visible]
    if idx.size:
        colors[idx] = _bilinear(img, uv[idx, 0], uv[idx, 1])
    return colors, ok


# ---------------------------------------------------------------------------------------------------------
# The thesis' Kinect v1 values and sensor profiles


def photogrammetric_to_opencv(
    c_px: float,
    xp_px: float,
    yp_px: float,
    K1: float,
    K2: float,
    K3: float,
    P1: float,
    P2: float,
    size: tuple[int, int],
    pixel_mm: float = 1e-3,
) -> tuple[CameraModel, float]:
    """A camera in the photogrammetric form of thesis table 6.1 → OpenCV form, and the fit's largest
    disagreement in pixels over the image.

    Input convention (eq 3.4-3.7): image coordinates in mm (pixel size `pixel_mm`), x right, y up, from the
    image centre; (xp, yp) the principal point offset; corrections Δ evaluated at distorted coordinates reduced
    to the principal point, with measured = ideal + Δ. OpenCV's forward model (ideal → distorted) is fitted to
    this inverse one by linear least squares over a dense pixel grid."""
    w, h = size
    c = c_px * pixel_mm
    u, v = np.meshgrid(np.linspace(0, w - 1, 81), np.linspace(0, h - 1, 61))
    x = (u - (w / 2 - 0.5)) * pixel_mm - xp_px * pixel_mm
    y = -(v - (h / 2 - 0.5)) * pixel_mm - yp_px * pixel_mm
    r2 = x * x + y * y
    radial = K1 * r2 + K2 * r2**2 + K3 * r2**3
    dx = x * radial + P2 * (r2 + 2 * x * x) + 2 * P1 * x * y
    dy = y * radial + P1 * (r2 + 2 * y * y) + 2 * P2 * x * y
    xi, yi = ((x - dx) / c).ravel(), (-(y - dy) / c).ravel()
    xd, yd = (x / c).ravel(), (-y / c).ravel()
    q2 = xi * xi + yi * yi
    n = xi.size
    A = np.zeros((2 * n, 5))
    A[:n] = np.stack([xi * q2, xi * q2**2, 2 * xi * yi, q2 + 2 * xi * xi, xi * q2**3], axis=1)
    A[n:] = np.stack([yi * q2, yi * q2**2, q2 + 2 * yi * yi, 2 * xi * yi, yi * q2**3], axis=1)
    b = np.concatenate([xd - xi, yd - yi])
    k, *_ = np.linalg.lstsq(A, b, rcond=None)
    worst = float(np.abs(A @ k - b).max() * c_px)
    K = np.array([[c_px, 0, w / 2 - 0.5 + xp_px], [0, c_px, h / 2 - 0.5 - yp_px], [0, 0, 1.0]])
    return CameraModel(K, k, size), worst


def thesis_kinect_v1(size: tuple[int, int] = (640, 480)) -> Calibration:
    """The Kinect v1 of thesis tables 6.1 and 6.2 in OpenCV form (source="profile").

    Table 6.2 gives the RGB camera centre in the IR frame (ΔX 23.9, ΔY 1.2, ΔZ 0.7 mm; heading −0.2°,
    elevation −0.1°, roll 0.1°) in photogrammetric axes; here y and z are flipped to OpenCV's and the angles
    are taken as a small rotation about y (heading), x (elevation) and z (roll). The disparity model is not in
    the thesis' tables: offset 1090 and b = 7.5 cm (thesis 6.1.2, ROS kinect_calibration) are typical values."""
    ir, _ = photogrammetric_to_opencv(
        585.7, 0.6, -9.1, 3.75303e-1, -3.94502, 1.37589e1, 2.60056e-4, 2.51454e-3, size
    )
    rgb, _ = photogrammetric_to_opencv(
        521.9, -0.3, -16.5, -6.63541e-1, 6.59073, -2.02217e1, 5.79941e-4, -1.13229e-3, size
    )
    centre = np.array([23.9, -1.2, -0.7]) / 1000.0
    heading, elevation, roll = np.radians([-0.2, -0.1, 0.1])
    R_rgb_in_ir = Rotation.from_rotvec([elevation, -heading, -roll]).as_matrix()
    pose = RigidPose(R_rgb_in_ir.T, -R_rgb_in_ir.T @ centre)
    depth = DepthModel(offset=1090.0, bc_m_px=0.075 * ir.fx, focal_px=ir.fx, shift_x_px=4.0)
    return Calibration(ir, rgb, pose, None, depth, source="profile", profile_name="thesis_kinect_v1")


def _profile_camera(d: dict[str, Any], what: str, profile: str) -> CameraModel:
    if "K" in d:
        K = np.array(d["K"], dtype=np.float64)
    else:
        try:
            fx = float(d["fx"])
        except KeyError:
            raise ValueError(
                f"sensor profile {profile!r}: {what} camera needs K or fx (fy, cx, cy)"
            ) from None
        fy = float(d.get("fy", fx))
        K = None
    if "size" in d:
        size = (int(d["size"][0]), int(d["size"][1]))
    elif "width" in d and "height" in d:
        size = (int(d["width"]), int(d["height"]))
    else:
        raise ValueError(f"sensor profile {profile!r}: {what} camera needs size [w, h] or width and height")
    if K is None:
        K = np.array(
            [
                [fx, 0, float(d.get("cx", (size[0] - 1) / 2))],
                [0, fy, float(d.get("cy", (size[1] - 1) / 2))],
                [0, 0, 1],
            ]
        )
    dist = d.get("dist", d.get("distortion", [0.0] * 5))
    return CameraModel(K, np.array(dist, dtype=np.float64), size, d.get("rms_px"))


def _heading_elevation_roll(angles_deg: Sequence[float]) -> NDArray[np.float64]:
    """Rotation of thesis table 6.2's angles in camera axes: Ry(heading) · Rx(elevation) · Rz(roll)."""
    h, e, r = np.radians(np.asarray(angles_deg, dtype=np.float64))
    return Rotation.from_euler("YXZ", [h, e, r]).as_matrix()


def profile_calibration(sensor_profile: dict[str, Any]) -> Calibration:
    """The fallback when a survey has no calibration data: the sensor profile's values, source="profile".

    Layout (configs/sensors/*.yaml; also accepted under a `calibration` key):
      ir | depth:  {K: 3x3 | fx, fy, cx, cy; size: [w, h] | width, height; dist: [k1, k2, p1, p2, k3]}
      rgb | color: {same}                                                 (optional)
      ir_to_rgb:   {t_m, heading_elevation_roll_deg}: the RGB camera's pose in the IR frame (thesis table
                   6.2; X_ir = Ry(h) Rx(e) Rz(r) X_rgb + t_m), or {R, t_m}: the point transform
                   X_rgb = R X_ir + t_m of calibration.json. Absent with `registered: true` (depth already
                   registered to colour): identity.
      depth:       {convention: disparity, disparity_offset, disparity_bc_m_px, disparity_shift_px}, or
      depth_model: the calibration.json form {offset, bc_m_px | baseline_m, shift_x_px, focal_px}.
    A profile without an IR/depth camera (a TLS) is an error: there is nothing to calibrate."""
    name = str(sensor_profile.get("name", "?"))
    d = sensor_profile.get("calibration", sensor_profile)
    if not isinstance(d, dict):
        raise ValueError(f"sensor profile {name!r}: calibration must be a mapping")
    ir_d = d.get("ir")
    if (
        not isinstance(ir_d, dict)
        and isinstance(d.get("depth"), dict)
        and ("K" in d["depth"] or "fx" in d["depth"])
    ):
        ir_d = d["depth"]
    if not isinstance(ir_d, dict):
        raise ValueError(f"sensor profile {name!r} has no IR/depth camera intrinsics (key ir)")
    ir = _profile_camera(ir_d, "ir", name)
    rgb_d = d.get("rgb", d.get("color"))
    rgb = _profile_camera(rgb_d, "rgb", name) if isinstance(rgb_d, dict) else None
    pose = None
    if rgb is not None:
        p = d.get("ir_to_rgb")
        if p is None:
            if not d.get("registered", False):
                raise ValueError(
                    f"sensor profile {name!r} has an RGB camera but no ir_to_rgb pose (or registered: true)"
                )
            pose = RigidPose(np.eye(3), np.zeros(3))
        elif "R" in p:
            pose = RigidPose(
                np.array(p["R"], dtype=np.float64), np.array(p.get("t_m", [0, 0, 0]), dtype=np.float64)
            )
        else:
            R_pose = _heading_elevation_roll(p.get("heading_elevation_roll_deg", [0.0, 0.0, 0.0]))
            centre = np.array(p.get("t_m", [0, 0, 0]), dtype=np.float64)
            pose = RigidPose(R_pose.T, -R_pose.T @ centre)
    dm = None
    depth_d = d.get("depth")
    if isinstance(d.get("depth_model"), dict):
        dm_d = dict(d["depth_model"])
        dm_d.setdefault("focal_px", ir.fx)
        dm = DepthModel.from_json(dm_d)
    elif isinstance(depth_d, dict) and depth_d.get("convention") == "disparity":
        try:
            dm = DepthModel(
                offset=float(depth_d["disparity_offset"]),
                bc_m_px=float(depth_d["disparity_bc_m_px"]),
                focal_px=ir.fx,
                shift_x_px=float(depth_d.get("disparity_shift_px", 4.0)),
            )
        except KeyError as err:
            raise ValueError(f"sensor profile {name!r}: disparity depth needs depth.{err.args[0]}") from None
    return Calibration(ir, rgb, pose, None, dm, source="profile", profile_name=name)
