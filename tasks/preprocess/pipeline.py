"""Preprocess stage (thesis 5.1): a registered room cloud -> a clean, smoothed, levelled cloud, the room's
floor, ceiling and height, and the furniture slice the wall stage projects.

Steps, in this order:

1. **Voxel grid** (5.1.2): every voxel's points are replaced by their centroid, colours averaged; each
   voxel's point count is kept. The grid is anchored at the origin (voxel i covers [i·v, (i+1)·v)), so it
   does not move with the cloud's extent.
2. **Statistical outlier removal** (5.1.1, eq 5.1): each point's mean distance to its K = 20 nearest
   neighbours, tested one-tailed at μ + `outlier_std_ratio` σ (the thesis' table 6.3: 1σ or 2σ). By
   default the test is density-aware (`outlier_reference: local`): a point's distance is judged against
   its neighbours' and the point must be linked to the dense part of the cloud (see
   `statistical_outliers`), so the sparse far surfaces of a range sensor stay.
3. **Moving-least-squares smoothing** (5.1.3, eq 5.2): a Gaussian-weighted plane (or quadratic) fit within
   `mls_radius_m` around every point, the point projected onto it. The fit's normal is kept for levelling.
4. **Levelling by normals** (5.1.4): normals split at 45° into horizontal and vertical surfaces, an up
   direction estimated from them, rotate, reclassify, repeat until the correction is below
   `level_tol_deg`. The rotation turns about the cleaned cloud's centroid, so x-y and heights stay close
   to the input's; the floor is not moved to z = 0.
5. **Height histogram** (5.1.5): bins of the voxel size, so counts measure horizontal area; the lowest and
   highest significant peaks are floor and ceiling, refined below the bin size.
6. **Furniture slice** (5.1.5): points from `slice_min_m` to `slice_max_m` above the floor, and at least
   `slice_ceiling_margin_m` below the ceiling (lamps, and rooms lower than 2.5 m). Where the walls were
   seen only lower (a handheld scan: no ceiling, walls ending at 1.3-2 m) the slice is the highest
   `slice_min_band_m` band under their top, and without a ceiling to tell walls by their reach it keeps only
   the points of smooth vertical surfaces (MLS normals): `slice_reason` in the metrics says which.

Choices and what was measured (`python -m bench.preprocess --order-study --level-study --voxel-study`,
synthetic furnished 6 x 5 x 2.7 m room tilted 3°, 2 % outliers; 2 cores shared with other work, so
wall-clock seconds are indicative and CPU seconds are given too):

- **Downsample first, then filter outliers** (the thesis filters first). Filtering costs a K-NN query per
  point: per raw point before the grid, per voxel after it; and after the grid the density is uniform, so
  the mean-distance statistic compares like with like (raw captures are far denser near the sensor). An
  outlier merged into a surface voxel shifts its centroid by at most a voxel over the voxel's count.
  1 M points: raw-first 32 s vs voxel-first 7 s for the two steps; far voxels left 0 and 0 (of 18 270);
  surface voxels kept 80.9 % vs 81.9 %; residual tilt after the stage 0.002° vs 0.017°.
- **Density-aware outlier test.** A range sensor samples a surface ever more sparsely with the range, so
  on the survey generator's rooms the global test (eq 5.1 as PCL) removed the far walls and corners and
  nothing else (their clouds hold almost no gross outliers: 34 of 300 k voxels more than 20 cm off a
  surface): TLS rooms lost up to half of a wall's length in the slice, Kinect v1 rooms a short wall
  seen only obliquely. The local test keeps them and still removes every far voxel of the test room
  below (`python -m bench.walls_survey`: with walls, TLS rooms 0/6 -> 6/6 meeting the issue's targets).
- **μ and σ of eq 5.1 with 3σ clipping.** Outliers metres away inflate σ: on the test room (7 284
  outliers more than 10 cm from any surface), plain μ + 1σ gave a 0.39 m threshold and the stage's output
  kept 3 712 points more than 10 cm off; clipped, the threshold was 0.040 m and none were left. On data
  without gross outliers it is PCL's test.
- **Voxel size 0.02 m.** The thesis uses 3-5 cm for Kinect clouds (noise) and 1 cm where accuracy matters
  (TLS: 7 mm model error). Kinect v1 range noise is 7 mm at 1.8 m and 15 mm at 2.6 m, so finer voxels
  mostly keep noise; the wall stage grids at this size, and half a 2 cm cell (5.8 mm RMS) fits the
  15 mm wall budget where 3-5 cm would not. On 1 M points, 1 / 1.5 / 2 / 3 cm: 12.3 / 8.4 / 5.8 / 3.4 CPU
  s, height error 0.1-0.5 mm and residual tilt <= 0.01° at every size. A 5 M point room at 1 cm would
  take ~4x longer; the TLS profile should set 0.01.
- **MLS on a support grid, with voxel counts as weights.** open3d has no MLS. The local fits use the
  cloud aggregated into cells of a third of the radius, each cell a support point at its (count-weighted)
  centroid carrying its total count (the Gaussian weight varies little across a cell): ~30 support points
  per fit on a plane whatever the voxel size, a cost linear in the points, and fits that agree with the
  textbook all-neighbours fit to a fraction of the noise removed (tests). Weighting by the voxel counts
  matters: unweighted voxel centroids of a noisy tilted surface form terraces along the grid (a voxel with
  a few points of the noise's tail counts as much as a full one), which biased normals by 0.2° (1 M
  points) to 0.7° (5 M) towards the input's axes; with the counts the fits see the raw points' moments.
- **Edges are not smoothed.** Near an edge the plane fit mixes both faces and MLS rounds the edge (99th
  percentile of distance to the true surfaces 18.8 mm, against 12.0 mm before MLS). Points whose surface
  variation λ0/Σλ exceeds `mls_edge_ratio` × its median (16 % of them) stay in place, and their normals
  are not used for levelling: 99th percentile 7.1 mm, median 0.4 mm (2.4 mm before MLS). The median adapts to the noise: with 4x the noise the test
  hardly fires, as there MLS helps everywhere.
- **Levelling on horizontal and vertical normals** ("both"): the up vector u maximises
  Σ_horizontal (n·u)² + Σ_vertical (1 − (n·u)²), the sign-free form of averaging the sign-aligned
  horizontal normals plus the condition that walls are vertical. Residual tilt, degrees, 500 k points,
  horizontal / vertical / both: full floor and ceiling 0.006 / 0.003 / 0.004; 30 % of each 0.008 /
  0.005 / 0.006; 10 % floor, no ceiling 0.198 / 0.041 / 0.025; 4x noise 0.066 / 0.116 / 0.010; 10 %
  floor, no ceiling, 4x noise 0.735 / 0.235 / 0.070. One wall and nothing horizontal is an error.
- **Where the time goes** (`python -m bench.preprocess --profile 25`, 5 M points): the two neighbour
  searches, K = 20 for the outlier test on the 672 k voxels and up to 64 support points within r for MLS
  on 544 k points, take about half the CPU (~3.3 and ~2 s); the voxel grid's hashing of a grid stretched by
  far outliers ~1 s. The MLS moments are sums along the contiguous axis of per-axis (M, K) arrays, the MLS
  chunks and the grid's per-cell sums are shared by two threads, levelling sums columns without BLAS: MLS
  4.2 -> 3.1 CPU s, levelling 0.53 -> 0.09 (load 9-17 on 2 cores, so wall seconds are 2-3x the CPU's).
  The outlier test's tree unbalanced and queried in its leaf order (the same neighbours, the same bytes
  out): its CPU 3.9 -> 3.5 and 4.9 -> 3.8 s on 5 M points (two pairs), within the noise of a shared
  machine. Its search in fixed chunks, one thread each with the chunk's statistics, bounded at 1.5x a
  sample's median K-th distance (short rows searched again): the same bytes, its CPU 3.19 -> 2.98 s
  (median of 8 interleaved runs). Tried and not kept: one MLS plane per support cell (each voxel projected onto its cell's
  plane; 2.8 voxels a cell) cut MLS
  3.4 -> 1.2 CPU s with the output as close to the truth (median 0.11 -> 0.12 mm, p99 8.3 mm) and
  `bench.walls_survey`'s 60 rooms' completeness, correctness and corner F1 unchanged, but data/mini's
  corridor got a 1.7 cm step in its smeared north face (corner F1 1.00 -> 0.86). What is left is the
  two searches (~2.3 CPU s each; Open3D's, scikit-learn's and scipy's dual-tree pairs are no faster)
  and the voxel grid (~1 s, most
  of it hashing a grid that far outliers stretch past an occupancy array: a dense box plus a sort of
  the points outside it was slower still).
  The output is the same bytes on one thread or two (`--threads-check`). The outlier test's link graph
  marks its candidates (a non-anchor end, both ends regular) on the (n, K) neighbour table before taking
  their positions, and the voxel grid takes its index bounds per column (the same links, the same voxels):
  statistical_outliers alone on the 672 k voxels in a fresh process 3.2 -> 2.3 CPU s (1.5 s of wall less
  on two cores); within the bench, whose allocator reuses the generator's freed memory, outliers 2.3-2.5
  -> 2.25 CPU s and the voxel grid 0.86-0.93 -> 0.78-0.85 s.
- **Missing floor or ceiling.** A peak counts as the floor (ceiling) only within `surface_search_m` of
  where the walls end at the bottom (top): otherwise it is a table or a lamp and the surface was not
  captured. One surface missing: its height is where the walls end, with a warning in
  `metrics["warnings"]`; with no ceiling the height came out 22 mm low, as the outlier filter thins the
  walls' free top edge by about a voxel. Both missing: an error.

Degenerate inputs raise `DegenerateInputError` with one line: an empty cloud, NaNs, fewer than K + 1
points, a single plane (vertical: levelling ill-determined; horizontal: no height span), or a room too low
for the slice.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.cloud import Cloud, DegenerateInputError, require_finite
from tasks.preprocess.config import PreprocessConfig
from tasks.preprocess.filters import LocalSurfaces, mls_smooth, statistical_outliers, voxel_grid
from tasks.preprocess.levelling import (
    HeightHistogram,
    floor_and_ceiling,
    height_histogram,
    level_by_normals,
    render_histogram,
)


@dataclass(frozen=True)
class Preprocessed:
    """The preprocess stage's result; every height is in the levelled frame."""

    cloud: Cloud
    """Filtered, smoothed cloud in the levelled frame (z up)."""
    slice: Cloud
    """The furniture slice of `cloud`."""
    levelling: NDArray[np.float64]
    """(4, 4) rigid transform input frame -> levelled frame: a rotation about the cleaned cloud's centroid."""
    floor_z_m: float
    """Floor height."""
    ceiling_z_m: float
    """Ceiling height."""
    height_m: float
    """Room height, ceiling - floor."""
    histogram: HeightHistogram
    """Height histogram of `cloud`, bins of the voxel size."""
    histogram_png: NDArray[np.uint8]
    """(H, W, 3) RGB picture of the histogram with floor, ceiling and slice marked."""
    metrics: dict[str, Any] = field(default_factory=dict)
    """Points per step, outliers, tilt per iteration, heights, warnings, timings (JSON-ready)."""


