"""Calibrate stage: RGB-D sensor calibration and coloured point clouds (thesis 3.1.2, 3.1.3, 6.1).

What it does
- Intrinsics of the IR and the RGB camera with the Brown model (OpenCV order k1 k2 p1 p2 k3) from images of a
  chessboard or an asymmetric circle grid; blurred and partial detections are rejected with a stated reason.
- The IR→RGB relative pose by a joint adjustment of both cameras (intrinsics, distortion, relative pose and
  board poses together, as the thesis' single bundle adjustment), started from the two mono calibrations.
- The Kinect v1 disparity model (eq 3.11-3.12): offset and b·c by least squares from flat-target frames at
  known distances, with residuals; the 4-pixel shift between the disparity and the IR image.
- Depth → 3D points (eq 3.13) through the undistorted IR rays, for raw disparity, mm, m and TUM/5000 depth.
- Colouring (eq 3.14-3.15): IR→RGB, projection with the RGB intrinsics and distortion, bilinear sampling. Points
  outside the RGB image or hidden from the RGB camera (z-buffer) are flagged uncoloured, never given a colour.

Conventions
- Camera frames are the computer-vision ones (x right, y down, z forward, metres), not the photogrammetric
  ones of eq 3.1-3.13 (y up, looking down -z); `thesis_kinect_v1()` converts the thesis tables.
- `ir_to_rgb` maps points: X_rgb = R · X_ir + t_m (eq 3.14); it is what OpenCV's stereo calibration returns.
- Reprojection RMS is the root mean square of the 2D residual length over all points (OpenCV's definition).
- Pixel centres are at integer coordinates (OpenCV).
"""

from __future__ import annotations

import functools
import glob
import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

log = logging.getLogger(__name__)

CODE_VERSION = "calibrate-1"
"""Bumped when the stage's output for the same inputs and config would change."""

PatternKind = Literal["chessboard", "circles"]
DepthKind = Literal["disparity", "mm", "m", "tum5000"]
DEPTH_KINDS: tuple[str, ...] = ("disparity", "mm", "m", "tum5000")
RejectKind = Literal["no_target", "partial", "blurred", "high_residual"]


# ---------------------------------------------------------------------------------------------------------
# Configuration and the calibration target


@dataclass(frozen=True)
class CalibrateConfig:
    """Settings of the calibrate stage (section `calibrate` of the config tree)."""

    pattern: str = "chessboard:9x6:0.025"
    """Target: `chessboard:COLSxROWS:SQUARE_M` (inner corners) or `circles:COLSxROWS:SPACING_M` (asymmetric grid)."""
    detector: Literal["classic", "sb"] = "classic"
    """Chessboard detector: OpenCV's classic one refined by cornerSubPix, or the sector-based (SB) one."""
    subpix_window_px: int = 7
    """Half size of the cornerSubPix search window (classic chessboard detector), capped at 0.3 of the square
    size in the image: larger windows reach the neighbouring corners (OpenCV's sample uses 11, which costs
    its reference left02 view of the real stereo set 1.2 px RMS)."""
    max_edge_rise_px: float = 5.0
    """Blur rejection: a view whose median 10-90 % edge rise around the target points exceeds this is rejected
    (sharp Kinect/webcam views measure 2-3.5 px; a Gaussian blur of sigma 2 px gives about 5.7 px)."""
    min_border_px: float = 4.0
    """A detection with a point closer than this to the image border is rejected as partial."""
    min_views: int = 6
    """Fewest usable views per camera for a calibration (and complete pairs for the "opencv" stereo solver);
    fewer is an error naming the files."""
    max_view_rms_px: float = 2.0
    """A view whose reprojection RMS after the first adjustment exceeds this is rejected and the camera
    re-adjusted without it."""
    min_coverage: float = 0.6
    """Below this share of image cells holding target points the stage warns that the distortion near the
    borders is extrapolated (reported as `coverage` in the residuals file either way)."""
    missing_target: Literal["error", "reject"] = "error"
    """Images in which no target is found at all: an error naming them, or a reject that is reported."""
    fix_k3: bool = False
    """Hold k3 at zero (for sets too small or too central to determine it)."""
    stereo_solver: Literal["bundle", "opencv"] = "bundle"
    """Joint adjustment: "bundle" adjusts both cameras, the relative pose and every board pose over all valid
    views of either camera (a view whose partner image was rejected still counts, as in the thesis' bundle
    adjustment); "opencv" is cv2.stereoCalibrate on the complete pairs only."""
    min_stereo_pairs: int = 4
    """Fewest views with the target found in both cameras for the relative pose."""
    stereo_refine_intrinsics: bool = True
    """Re-estimate both cameras' intrinsics together with the relative pose (the thesis' joint adjustment);
    False keeps the mono intrinsics and estimates the relative pose only."""
    depth_shift_x_px: float = 4.0
    """Shift of the Kinect v1 disparity image against the IR image, in native disparity pixels: IR column =
    disparity column + shift (scaled to the IR image when that is binned, e.g. 2 px at 320x240)."""
    disparity_native_width_px: int = 640
    """Width at which the device computes disparity: raw d_k are in these pixels whatever the delivered image
    size, so b·c splits into the baseline with the IR focal length scaled to this width."""
    flat_roi_fraction: float = 0.6
    """Central part (fraction of width and height) of flat-target disparity frames used for the model fit."""
    occlusion_tol_m: float = 0.02
    """Colouring: a point counts as hidden from the RGB camera when it lies farther than this plus
    `occlusion_tol_rel` times its depth behind the nearest point projecting into its RGB neighbourhood."""
    occlusion_tol_rel: float = 0.02
    """Relative part of the occlusion tolerance (of the point's depth in the RGB camera)."""
    zbuffer_splat_px: int = 3
    """Neighbourhood (odd, pixels) over which each projected point claims the RGB z-buffer, so that background
    points cannot show through the gaps between the projected foreground points."""


