"""The calibration target (chessboard or asymmetric circle grid) and its detection: complete, sharp views are
kept with their points in one canonical order; blurred and partial ones are rejected with a stated reason."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.calibrate.config import CalibrateConfig
from tasks.camera import Reject

PatternKind = Literal["chessboard", "circles"]


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


def to_gray8(image: NDArray) -> NDArray[np.uint8]:
    """An 8-bit grey image of a calibration view (colour converted, 16-bit or float stretched)."""
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


def grid_spacing_px(points: NDArray, pattern: TargetPattern) -> float:
    """Median distance (px) between neighbouring target points in the image."""
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
    corners = corners.reshape(-1, 2)
    return refine_corners(gray, corners, grid_spacing_px(corners, pattern), cfg)


def refine_corners(
    gray: NDArray[np.uint8], guesses: NDArray, spacing_px: float, cfg: CalibrateConfig
) -> NDArray[np.float32]:
    """Chessboard corners refined to the saddle point nearest each guess (cornerSubPix), with the search
    window capped at 0.3 of the square size in the image so that it never reaches a neighbouring corner.
    cornerSubPix leaves a guess where it was when its solution leaves the window: a guess several pixels
    off stays off (see `redetect_outliers` in `tasks.calibrate.bundle`)."""
    pts = np.ascontiguousarray(np.asarray(guesses, dtype=np.float32).reshape(-1, 1, 2))
    win = max(2, min(cfg.subpix_window_px, int(spacing_px * 0.3)))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
    pts = cv2.cornerSubPix(gray, pts, (win, win), (-1, -1), crit)
    return pts.reshape(-1, 2).astype(np.float32)


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
        gray = to_gray8(image)
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
        spacing = grid_spacing_px(ordered, pat)
        rise = _edge_rise_px(gray, ordered, 0.4 * spacing)
        if rise > cfg.max_edge_rise_px:
            rejects.append(
                Reject(name, camera, "blurred", f"edge rise {rise:.1f} px > {cfg.max_edge_rise_px:g} px")
            )
            continue
        detections.append(TargetDetection(name, ordered.astype(np.float32), (w, h), rise))
    return detections, rejects