def preprocess(cloud: Cloud, cfg: PreprocessConfig | None = None) -> Preprocessed:
    """The whole stage (thesis 5.1) on a registered room cloud in metres; see the module docstring."""
    cfg = cfg or PreprocessConfig()
    timings: dict[str, float] = {}
    cpu_timings: dict[str, float] = {}
    warnings: list[str] = []
    clock, cpu_clock = time.perf_counter(), time.process_time()
    start, cpu_start = clock, cpu_clock

    def lap(name: str) -> None:
        nonlocal clock, cpu_clock
        now, cpu_now = time.perf_counter(), time.process_time()
        timings[name] = round(now - clock, 4)
        cpu_timings[name] = round(cpu_now - cpu_clock, 4)
        clock, cpu_clock = now, cpu_now

    min_points = cfg.outlier_neighbours + 1
    require_finite(cloud, min_points=min_points)
    lap("check")

    voxels, voxel_counts = _voxels(cloud, cfg.voxel_size_m, min_points)
    lap("voxel")

    keep, outlier_stats = statistical_outliers(
        voxels.points, cfg.outlier_neighbours, cfg.outlier_std_ratio, cfg.outlier_reference
    )
    clean = voxels.subset(keep)
    lap("outliers")

    surfaces = mls_smooth(
        clean.points, cfg.mls_radius_m, cfg.mls_degree, cfg.mls_edge_ratio, voxel_counts[keep]
    )
    smoothed = Cloud(surfaces.points, clean.colors)
    lap("mls")

    levelling, pivot, level_stats = _levelling(smoothed.points, surfaces, cfg)
    levelled = smoothed.transformed(levelling)
    lap("level")

    z = levelled.points[:, 2]
    histogram, z_sums = height_histogram(z, cfg.voxel_size_m)
    floor_z, ceiling_z, peak_stats = floor_and_ceiling(histogram, z_sums, cfg, warnings)
    lap("histogram")

    height = ceiling_z - floor_z
    slice_low, slice_high, in_slice, slice_reason = _slice_band(
        z, floor_z, ceiling_z, cfg, peak_stats["ceiling_captured"]
    )
    vertical_only = not peak_stats["ceiling_captured"] or slice_low < floor_z + cfg.slice_min_m
    dropped_not_vertical = 0
    if vertical_only:
        # no ceiling to tell walls by their reach (everything in the band reaches its top): keep the points
        # of smooth vertical surfaces; plants, lamps, table tops and ragged edges go
        wall_like = _vertical_surface(surfaces, levelling[:3, :3], cfg.wall_normal_max_z)
        dropped_not_vertical = int((in_slice & ~wall_like).sum())
        if (in_slice & wall_like).any():
            in_slice = in_slice & wall_like
    furniture_slice = levelled.subset(in_slice)
    lap("slice")

    picture = render_histogram(histogram, floor_z, ceiling_z, slice_low, slice_high)
    lap("render")
    timings["total"] = round(time.perf_counter() - start, 4)
    cpu_timings["total"] = round(time.process_time() - cpu_start, 4)

    metrics: dict[str, Any] = {
        "points_in": len(cloud),
        "points_after_voxel": len(voxels),
        "points_after_outliers": len(clean),
        "outliers_removed": len(voxels) - len(clean),
        **outlier_stats,
        **surfaces.stats,
        **level_stats,
        "levelling_pivot_m": [float(v) for v in pivot],
        **peak_stats,
        "floor_z_m": floor_z,
        "ceiling_z_m": ceiling_z,
        "height_m": height,
        "slice_low_z_m": slice_low,
        "slice_high_z_m": slice_high,
        "slice_reason": slice_reason,
        "slice_vertical_surfaces_only": vertical_only,
        "slice_dropped_not_vertical": dropped_not_vertical,
        "slice_points": int(in_slice.sum()),
        "points_out": len(levelled),
        "warnings": warnings,
        "timings_s": timings,
        "cpu_timings_s": cpu_timings,
        "points_per_second": len(cloud) / max(timings["total"], 1e-9),
    }
    return Preprocessed(
        cloud=levelled,
        slice=furniture_slice,
        levelling=levelling,
        floor_z_m=floor_z,
        ceiling_z_m=ceiling_z,
        height_m=height,
        histogram=histogram,
        histogram_png=picture,
        metrics=metrics,
    )