@dataclass(frozen=True)
class TargetPattern:
    """A planar calibration target. Object points lie in the board's z = 0 plane, in metres."""

    kind: PatternKind
    cols: int
    """Inner corners per row (chessboard) or circles per row (asymmetric grid)."""
    rows: int
    """Inner corners per column (chessboard) or rows of circles (asymmetric grid)."""
    spacing_m: float
    """Square size (chessboard); for the asymmetric grid the row pitch s of OpenCV's layout
    ((2j + i mod 2)·s, i·s): circles in a row are 2s apart."""

    @property
    def size(self) -> tuple[int, int]:
        """OpenCV pattern size (cols, rows)."""
        return (self.cols, self.rows)

    @property
    def n_points(self) -> int:
        return self.cols * self.rows

    def object_points(self) -> NDArray[np.float32]:
        """(cols·rows, 3) board coordinates in metres, in OpenCV's detection order (row by row)."""
        i, j = np.mgrid[0 : self.rows, 0 : self.cols]
        if self.kind == "chessboard":
            x, y = j, i
        else:
            x, y = 2 * j + i % 2, i
        pts = np.zeros((self.n_points, 3), np.float32)
        pts[:, 0] = x.ravel() * self.spacing_m
        pts[:, 1] = y.ravel() * self.spacing_m
        return pts

    def __str__(self) -> str:
        return f"{self.kind}:{self.cols}x{self.rows}:{self.spacing_m:g}"

    def describe(self) -> str:
        what = "chessboard" if self.kind == "chessboard" else "asymmetric circle grid"
        return f"{self.cols}x{self.rows} {what}"


_PATTERN_RE = re.compile(r"^\s*(chessboard|circles)\s*:\s*(\d+)\s*[xX]\s*(\d+)\s*:\s*([0-9.eE+-]+)\s*$")


def parse_pattern(text: str | TargetPattern) -> TargetPattern:
    """`chessboard:9x6:0.025` (inner corners, square in metres) or `circles:4x11:0.02` (asymmetric grid)."""
    if isinstance(text, TargetPattern):
        return text
    m = _PATTERN_RE.match(text)
    if not m:
        raise ValueError(
            f"bad calibration pattern {text!r}: expected chessboard:COLSxROWS:SQUARE_M or circles:COLSxROWS:SPACING_M"
        )
    kind, cols, rows, spacing = m.group(1), int(m.group(2)), int(m.group(3)), float(m.group(4))
    if cols < 2 or rows < 2 or (kind == "chessboard" and cols * rows < 6):
        raise ValueError(f"bad calibration pattern {text!r}: the grid {cols}x{rows} is too small")
    if not (0.0 < spacing < 2.0):
        raise ValueError(
            f"bad calibration pattern {text!r}: spacing {spacing} m is not a plausible size in metres"
        )
    return TargetPattern(kind, cols, rows, spacing)  # type: ignore[arg-type]


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
            "code_version": CODE_VERSION,
            "baseline_mm": self.baseline_mm,
            "rms_px": {
                "ir": self.ir.rms_px,
                "rgb": None if self.rgb is None else self.rgb.rms_px,
                "stereo": self.stereo_rms_px,
            },
            "views": [v.__dict__ for v in self.views],
            "coverage": dict(self.coverage),
            "rejects": [r.__dict__ for r in self.rejects],
            "depth_model": None if self.depth_model is None else self.depth_model.to_json(),
        }


# ---------------------------------------------------------------------------------------------------------
# Target detection


@dataclass(frozen=True, eq=False)
class TargetDetection:
    """A complete, sharp detection of the target in one image."""

    name: str
    points: NDArray[np.float32]
    """(N, 2) image points in the order of `TargetPattern.object_points()`."""
    size: tuple[int, int]
    """(width, height) of the image."""
    edge_rise_px: float
    """Median 10-90 % edge rise around the points (the blur measure)."""


def _to_gray8(image: NDArray) -> NDArray[np.uint8]:
    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    f = img.astype(np.float64)
    finite = np.isfinite(f)
    if not finite.any():
        return np.zeros(img.shape, np.uint8)
    lo, hi = np.percentile(f[finite], [0.5, 99.5])
    scale = 255.0 / max(hi - lo, 1e-12)
    return np.clip((np.nan_to_num(f, nan=lo) - lo) * scale, 0, 255).astype(np.uint8)


def _edge_rise_px(gray: NDArray[np.uint8], points: NDArray, radius: float) -> float:
    """Median over the points of contrast / steepest gradient in a window around each: for a step edge blurred
    by a Gaussian of sigma s this is 2.5 s, close to the 10-90 % rise distance (OpenCV's chessboard sharpness)."""
    g = gray.astype(np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = cv2.magnitude(gx, gy)
    h, w = g.shape
    r = max(3, round(radius))
    rises = []
    for x, y in np.asarray(points).reshape(-1, 2):
        xi, yi = round(float(x)), round(float(y))
        x0, x1, y0, y1 = max(xi - r, 1), min(xi + r + 1, w - 1), max(yi - r, 1), min(yi + r + 1, h - 1)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        patch = g[y0:y1, x0:x1]
        lo, hi = np.percentile(patch, [5, 95])
        steep = float(mag[y0:y1, x0:x1].max())
        if hi - lo > 8 and steep > 0:
            rises.append((hi - lo) / steep)
    return float(np.median(rises)) if rises else float("inf")


def _grid_spacing_px(points: NDArray, pattern: TargetPattern) -> float:
    grid = points.reshape(pattern.rows, pattern.cols, 2)
    if pattern.kind == "chessboard":
        d = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    else:  # neighbours in adjacent rows are s·√2 apart
        d = np.linalg.norm(grid[1:, :, :] - grid[:-1, :, :], axis=2)
    return float(np.median(d))


def _canonical_order(gray: NDArray[np.uint8], points: NDArray, pattern: TargetPattern) -> NDArray | None:
    """Put the detected points in one order whatever the view, so that IR and RGB detections of the same pose
    match point for point: right-handed (board x × board y points away from the camera), and for chessboards
    whose 180° turn changes the square colours (cols + rows odd) the first inner square dark.
    None when the order cannot be made right-handed."""
    grid = points.reshape(pattern.rows, pattern.cols, 2).copy()

    def handed(gr: NDArray) -> float:
        ex = gr[:, -1].mean(axis=0) - gr[:, 0].mean(axis=0)
        ey = gr[-1, :].mean(axis=0) - gr[0, :].mean(axis=0)
        return float(ex[0] * ey[1] - ex[1] * ey[0])

    if handed(grid) < 0:
        if pattern.kind == "chessboard":
            grid = grid[:, ::-1]
        elif pattern.rows % 2 == 1:
            grid = grid[::-1, :]
        else:
            return None
    if pattern.kind == "chessboard" and (pattern.cols + pattern.rows) % 2 == 1:

        def square_mean(gr: NDArray, i: int, j: int) -> float:
            c = gr[i : i + 2, j : j + 2].reshape(-1, 2).mean(axis=0)
            xi, yi = round(float(c[0])), round(float(c[1]))
            return float(gray[max(yi - 1, 0) : yi + 2, max(xi - 1, 0) : xi + 2].mean())

        if square_mean(grid, 0, 0) > square_mean(grid, 0, 1):
            grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2)


