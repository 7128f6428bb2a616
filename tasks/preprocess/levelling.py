"""Levelling by surface normals (thesis 5.1.4), and the room's floor and ceiling from the height histogram
of the levelled cloud (5.1.5), with a picture of it."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.signal import find_peaks

from tasks.cloud import DegenerateInputError
from tasks.preprocess.config import PreprocessConfig


def rotation_between(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotation (3, 3) taking unit vector a onto unit vector b (Rodrigues)."""
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    c = float(np.dot(a, b))
    if s < 1e-15:
        if c > 0:
            return np.eye(3)
        raise ValueError("rotation_between: opposite vectors have no unique smallest rotation")
    k = axis / s
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * skew + (1 - c) * skew @ skew


def level_by_normals(
    normals: NDArray[np.float64], cfg: PreprocessConfig
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Rotation (3, 3) that levels the cloud (thesis 5.1.4), and its statistics.

    Each iteration classifies the (rotated) unit normals (N, 3; sign free; NaN rows ignored) into
    horizontal surfaces (within `level_split_deg` of the vertical) and vertical surfaces, takes as up the
    unit u maximising Σ_h (n·u)² + Σ_v (1 − (n·u)²) (the top eigenvector; terms per `level_normals`), and
    rotates u onto z, until the correction is below `level_tol_deg`."""
    n = normals[np.isfinite(normals).all(axis=1)]
    if len(n) < 3:
        raise DegenerateInputError(f"levelling: only {len(n)} points lie on smooth surfaces")
    cos_split = math.cos(math.radians(cfg.level_split_deg))
    rotation = np.eye(3)
    tilts: list[float] = []
    z = np.array([0.0, 0.0, 1.0])
    n_horizontal = n_vertical = 0
    use_h = 1.0 if cfg.level_normals in ("horizontal", "both") else 0.0
    use_v = 1.0 if cfg.level_normals in ("vertical", "both") else 0.0
    for _ in range(cfg.level_max_iterations):
        current = _rotated_columns(n, rotation)
        horizontal = np.abs(current[2]) >= cos_split
        n_horizontal = int(horizontal.sum())
        n_vertical = len(n) - n_horizontal
        # Σ_h n nᵀ + Σ_v (I - n nᵀ) as one signed sum over the columns (no BLAS: its threads spin for CPU
        # on a loaded machine, and the sums are the same whatever the thread count)
        sign = np.where(horizontal, use_h, -use_v)
        scatter = use_v * n_vertical * np.eye(3)
        for a in range(3):
            signed = sign * current[a]
            for b in range(a, 3):
                scatter[a, b] += float((signed * current[b]).sum())
                scatter[b, a] = scatter[a, b]
        evals, evecs = np.linalg.eigh(scatter)
        # the up direction must stand out: a single wall (or nothing usable) leaves two equal eigenvalues
        if evals[2] <= 0 or (evals[2] - evals[1]) / evals[2] < 0.05:
            raise DegenerateInputError(
                f"levelling is ill-determined: {n_horizontal} horizontal and {n_vertical} vertical surface "
                f"normals do not fix the up direction (a single wall?)"
            )
        up = evecs[:, 2] * np.sign(evecs[2, 2])
        tilt = math.degrees(math.acos(min(1.0, float(up @ z))))
        tilts.append(tilt)
        rotation = rotation_between(up, z) @ rotation
        if tilt < cfg.level_tol_deg:
            break
    total = math.degrees(math.acos(min(1.0, float(rotation[2, 2]))))
    final_z = _rotated_columns(n, rotation)[2]
    horizontal = np.abs(final_z) >= cos_split
    spread = np.degrees(np.arccos(np.clip(np.abs(final_z[horizontal]), 0, 1))) if horizontal.any() else []
    stats = {
        "level_tilt_per_iteration_deg": [round(t, 6) for t in tilts],
        "level_tilt_deg": total,
        "level_residual_deg": tilts[-1],
        "level_iterations": len(tilts),
        "level_converged": tilts[-1] < cfg.level_tol_deg,
        "level_horizontal_normals": n_horizontal,
        "level_vertical_normals": n_vertical,
        "level_unused_normals": len(normals) - len(n),
        "level_horizontal_median_deg": float(np.median(spread)) if len(spread) else None,
    }
    if total > cfg.level_split_deg:
        raise DegenerateInputError(
            f"levelling found a tilt of {total:.1f}°, beyond the {cfg.level_split_deg}° the method assumes"
        )
    return rotation, stats


def _rotated_columns(
    vectors: NDArray[np.float64], rotation: NDArray[np.float64]
) -> list[NDArray[np.float64]]:
    """The x, y and z columns (each (N,)) of vectors (N, 3) rotated by `rotation` (3, 3)."""
    return [
        vectors[:, 0] * rotation[i, 0] + vectors[:, 1] * rotation[i, 1] + vectors[:, 2] * rotation[i, 2]
        for i in range(3)
    ]


class HeightHistogram(NamedTuple):
    """Point heights in the levelled frame; unpacks as `edges, counts`."""

    edges_m: NDArray[np.float64]
    """(B + 1,) bin edges, metres, ascending."""
    counts: NDArray[np.int64]
    """(B,) points per bin."""


def height_histogram(z: NDArray[np.float64], bin_m: float) -> tuple[HeightHistogram, NDArray[np.float64]]:
    """Histogram of heights with bins of `bin_m` aligned to multiples of it, over the robust range of
    the data (0.1 %-99.9 % quantiles, padded by 0.25 m); also each bin's sum of heights."""
    lo_q, hi_q = np.quantile(z, [0.001, 0.999])
    lo = math.floor((lo_q - 0.25) / bin_m) * bin_m
    bins = max(1, math.ceil((hi_q + 0.25 - lo) / bin_m))
    edges = lo + bin_m * np.arange(bins + 1)
    index = np.floor((z - lo) / bin_m).astype(np.int64)
    inside = (index >= 0) & (index < bins)
    counts = np.bincount(index[inside], minlength=bins).astype(np.int64)
    sums = np.bincount(index[inside], weights=z[inside], minlength=bins)
    return HeightHistogram(edges, counts), sums


def _refined_peak(i: int, hist: HeightHistogram, z_sums: NDArray[np.float64]) -> float:
    """Sub-bin height of the peak at bin i: the mean height of its points in bins i-1..i+1, the two
    neighbours less the background on their side (median of bins 3-8 further out: walls, which end at a
    floor or ceiling), spread evenly over the bin. The peak bin counts whole: its wall points lie within
    a bin of the surface and are few beside it."""
    counts = hist.counts.astype(np.float64)
    width = float(hist.edges_m[1] - hist.edges_m[0])
    n = len(counts)

    def background(side: int) -> float:
        around = [j for j in range(i + 3 * side, i + 9 * side, side) if 0 <= j < n]
        return float(np.median(counts[around])) if around else 0.0

    total_count, total_sum = counts[i], z_sums[i]
    for side in (-1, 1):
        j = i + side
        if 0 <= j < n:
            wall = min(background(side), counts[j])
            centre = hist.edges_m[j] + width / 2
            total_count += counts[j] - wall
            total_sum += z_sums[j] - wall * centre
    return float(total_sum / total_count)


def _band_edges(hist: HeightHistogram) -> tuple[float, float]:
    """Bottom and top of the data: the outermost bins holding at least half the median occupied bin (the
    walls' level), each refined by how full that bin is compared with its five inner neighbours."""
    counts = hist.counts.astype(np.float64)
    width = float(hist.edges_m[1] - hist.edges_m[0])
    level = 0.5 * float(np.median(counts[counts > 0]))
    dense = np.flatnonzero(counts >= level)
    lo, hi = int(dense[0]), int(dense[-1])

    def fill(i: int, inner: NDArray[np.float64]) -> float:
        reference = float(np.median(inner)) if len(inner) else 0.0
        return min(1.0, counts[i] / reference) if reference > 0 else 1.0

    fill_lo = fill(lo, counts[lo + 1 : lo + 6])
    fill_hi = fill(hi, counts[max(0, hi - 5) : hi])
    return float(hist.edges_m[lo + 1] - width * fill_lo), float(hist.edges_m[hi] + width * fill_hi)


def floor_and_ceiling(
    hist: HeightHistogram,
    z_sums: NDArray[np.float64],
    cfg: PreprocessConfig,
    warnings: list[str],
) -> tuple[float, float, dict[str, Any]]:
    """Floor and ceiling heights from the histogram (thesis 5.1.5): the lowest and highest peaks that rise
    `peak_min_area_m2` above their surroundings, each accepted only within `surface_search_m` of the
    bottom (top) of the data. A surface not captured falls back to that bottom (top), the end of the walls,
    with a warning, and so do both when neither was captured: a handheld scan cut at 1.3-2 m that saw
    only part of its floor, sparsely, still shows its walls (issue 14: a cloud is refused only when no
    wall can be told apart; a single plane is, above)."""
    bottom, top = _band_edges(hist)
    span = top - bottom
    if span < cfg.min_wall_span_m:
        raise DegenerateInputError(
            f"the levelled cloud spans only {span:.2f} m in height (a single plane?); "
            f"walls need at least min_wall_span_m = {cfg.min_wall_span_m} m"
        )
    bin_m = float(hist.edges_m[1] - hist.edges_m[0])
    min_count = cfg.peak_min_area_m2 / bin_m**2
    padded = np.concatenate([[0], hist.counts, [0]])
    found, _ = find_peaks(padded, prominence=min_count)
    peaks = [_refined_peak(int(i) - 1, hist, z_sums) for i in found]
    floor = peaks[0] if peaks and peaks[0] - bottom <= cfg.surface_search_m else None
    ceiling = peaks[-1] if peaks and top - peaks[-1] <= cfg.surface_search_m else None
    if floor is None:
        floor = bottom
        warnings.append(f"no floor peak: floor taken as the bottom of the walls, z = {bottom:.3f} m")
    if ceiling is None:
        ceiling = top
        warnings.append(f"no ceiling peak: ceiling taken as the top of the walls, z = {top:.3f} m")
    stats = {
        "histogram_peaks_z_m": [round(p, 4) for p in peaks],
        "histogram_peak_min_count": min_count,
        "data_bottom_z_m": bottom,
        "data_top_z_m": top,
        "floor_captured": bool(peaks and peaks[0] - bottom <= cfg.surface_search_m),
        "ceiling_captured": bool(peaks and top - peaks[-1] <= cfg.surface_search_m),
    }
    return floor, ceiling, stats


def render_histogram(
    hist: HeightHistogram,
    floor_z: float,
    ceiling_z: float,
    slice_low: float,
    slice_high: float,
    size: tuple[int, int] = (480, 640),
) -> NDArray[np.uint8]:
    """(H, W, 3) RGB picture of the height histogram: height upwards, count to the right on a square-root
    scale (walls stay visible beside the floor peak); the furniture slice shaded green, the floor blue, the
    ceiling red."""
    height, width = size
    left, right, top, bottom = 64, 16, 28, 20
    image = np.full((height, width, 3), 255, np.uint8)
    z_lo, z_hi = float(hist.edges_m[0]), float(hist.edges_m[-1])

    def row(z: float) -> int:
        frac = (z - z_lo) / max(z_hi - z_lo, 1e-9)
        return round(height - bottom - frac * (height - top - bottom))

    cv2.rectangle(image, (left, row(slice_high)), (width - right, row(slice_low)), (205, 235, 205), -1)
    marks = ((floor_z, (30, 80, 220), "floor"), (ceiling_z, (220, 40, 40), "ceiling"))
    for z_mark, colour, _ in marks:  # under the bars, so a floor or ceiling peak stays visible
        cv2.line(image, (left, row(z_mark)), (width - right, row(z_mark)), colour, 1)
    scale = np.sqrt(hist.counts / max(int(hist.counts.max()), 1))
    for i, s in enumerate(scale):
        if s <= 0:
            continue
        y0, y1 = row(hist.edges_m[i + 1]), row(hist.edges_m[i])
        x1 = left + round(s * (width - left - right))
        cv2.rectangle(image, (left, y0), (x1, max(y0, y1 - 1)), (110, 110, 110), -1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for z_tick in np.arange(math.ceil(z_lo * 2) / 2, z_hi, 0.5):
        y = row(float(z_tick))
        cv2.line(image, (left - 5, y), (left, y), (0, 0, 0), 1)
        cv2.putText(image, f"{z_tick:.1f}", (4, y + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.line(image, (left, top), (left, height - bottom), (0, 0, 0), 1)
    for z_mark, colour, name in marks:
        y = row(z_mark)
        cv2.putText(image, f"{name} {z_mark:.3f} m", (width - 190, y - 5), font, 0.45, colour, 1, cv2.LINE_AA)
    bin_cm = 100 * (hist.edges_m[1] - hist.edges_m[0])
    title = f"height histogram, bin {bin_cm:.1f} cm: height {ceiling_z - floor_z:.3f} m"
    cv2.putText(image, title, (left, 18), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(
        image, "slice", (width - right - 50, row(slice_high) + 16), font, 0.45, (40, 130, 40), 1, cv2.LINE_AA
    )
    cv2.putText(image, "z (m)", (4, 18), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(
        image, "points per bin (square root)", (left + 6, height - 3), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA
    )
    return image