def _voxels(cloud: Cloud, voxel_size_m: float, min_points: int) -> tuple[Cloud, NDArray[np.float64]]:
    """The voxel grid's cloud and per-voxel point counts (K,), enough of them for the outlier test."""
    voxels, voxel_counts = voxel_grid(cloud, voxel_size_m)
    if len(voxels) < min_points:
        raise DegenerateInputError(
            f"only {len(voxels)} voxels of {voxel_size_m} m are occupied, at least {min_points} needed"
        )
    return voxels, voxel_counts


def _levelling(
    points: NDArray[np.float64], surfaces: LocalSurfaces, cfg: PreprocessConfig
) -> tuple[NDArray[np.float64], NDArray[np.float64], dict[str, Any]]:
    """The (4, 4) levelling transform, its pivot (3,) and the levelling statistics: the rotation from the
    normals of the smooth (non-edge) surfaces, turning about the points' (N, 3) centroid so that x-y and
    heights stay close to the input's."""
    rotation, level_stats = level_by_normals(surfaces.normals[~surfaces.edge], cfg)
    pivot = points.mean(axis=0)
    levelling = np.eye(4)
    levelling[:3, :3] = rotation
    levelling[:3, 3] = pivot - rotation @ pivot
    return levelling, pivot, level_stats