def _find_complete(gray: NDArray[np.uint8], pattern: TargetPattern, cfg: CalibrateConfig) -> NDArray | None:
    if pattern.kind == "circles":
        ok, centers = cv2.findCirclesGrid(
            gray, pattern.size, None, cv2.CALIB_CB_ASYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING
        )
        if not ok:
            ok, centers = cv2.findCirclesGrid(gray, pattern.size, None, cv2.CALIB_CB_ASYMMETRIC_GRID)
        return centers.reshape(-1, 2).astype(np.float32) if ok else None
    if cfg.detector == "sb":
        ok, corners = cv2.findChessboardCornersSB(
            gray, pattern.size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
        )
        return corners.reshape(-1, 2).astype(np.float32) if ok else None
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, pattern.size, flags=flags | cv2.CALIB_CB_FAST_CHECK)
    if not ok:
        # the sector-based detector finds boards the classic one misses (strong distortion, low contrast)
        ok, corners = cv2.findChessboardCornersSB(gray, pattern.size, flags=cv2.CALIB_CB_EXHAUSTIVE)
        if not ok:
            return None
    corners = np.ascontiguousarray(corners.reshape(-1, 1, 2), dtype=np.float32)
    win = cfg.subpix_window_px
    spacing = _grid_spacing_px(corners.reshape(-1, 2), pattern)
    win = max(2, min(win, int(spacing * 0.3)))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners, (win, win), (-1, -1), crit)
    return corners.reshape(-1, 2).astype(np.float32)


def _partial_count(gray: NDArray[np.uint8], pattern: TargetPattern) -> int:
    """How many target points a partial view shows (0 when nothing target-like is there)."""
    if pattern.kind == "chessboard":
        ok, corners, _meta = cv2.findChessboardCornersSBWithMeta(
            gray, (3, 3), cv2.CALIB_CB_LARGER | cv2.CALIB_CB_EXHAUSTIVE
        )
        return len(corners.reshape(-1, 2)) if ok else 0
    params = cv2.SimpleBlobDetector_Params()
    params.filterByArea = True
    params.minArea = 12
    params.maxArea = gray.size / 50
    params.filterByCircularity = True
    params.minCircularity = 0.7
    blobs = cv2.SimpleBlobDetector_create(params).detect(gray)
    return len(blobs) if len(blobs) >= max(6, pattern.n_points // 4) else 0


def detect_targets(
    images: Sequence[tuple[str, NDArray]],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig | None = None,
    camera: str = "ir",
) -> tuple[list[TargetDetection], list[Reject]]:
    """Find the target in each (name, image) and keep complete, sharp detections.

    images: grey (H, W) or colour (H, W, 3, BGR) arrays, 8 or 16 bit (16-bit IR is stretched to 8 bit).
    Returns the detections (points in canonical order, see `_canonical_order`) and the rejects, each with its
    reason: no_target (nothing found), partial (part of the target visible, or touching the border), blurred.
    """
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(pattern)
    detections: list[TargetDetection] = []
    rejects: list[Reject] = []
    for name, image in images:
        gray = _to_gray8(image)
        h, w = gray.shape
        pts = _find_complete(gray, pat, cfg)
        if pts is None:
            n = _partial_count(gray, pat)
            if n:
                rejects.append(
                    Reject(name, camera, "partial", f"only {n} of {pat.n_points} target points visible")
                )
            else:
                rejects.append(Reject(name, camera, "no_target", f"no {pat.describe()} found"))
            continue
        margin = float(
            min(pts[:, 0].min(), pts[:, 1].min(), w - 1 - pts[:, 0].max(), h - 1 - pts[:, 1].max())
        )
        if margin < cfg.min_border_px:
            rejects.append(
                Reject(
                    name,
                    camera,
                    "partial",
                    f"target within {margin:.1f} px of the image border (< {cfg.min_border_px:g})",
                )
            )
            continue
        ordered = _canonical_order(gray, pts, pat)
        if ordered is None:
            rejects.append(
                Reject(name, camera, "partial", "target orientation ambiguous (mirrored detection)")
            )
            continue
        spacing = _grid_spacing_px(ordered, pat)
        rise = _edge_rise_px(gray, ordered, 0.4 * spacing)
        if rise > cfg.max_edge_rise_px:
            rejects.append(
                Reject(name, camera, "blurred", f"edge rise {rise:.1f} px > {cfg.max_edge_rise_px:g} px")
            )
            continue
        detections.append(TargetDetection(name, ordered.astype(np.float32), (w, h), rise))
    return detections, rejects


# ---------------------------------------------------------------------------------------------------------
# Camera and stereo adjustment


@dataclass(frozen=True, eq=False)
class CameraFit:
    """One camera calibrated from its views."""

    camera: CameraModel
    detections: tuple[TargetDetection, ...]
    """The views used, in order."""
    view_rms_px: tuple[float, ...]
    rvecs: tuple[NDArray, ...]
    """Board → camera rotation vectors per view."""
    tvecs: tuple[NDArray, ...]
    rejects: tuple[Reject, ...] = ()
    """Views dropped for a high residual."""
    coverage: float = 0.0
    """Share of the image's 8 x 6 cells holding target points of the used views: the distortion model is
    measured there and extrapolated elsewhere (thesis 3.1.2: fill the image format)."""


def image_coverage(
    detections: Sequence[TargetDetection], size: tuple[int, int], cells: tuple[int, int] = (8, 6)
) -> float:
    """Share of an image's grid cells that contain at least one detected target point."""
    if not detections:
        return 0.0
    pts = np.concatenate([d.points for d in detections])
    cx = np.clip((pts[:, 0] / size[0] * cells[0]).astype(int), 0, cells[0] - 1)
    cy = np.clip((pts[:, 1] / size[1] * cells[1]).astype(int), 0, cells[1] - 1)
    return float(len(set(zip(cx.tolist(), cy.tolist(), strict=True))) / (cells[0] * cells[1]))


def _names(items: Sequence[Any], limit: int = 12) -> str:
    names = [getattr(x, "name", getattr(x, "file", x)) for x in items]
    names = [str(n) for n in names]
    return ", ".join(names[:limit]) + (f" … ({len(names) - limit} more)" if len(names) > limit else "")


def check_same_size(items: Sequence[tuple[str, tuple[int, int]]], camera: str) -> tuple[int, int]:
    """The common (w, h) of named images, or a ValueError naming the files of each size."""
    by_size: dict[tuple[int, int], list[str]] = {}
    for name, size in items:
        by_size.setdefault(tuple(size), []).append(name)
    if len(by_size) > 1:
        parts = "; ".join(f"{w}x{h}: {_names(n, 6)}" for (w, h), n in sorted(by_size.items()))
        raise ValueError(f"mixed image sizes among the {camera.upper()} calibration images: {parts}")
    if not by_size:
        raise ValueError(f"no {camera.upper()} calibration images")
    return next(iter(by_size))


def _too_few(
    camera: str, used: Sequence[Any], rejects: Sequence[Reject], need: int, what: str = "views"
) -> str:
    rej = "; ".join(str(r) for r in rejects[:12]) + (
        f"; … ({len(rejects) - 12} more)" if len(rejects) > 12 else ""
    )
    return (
        f"too few usable {camera.upper()} calibration {what}: {len(used)} (need {need}): "
        f"{_names(used) or 'none'}" + (f"; rejected: {rej}" if rejects else "")
    )


def _calib_flags(cfg: CalibrateConfig) -> int:
    return cv2.CALIB_FIX_K3 if cfg.fix_k3 else 0


def calibrate_camera(
    detections: Sequence[TargetDetection],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig | None = None,
    camera: str = "ir",
    prior_rejects: Sequence[Reject] = (),
) -> CameraFit:
    """Intrinsics and Brown distortion of one camera from its detections (OpenCV's adjustment, k1 k2 p1 p2 k3).
    Views whose RMS exceeds `max_view_rms_px` are dropped once and the camera re-adjusted.
    Raises ValueError naming the files for mixed image sizes or fewer than `min_views` views."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(pattern)
    size = check_same_size([(d.name, d.size) for d in detections], camera) if detections else None
    dets = list(detections)
    dropped: list[Reject] = []
    for attempt in range(2):
        if len(dets) < cfg.min_views or size is None:
            raise ValueError(_too_few(camera, dets, [*prior_rejects, *dropped], cfg.min_views))
        obj = [pat.object_points().reshape(-1, 1, 3)] * len(dets)
        img = [d.points.reshape(-1, 1, 2).astype(np.float32) for d in dets]
        rms, K, dist, rvecs, tvecs, _si, _se, per_view = cv2.calibrateCameraExtended(
            obj, img, size, None, None, flags=_calib_flags(cfg)
        )
        per_view = np.asarray(per_view, dtype=np.float64).reshape(-1)
        bad = per_view > cfg.max_view_rms_px
        if attempt == 1 or not bad.any():
            break
        for d, e in zip(dets, per_view, strict=True):
            if e > cfg.max_view_rms_px:
                dropped.append(
                    Reject(
                        d.name,
                        camera,
                        "high_residual",
                        f"reprojection RMS {e:.2f} px > {cfg.max_view_rms_px:g} px",
                    )
                )
        dets = [d for d, b in zip(dets, bad, strict=True) if not b]
    cam = CameraModel(K, np.asarray(dist).reshape(-1)[:5], size, float(rms))
    log.info("%s camera: %d views, RMS %.3f px, fx %.2f fy %.2f", camera, len(dets), rms, cam.fx, cam.fy)
    coverage = image_coverage(dets, size)
    if coverage < cfg.min_coverage:
        log.warning(
            "%s views cover only %.0f %% of the image (cells with target points): lens distortion near the image "
            "borders is extrapolated; add views with the target near the corners",
            camera.upper(),
            coverage * 100,
        )
    return CameraFit(
        cam,
        tuple(dets),
        tuple(float(e) for e in per_view),
        tuple(np.asarray(r).reshape(3) for r in rvecs),
        tuple(np.asarray(t).reshape(3) for t in tvecs),
        tuple(dropped),
        coverage,
    )


@dataclass(frozen=True, eq=False)
class StereoFit:
    ir: CameraModel
    rgb: CameraModel
    ir_to_rgb: RigidPose
    stereo_rms_px: float
    views: tuple[ViewResidual, ...]


def pair_names(ir_names: Sequence[str], rgb_names: Sequence[str]) -> list[tuple[str, str]]:
    """Pair IR and RGB images by the last number in their file names (left03 ↔ right03), or by sorted order
    when names carry no unique numbers. Raises ValueError naming the images without a partner."""

    def number(name: str) -> int | None:
        found = re.findall(r"\d+", Path(name).stem)
        return int(found[-1]) if found else None

    ir_num = {number(n): n for n in ir_names}
    rgb_num = {number(n): n for n in rgb_names}
    numbered = (
        None not in ir_num
        and None not in rgb_num
        and len(ir_num) == len(ir_names)
        and len(rgb_num) == len(rgb_names)
    )
    if numbered:
        lone_ir = [ir_num[k] for k in sorted(ir_num) if k not in rgb_num]  # type: ignore[type-var]
        lone_rgb = [rgb_num[k] for k in sorted(rgb_num) if k not in ir_num]  # type: ignore[type-var]
        if lone_ir or lone_rgb:
            raise ValueError(
                "IR and RGB calibration images do not pair up by number: "
                + "; ".join(
                    s
                    for s in (
                        f"IR without RGB: {_names(lone_ir)}" if lone_ir else "",
                        f"RGB without IR: {_names(lone_rgb)}" if lone_rgb else "",
                    )
                    if s
                )
            )
        return [(ir_num[k], rgb_num[k]) for k in sorted(ir_num)]  # type: ignore[type-var]
    if len(ir_names) != len(rgb_names):
        raise ValueError(
            f"cannot pair {len(ir_names)} IR with {len(rgb_names)} RGB calibration images "
            f"(names carry no unique numbers): IR {_names(sorted(ir_names))}; RGB {_names(sorted(rgb_names))}"
        )
    return list(zip(sorted(ir_names), sorted(rgb_names), strict=True))


def _relative_pose_guess(
    ir_fit: CameraFit, rgb_fit: CameraFit, both: Sequence[tuple[int, int]]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Median of the per-pair relative poses of the two mono calibrations (R, t: X_rgb = R X_ir + t)."""
    rel_r, rel_t = [], []
    for i, j in both:
        Ri = cv2.Rodrigues(ir_fit.rvecs[i])[0]
        Rj = cv2.Rodrigues(rgb_fit.rvecs[j])[0]
        R = Rj @ Ri.T
        rel_r.append(R)
        rel_t.append(rgb_fit.tvecs[j] - R @ ir_fit.tvecs[i])
    return Rotation.from_matrix(np.array(rel_r)).mean().as_matrix(), np.median(np.array(rel_t), axis=0)


def _project_params(params: NDArray, X: NDArray) -> NDArray:
    """Pinhole + Brown projection of (..., 3) camera-frame points with params fx fy cx cy k1 k2 p1 p2 k3."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = params
    x = X[..., 0] / X[..., 2]
    y = X[..., 1] / X[..., 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=-1)


def _bundle_stereo(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    stations: Sequence[tuple[int | None, int | None]],
    pat: TargetPattern,
    cfg: CalibrateConfig,
    R0: NDArray,
    t0: NDArray,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """One least-squares adjustment of both cameras' intrinsics and distortion, the relative pose and one board
    pose per station (board → IR), over every valid observation of either camera.
    Returns (ir params, rgb params, R, t, per-station IR RMS (NaN if none), per-station RGB RMS)."""
    from scipy.optimize import least_squares

    obj = pat.object_points().astype(np.float64)
    n_pts = len(obj)
    n_st = len(stations)
    boards = np.zeros((n_st, 6))
    for s, (i, j) in enumerate(stations):
        if i is not None:
            boards[s] = np.r_[ir_fit.rvecs[i], ir_fit.tvecs[i]]
        else:  # seen by the RGB camera only: carry its board pose into the IR frame
            Rb = cv2.Rodrigues(rgb_fit.rvecs[j])[0]
            boards[s] = np.r_[cv2.Rodrigues(R0.T @ Rb)[0].ravel(), R0.T @ (rgb_fit.tvecs[j] - t0)]
    ir_st = np.array([s for s, (i, _) in enumerate(stations) if i is not None], dtype=np.intp)
    rgb_st = np.array([s for s, (_, j) in enumerate(stations) if j is not None], dtype=np.intp)
    ir_obs = np.array([ir_fit.detections[i].points for i, _ in stations if i is not None], dtype=np.float64)
    rgb_obs = np.array([rgb_fit.detections[j].points for _, j in stations if j is not None], dtype=np.float64)

    def intrinsics(cam: CameraModel) -> NDArray:
        k1, k2, p1, p2, k3 = cam.dist
        return np.array([cam.fx, cam.fy, cam.cx, cam.cy, k1, k2, p1, p2, k3])

    p_ir, p_rgb = intrinsics(ir_fit.camera), intrinsics(rgb_fit.camera)
    free = np.ones(9, bool)
    if cfg.fix_k3:
        free[8] = False
    if not cfg.stereo_refine_intrinsics:
        free[:] = False
    nf = int(free.sum())
    rel0 = np.r_[Rotation.from_matrix(R0).as_rotvec(), t0]
    x0 = np.concatenate([p_ir[free], p_rgb[free], rel0, boards.ravel()])

    def unpack(x: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        a, b = p_ir.copy(), p_rgb.copy()
        a[free] = x[:nf]
        b[free] = x[nf : 2 * nf]
        return a, b, x[2 * nf : 2 * nf + 6], x[2 * nf + 6 :].reshape(n_st, 6)

    def residuals(x: NDArray) -> NDArray:
        a, b, rel, bd = unpack(x)
        Rb = Rotation.from_rotvec(bd[:, :3]).as_matrix()
        X = np.einsum("sij,pj->spi", Rb, obj) + bd[:, None, 3:]
        r_ir = _project_params(a, X[ir_st]) - ir_obs
        X_rgb = X[rgb_st] @ Rotation.from_rotvec(rel[:3]).as_matrix().T + rel[3:]
        r_rgb = _project_params(b, X_rgb) - rgb_obs
        return np.concatenate([r_ir.ravel(), r_rgb.ravel()])

    # Jacobian by forward differences, columns grouped: each board pose touches only its own station's rows,
    # so one evaluation per board parameter serves all stations (about 30 evaluations instead of 100+)
    n_ir_rows = 2 * n_pts * len(ir_st)
    st_rows = [np.zeros(0, np.intp)] * n_st
    for k, s_ in enumerate(ir_st):
        st_rows[s_] = np.r_[st_rows[s_], np.arange(2 * n_pts * k, 2 * n_pts * (k + 1))]
    for k, s_ in enumerate(rgb_st):
        rows = n_ir_rows + np.arange(2 * n_pts * k, 2 * n_pts * (k + 1))
        st_rows[s_] = np.r_[st_rows[s_], rows]
    n_glob = 2 * nf + 6

    def jacobian(x: NDArray) -> NDArray:
        f0 = residuals(x)
        J = np.zeros((f0.size, x.size))
        for c in range(n_glob):
            h = 1e-7 * max(abs(x[c]), 1e-2)
            xp = x.copy()
            xp[c] += h
            J[:, c] = (residuals(xp) - f0) / h
        for k in range(6):
            xp = x.copy()
            cols = n_glob + 6 * np.arange(n_st) + k
            h = 1e-7 * np.maximum(np.abs(x[cols]), 1e-2)
            xp[cols] += h
            d = residuals(xp) - f0
            for s_ in range(n_st):
                J[st_rows[s_], cols[s_]] = d[st_rows[s_]] / h[s_]
        return J

    sol = least_squares(
        residuals, x0, jac=jacobian, method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200
    )
    a, b, rel, _ = unpack(sol.x)
    res = residuals(sol.x)
    e_ir = np.sum(res[: ir_obs.size].reshape(-1, n_pts, 2) ** 2, axis=2)
    e_rgb = np.sum(res[ir_obs.size :].reshape(-1, n_pts, 2) ** 2, axis=2)
    view_ir = np.full(n_st, np.nan)
    view_rgb = np.full(n_st, np.nan)
    view_ir[ir_st] = np.sqrt(e_ir.mean(axis=1))
    view_rgb[rgb_st] = np.sqrt(e_rgb.mean(axis=1))
    return a, b, Rotation.from_rotvec(rel[:3]).as_matrix(), rel[3:].copy(), view_ir, view_rgb


def calibrate_stereo(
    ir_fit: CameraFit,
    rgb_fit: CameraFit,
    pairs: Sequence[tuple[str, str]],
    pattern: str | TargetPattern,
    cfg: CalibrateConfig | None = None,
) -> StereoFit:
    """Relative pose of the RGB camera with both cameras adjusted together (thesis 3.1.2: interior and exterior
    orientation of the IR and RGB images in one adjustment), started from the mono calibrations and the median of
    the per-pair relative poses. `pairs` are the synchronized (IR, RGB) image names; with the "bundle" solver a
    pair whose one image was rejected still contributes the other. The stereo RMS is over every observation of
    both cameras in the adjustment."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(pattern)
    ir_idx = {d.name: i for i, d in enumerate(ir_fit.detections)}
    rgb_idx = {d.name: i for i, d in enumerate(rgb_fit.detections)}
    used = [(a, b) for a, b in pairs if a in ir_idx and b in rgb_idx]
    need = max(cfg.min_stereo_pairs, 1) if cfg.stereo_solver == "bundle" else cfg.min_views
    if len(used) < need:
        missing = [f"{a}+{b}" for a, b in pairs if a not in ir_idx or b not in rgb_idx]
        raise ValueError(
            f"too few IR+RGB calibration pairs with the target found in both images: {len(used)} (need {need}): "
            f"{', '.join(f'{a}+{b}' for a, b in used) or 'none'}"
            + (f"; incomplete pairs: {', '.join(missing[:12])}" if missing else "")
        )
    R0, t0 = _relative_pose_guess(ir_fit, rgb_fit, [(ir_idx[a], rgb_idx[b]) for a, b in used])
    size_ir, size_rgb = ir_fit.camera.size, rgb_fit.camera.size
    if cfg.stereo_solver == "bundle":
        stations = [(ir_idx.get(a), rgb_idx.get(b)) for a, b in pairs if a in ir_idx or b in rgb_idx]
        names = [
            (a if a in ir_idx else None, b if b in rgb_idx else None)
            for a, b in pairs
            if a in ir_idx or b in rgb_idx
        ]
        a_par, b_par, R, T, v_ir, v_rgb = _bundle_stereo(ir_fit, rgb_fit, stations, pat, cfg, R0, t0)
        e_ir, e_rgb = v_ir[np.isfinite(v_ir)], v_rgb[np.isfinite(v_rgb)]
        rms_ir = float(np.sqrt(np.mean(e_ir**2)))
        rms_rgb = float(np.sqrt(np.mean(e_rgb**2)))
        rms = float(np.sqrt((np.sum(e_ir**2) + np.sum(e_rgb**2)) / (e_ir.size + e_rgb.size)))

        def model(p: NDArray, size: tuple[int, int], r: float) -> CameraModel:
            K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
            return CameraModel(K, p[4:9], size, r)

        ir, rgb = model(a_par, size_ir, rms_ir), model(b_par, size_rgb, rms_rgb)
        views = tuple(
            ViewResidual(na, None if np.isnan(ei) else float(ei), nb, None if np.isnan(er) else float(er))
            for (na, nb), ei, er in zip(names, v_ir, v_rgb, strict=True)
        )
    else:
        obj = [pat.object_points().reshape(-1, 1, 3)] * len(used)
        p_ir = [ir_fit.detections[ir_idx[a]].points.reshape(-1, 1, 2) for a, _ in used]
        p_rgb = [rgb_fit.detections[rgb_idx[b]].points.reshape(-1, 1, 2) for _, b in used]
        flags = cv2.CALIB_USE_EXTRINSIC_GUESS | _calib_flags(cfg)
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS if cfg.stereo_refine_intrinsics else cv2.CALIB_FIX_INTRINSIC
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-10)
        K1, d1 = ir_fit.camera.K.copy(), ir_fit.camera.dist.copy().reshape(1, 5)
        K2, d2 = rgb_fit.camera.K.copy(), rgb_fit.camera.dist.copy().reshape(1, 5)
        out = cv2.stereoCalibrateExtended(
            obj,
            p_ir,
            p_rgb,
            K1,
            d1,
            K2,
            d2,
            size_ir,
            R0.copy(),
            t0.reshape(3, 1).copy(),
            flags=flags,
            criteria=crit,
        )
        rms, K1, d1, K2, d2, R, T = out[:7]
        per_view = np.asarray(out[11], dtype=np.float64).reshape(-1, 2)
        rms_ir = float(np.sqrt(np.mean(per_view[:, 0] ** 2)))
        rms_rgb = float(np.sqrt(np.mean(per_view[:, 1] ** 2)))
        ir = CameraModel(K1, np.asarray(d1).reshape(-1)[:5], size_ir, rms_ir)
        rgb = CameraModel(K2, np.asarray(d2).reshape(-1)[:5], size_rgb, rms_rgb)
        views = tuple(
            ViewResidual(a, float(e[0]), b, float(e[1])) for (a, b), e in zip(used, per_view, strict=True)
        )
    # re-orthonormalize: the adjustment's R is a rotation up to rounding
    u, _s, vt = np.linalg.svd(np.asarray(R))
    pose = RigidPose(u @ vt, np.asarray(T).reshape(3))
    log.info(
        "stereo (%s): %d views, %d complete pairs, RMS %.3f px (IR %.3f, RGB %.3f), baseline %.1f mm",
        cfg.stereo_solver,
        len(views),
        len(used),
        rms,
        rms_ir,
        rms_rgb,
        np.linalg.norm(pose.t_m) * 1000,
    )
    return StereoFit(ir, rgb, pose, float(rms), views)