def _vertical_surface(
    surfaces: LocalSurfaces, rotation: NDArray[np.float64], max_z: float
) -> NDArray[np.bool_]:
    """(N,) points whose local fit is a smooth surface (not an edge, not unfit) with a normal within
    `max_z` (its levelled z component) of horizontal: walls and the faces of furniture, not the loose
    cloud of a plant nor a table top."""
    n = surfaces.normals
    z = n[:, 0] * rotation[2, 0] + n[:, 1] * rotation[2, 1] + n[:, 2] * rotation[2, 2]  # no threaded BLAS
    with np.errstate(invalid="ignore"):
        return ~surfaces.edge & (np.abs(z) <= max_z)


def _slice_band(
    z: NDArray[np.float64],
    floor_z: float,
    ceiling_z: float,
    cfg: PreprocessConfig,
    ceiling_captured: bool = True,
) -> tuple[float, float, NDArray[np.bool_], str]:
    """The furniture slice's lower and upper height, which of the heights z (N,) lie in it, and why: from
    `slice_min_m` to `slice_max_m` above the floor, at least `slice_ceiling_margin_m` below the ceiling
    (without a captured ceiling `ceiling_z` is the top of the walls, and the margin is a voxel: their
    free top edge is thinned by the outlier filter). When that leaves less than `slice_min_band_m`
    (a low room, walls seen only to 1.3-2 m), the slice is the highest band of that height under its top."""
    height = ceiling_z - floor_z
    margin = cfg.slice_ceiling_margin_m if ceiling_captured else cfg.voxel_size_m
    slice_low = floor_z + cfg.slice_min_m
    slice_high = min(floor_z + cfg.slice_max_m, ceiling_z - margin)
    reason = f"{cfg.slice_min_m}-{cfg.slice_max_m} m above the floor"
    if slice_high < floor_z + cfg.slice_max_m:
        reason += ", cut " + (
            f"{margin} m below the ceiling" if ceiling_captured else f"{margin} m below the top of the walls"
        )
    if slice_high - slice_low < cfg.slice_min_band_m:
        slice_low = slice_high - cfg.slice_min_band_m
        reason = (
            f"the highest {cfg.slice_min_band_m} m band under "
            + ("the ceiling" if ceiling_captured else "the top of the walls (no ceiling captured)")
            + f": walls seen up to {height:.2f} m above the floor"
        )
    if slice_low <= floor_z + cfg.voxel_size_m:
        raise DegenerateInputError(
            f"room height {height:.2f} m leaves no wall band of {cfg.slice_min_band_m} m above the floor "
            f"(slice_min_band_m) and {margin} m below the "
            + ("ceiling" if ceiling_captured else "top of the walls")
        )
    in_slice = (z >= slice_low) & (z <= slice_high)
    if not in_slice.any():
        raise DegenerateInputError(
            f"furniture slice {slice_low:.2f}-{slice_high:.2f} m (levelled frame) holds no points"
        )
    return slice_low, slice_high, in_slice, reason