# ---------------------------------------------------------------------------------------------------------
# Kinect v1 disparity model


def fit_disparity_model(
    frames: Sequence[NDArray],
    known_distances: Sequence[float | NDArray],
    *,
    focal_px: float | None = None,
    names: Sequence[str] | None = None,
    cfg: CalibrateConfig | None = None,
    shift_x_px: float | None = None,
) -> DepthModel:
    """Offset and b·c of eq 3.11-3.12 by least squares from raw disparity frames of a flat target.

    frames: raw Kinect d_k images (H, W), 2047 = no measurement. known_distances: per frame the target's depth H
    in metres (a plane perpendicular to the optical axis), or an (H, W) array of per-pixel depths (a tilted
    target). The observation equation d_k = offset − (b·c / subpixel_scale) · (1/H) is linear in the unknowns;
    pixels of the central `flat_roi_fraction` are used, with two rounds of 3.5·MAD outlier trimming.
    focal_px (the IR focal length c in native disparity pixels) splits b·c into the baseline b; shift_x_px (the
    disparity/IR column shift in the frames' pixels) defaults to cfg.depth_shift_x_px scaled to the frame width."""
    cfg = cfg or CalibrateConfig()
    names = list(names) if names is not None else [f"frame{i:03d}" for i in range(len(frames))]
    if len(frames) != len(known_distances) or len(names) != len(frames):
        raise ValueError(
            f"{len(frames)} flat-target frames but {len(known_distances)} known distances "
            f"({_names(names)}): give one distance per frame"
        )
    scale = 0.125
    invalid = 2047
    dk_all, inv_h_all, frame_all = [], [], []
    empty = []
    for i, (frame, dist) in enumerate(zip(frames, known_distances, strict=True)):
        raw = np.asarray(frame)
        if raw.ndim != 2:
            raise ValueError(f"flat-target frame {names[i]} is not a single-channel disparity image")
        h, w = raw.shape
        depth = np.broadcast_to(np.asarray(dist, dtype=np.float64), raw.shape)
        m = np.zeros(raw.shape, bool)
        fy0, fx0 = int(h * (1 - cfg.flat_roi_fraction) / 2), int(w * (1 - cfg.flat_roi_fraction) / 2)
        m[fy0 : h - fy0, fx0 : w - fx0] = True
        m &= (raw < invalid) & np.isfinite(depth) & (depth > 0)
        if m.sum() < 10:
            empty.append(names[i])
            continue
        dk_all.append(raw[m].astype(np.float64))
        inv_h_all.append(1.0 / depth[m])
        frame_all.append(np.full(int(m.sum()), i))
    if empty:
        raise ValueError(f"flat-target frames without valid disparities in their centre: {_names(empty)}")
    dk = np.concatenate(dk_all)
    inv_h = np.concatenate(inv_h_all)
    fr = np.concatenate(frame_all)
    if np.ptp(inv_h) < 1e-6:
        raise ValueError(f"flat-target frames must span at least two distances: {_names(names)}")
    keep = np.ones(dk.size, bool)
    for _ in range(3):
        A = np.stack([np.ones(keep.sum()), -inv_h[keep] / scale], axis=1)
        sol, *_ = np.linalg.lstsq(A, dk[keep], rcond=None)
        res = dk - (sol[0] - sol[1] * inv_h / scale)
        mad = 1.4826 * np.median(np.abs(res[keep] - np.median(res[keep])))
        keep = np.abs(res) <= max(3.5 * mad, 1.0)
    offset, bc = float(sol[0]), float(sol[1])
    res = dk - (offset - bc * inv_h / scale)
    residuals = []
    for i in range(len(frames)):
        sel = keep & (fr == i)
        if not sel.any():
            continue
        mean_dk = float(dk[sel].mean())
        h_known = float(1.0 / inv_h[sel].mean())
        pred_mean = offset - bc * float(inv_h[sel].mean()) / scale
        h_model = bc / ((offset - mean_dk) * scale) if offset > mean_dk else float("nan")
        residuals.append(
            FlatTargetResidual(
                names[i], h_known, int(sel.sum()), mean_dk, mean_dk - pred_mean, h_model - h_known
            )
        )
    rms_depth = float(np.sqrt(np.nanmean([r.depth_error_m**2 for r in residuals])))
    model = DepthModel(
        offset=offset,
        bc_m_px=bc,
        focal_px=None if focal_px is None else float(focal_px),
        shift_x_px=float(shift_x_px)
        if shift_x_px is not None
        else cfg.depth_shift_x_px * np.asarray(frames[0]).shape[1] / cfg.disparity_native_width_px,
        subpixel_scale=scale,
        invalid_raw=invalid,
        rms_raw=float(np.sqrt(np.mean(res[keep] ** 2))),
        rms_depth_m=rms_depth,
        residuals=tuple(residuals),
    )
    log.info(
        "disparity model: offset %.2f, b·c %.3f m·px (b %s), RMS %.2f d_k, %.1f mm",
        offset,
        bc,
        "?" if model.baseline_m is None else f"{model.baseline_m * 1000:.1f} mm",
        model.rms_raw,
        rms_depth * 1000,
    )
    return model


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
    cfg: CalibrateConfig | None = None,
) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """Colour for each IR-frame point from the RGB image (eq 3.14 IR→RGB, eq 3.15 projection with the RGB
    intrinsics and distortion, bilinear sampling).

    rgb_image: (H, W, 3) uint8 (colours come back in its channel order) or (H, W) grey, of the calibrated RGB
    size. Returns ((N, 3) uint8 colours, zero where uncoloured; (N,) valid mask). A point is uncoloured when it
    is not finite, behind the RGB camera, projects outside the image, or is hidden from the RGB camera by a
    nearer point (z-buffer over the projected cloud, each point splatted over `zbuffer_splat_px`)."""
    cfg = cfg or CalibrateConfig()
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
    k = max(1, int(cfg.zbuffer_splat_px) | 1)
    if k > 1:
        zbuf = cv2.erode(zbuf, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
    tol = cfg.occlusion_tol_m + cfg.occlusion_tol_rel * z[idx]
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


# ---------------------------------------------------------------------------------------------------------
# Whole calibrations from images and files


def calibrate_images(
    ir_images: Sequence[tuple[str, NDArray]],
    rgb_images: Sequence[tuple[str, NDArray]] | None = None,
    cfg: CalibrateConfig | None = None,
    *,
    flat_frames: Sequence[tuple[str, NDArray]] | None = None,
    known_distances: Sequence[float | NDArray] | None = None,
) -> Calibration:
    """The calibrate stage as a pure function of images: IR (and RGB) target views, optionally flat-target
    raw disparity frames with their known distances. Raises ValueError naming the files for images without a
    target (unless `missing_target="reject"`), mixed sizes, unpaired images or too few views."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(cfg.pattern)
    cams = [("ir", ir_images)] + ([("rgb", rgb_images)] if rgb_images is not None else [])
    pairs = (
        pair_names([n for n, _ in ir_images], [n for n, _ in rgb_images]) if rgb_images is not None else []
    )
    if flat_frames and known_distances is None:
        raise ValueError(
            f"flat-target frames need their known distances: {_names([n for n, _ in flat_frames])}"
        )
    fits: dict[str, CameraFit] = {}
    rejects: list[Reject] = []
    for cam, images in cams:
        check_same_size([(n, (im.shape[1], im.shape[0])) for n, im in images], cam)
        dets, rej = detect_targets(images, pat, cfg, camera=cam)
        none = [r for r in rej if r.kind == "no_target"]
        if none and cfg.missing_target == "error":
            raise ValueError(
                f"no {pat.describe()} found in {len(none)} of {len(images)} {cam.upper()} calibration images: "
                f"{_names([r.file for r in none])}"
            )
        fit = calibrate_camera(dets, pat, cfg, camera=cam, prior_rejects=rej)
        fits[cam] = fit
        rejects += rej + list(fit.rejects)
    ir_fit = fits["ir"]
    if rgb_images is None:
        views = tuple(
            ViewResidual(d.name, e) for d, e in zip(ir_fit.detections, ir_fit.view_rms_px, strict=True)
        )
        ir, rgb, pose, stereo_rms = ir_fit.camera, None, None, None
    else:
        st = calibrate_stereo(ir_fit, fits["rgb"], pairs, pat, cfg)
        ir, rgb, pose, stereo_rms, views = st.ir, st.rgb, st.ir_to_rgb, st.stereo_rms_px, st.views
    for label, cam in (("ir", ir), ("rgb", rgb)):
        if cam is not None:
            w, h = cam.size
            border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, 0], [0, h / 2]], float)
            if np.isnan(cam.undistort_pixels(border)).any():
                log.warning(
                    "%s distortion model folds back inside the image: its border pixels have no ray (the views "
                    "do not reach the image corners); those pixels give no points",
                    label.upper(),
                )
    depth_model = None
    if flat_frames and known_distances is not None:
        native = cfg.disparity_native_width_px / ir.size[0]
        depth_model = fit_disparity_model(
            [f for _, f in flat_frames],
            known_distances,
            focal_px=ir.fx * native,
            names=[n for n, _ in flat_frames],
            cfg=cfg,
            shift_x_px=cfg.depth_shift_x_px / native,
        )
    return Calibration(
        ir,
        rgb,
        pose,
        stereo_rms,
        depth_model,
        source="targets",
        rejects=tuple(rejects),
        views=views,
        pattern=str(pat),
        coverage=tuple((cam, fit.coverage) for cam, fit in fits.items()),
    )


def read_gray(path: str | Path) -> NDArray:
    """A calibration image as stored (8- or 16-bit grey; colour converted to grey); ValueError if unreadable."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot read calibration image {path}")
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY) if img.shape[2] >= 3 else img[:, :, 0]
    return img


def read_disparity(path: str | Path) -> NDArray:
    """A raw disparity frame: 16-bit PNG/PGM or .npy."""
    p = Path(path)
    if p.suffix == ".npy":
        return np.load(p)
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2:
        raise ValueError(f"cannot read disparity frame {path} as a single-channel image")
    return img


def calibrate_files(
    ir_paths: Sequence[str | Path],
    rgb_paths: Sequence[str | Path] | None = None,
    cfg: CalibrateConfig | None = None,
    *,
    flat_paths: Sequence[str | Path] | None = None,
    known_distances: Sequence[float] | None = None,
) -> Calibration:
    """`calibrate_images` on files (names reported by file name). Use it for a survey's calibration/ folder."""
    ir = [(Path(p).name, read_gray(p)) for p in ir_paths]
    rgb = None if rgb_paths is None else [(Path(p).name, read_gray(p)) for p in rgb_paths]
    flats = None if flat_paths is None else [(Path(p).name, read_disparity(p)) for p in flat_paths]
    return calibrate_images(ir, rgb, cfg, flat_frames=flats, known_distances=known_distances)


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".tif", ".tiff", ".bmp")


def calibrate_folder(folder: str | Path, cfg: CalibrateConfig | None = None) -> Calibration:
    """A survey's `calibration/` folder: `ir/` (and `rgb/`) target images, paired by the numbers in their names;
    optionally `flat/` raw disparity frames with `flat.yaml` ({distances_m: [...], files: [...]} in file order);
    optionally `target.yaml` ({pattern: "chessboard:9x6:0.04"}) overriding cfg.pattern."""
    import yaml

    folder = Path(folder)
    cfg = cfg or CalibrateConfig()
    target = folder / "target.yaml"
    if target.is_file():
        meta = yaml.safe_load(target.read_text()) or {}
        if "pattern" in meta:
            cfg = replace(cfg, pattern=str(parse_pattern(str(meta["pattern"]))))

    def images(sub: str) -> list[Path]:
        return sorted(p for p in (folder / sub).glob("*") if p.suffix.lower() in _IMAGE_SUFFIXES)

    ir = images("ir")
    if not ir:
        raise ValueError(f"calibration folder {folder} has no ir/ target images")
    rgb = images("rgb") or None
    flats, distances = None, None
    if (folder / "flat.yaml").is_file():
        meta = yaml.safe_load((folder / "flat.yaml").read_text()) or {}
        distances = [float(x) for x in meta.get("distances_m", [])]
        files = meta.get("files") or [p.name for p in images("flat")]
        flats = [folder / "flat" / f for f in files]
        if len(flats) != len(distances):
            raise ValueError(
                f"{folder / 'flat.yaml'}: {len(files)} flat-target files but {len(distances)} distances_m"
            )
    return calibrate_files(ir, rgb, cfg, flat_paths=flats, known_distances=distances)


def _glob(pattern: str, what: str) -> list[str]:
    files = sorted(f for f in glob.glob(os.path.expanduser(pattern), recursive=True) if os.path.isfile(f))
    if not files:
        raise ValueError(f"no files match {what} {pattern!r}")
    return files


def write_calibration(calib: Calibration, out_dir: Path) -> Path:
    """DIR/calibration.json (the contract) and DIR/calibration_residuals.json (source, views, coverage,
    rejects), each written atomically; returns the path of calibration.json."""
    from tasks.artefacts import write_json

    out_dir = Path(out_dir)
    write_json(out_dir / "calibration_residuals.json", _json_safe(calib.residuals_json()))
    return write_json(out_dir / "calibration.json", _json_safe(calib.to_json()))


def _json_safe(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def run_calibrate(
    ir_glob: str,
    rgb_glob: str | None,
    pattern: str,
    out_dir: Path,
    *,
    flat_glob: str | None = None,
    known_distances: Sequence[float] | None = None,
    cfg: CalibrateConfig | None = None,
) -> Path:
    """`indoor-survey calibrate --ir GLOB [--rgb GLOB] --pattern P --out DIR`: writes DIR/calibration.json
    (plus DIR/calibration_residuals.json) and returns its path. IR and RGB images pair by the numbers in
    their names (else by sorted order); `--ir` alone calibrates one camera."""
    cfg = replace(cfg or CalibrateConfig(), pattern=str(parse_pattern(pattern)))
    ir = _glob(ir_glob, "--ir")
    rgb = _glob(rgb_glob, "--rgb") if rgb_glob else None
    flats = _glob(flat_glob, "flat-target") if flat_glob else None
    calib = calibrate_files(ir, rgb, cfg, flat_paths=flats, known_distances=known_distances)
    path = write_calibration(calib, Path(out_dir))
    log.info("wrote %s (%s)", path, "IR+RGB" if rgb else "IR only")
    return path


__all__ = [
    "CODE_VERSION",
    "CalibrateConfig",
    "Calibration",
    "CameraFit",
    "CameraModel",
    "DepthModel",
    "FlatTargetResidual",
    "Reject",
    "RigidPose",
    "StereoFit",
    "TargetDetection",
    "TargetPattern",
    "ViewResidual",
    "calibrate_camera",
    "calibrate_files",
    "calibrate_folder",
    "calibrate_images",
    "calibrate_stereo",
    "check_same_size",
    "colour_points",
    "depth_to_metres",
    "depth_to_points",
    "detect_targets",
    "fit_disparity_model",
    "image_coverage",
    "pair_names",
    "parse_pattern",
    "photogrammetric_to_opencv",
    "profile_calibration",
    "read_disparity",
    "read_gray",
    "run_calibrate",
    "thesis_kinect_v1",
    "write_calibration",
]
