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
   `slice_ceiling_margin_m` below the ceiling (lamps, and rooms lower than 2.5 m).

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

import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.signal import find_peaks
from scipy.spatial import cKDTree

from tasks.cloud import Cloud, DegenerateInputError, require_finite

# Support cells per MLS radius: with cells of r/3 a plane has ~28 support points within r.
_MLS_CELLS_PER_RADIUS = 3
# At most this many support points per fit, the nearest, so a cut drops the lightest. A corner of three
# planes has ~60. On the 2 M point bench room 48 capped 3.8 % of the fits, 64 none, both with the same
# result and CPU time.
_MLS_MAX_SUPPORT = 64
# Density-aware outlier test: two points are linked (same surface) when they lie no farther apart than this
# × the smaller of their mean K-NN distances. On a regular grid the nearest neighbours lie at 0.56 × the
# mean distance to the 20 nearest, so a sparse surface stays linked while its sampling thins out by up to
# ~1.8x from one point to the next; a point 10 cm off a surface sampled every 2 cm is not linked.
_LINK_RATIO = 1.0
# Neighbour entries per chunk of the MLS and outlier queries: bounds memory (~25 MB per (M, K, 3) array).
_CHUNK_ENTRIES = 1_000_000


@dataclass(frozen=True)
class PreprocessConfig:
    """Preprocess parameters (thesis 5.1, table 6.3)."""

    outlier_neighbours: int = 20
    """K: nearest neighbours whose mean distance each point is tested on (count; thesis: 20)."""
    outlier_std_ratio: float = 2.0
    """Removed: statistic above μ + this × σ of its values (unitless; eq 5.1: 1σ or 2σ, table 6.3)."""
    outlier_reference: Literal["global", "local"] = "local"
    """"global": eq 5.1 on the mean K-NN distance (PCL); "local": density-aware, the distance against the
    neighbours' and linked to the dense points (far surfaces of a range sensor stay), see
    `statistical_outliers`."""
    voxel_size_m: float = 0.02
    """Voxel grid edge (m); also the height histogram's bin (thesis: 3-5 cm Kinect, 1 cm TLS)."""
    mls_radius_m: float = 0.10
    """MLS search radius, also the Gaussian weight's scale (m; thesis: 10-15 cm for Kinect)."""
    mls_degree: Literal[1, 2] = 1
    """Degree of the MLS local fit: 1 plane (the thesis' choice for Kinect), 2 quadratic (unitless)."""
    mls_edge_ratio: float = 10.0
    """Surface variation above this × its median marks an edge: not moved by MLS, not levelled on (0: off)."""
    level_normals: Literal["horizontal", "vertical", "both"] = "both"
    """Normals the tilt comes from: horizontal surfaces (the thesis), walls, or both (measured best)."""
    level_split_deg: float = 45.0
    """Normals within this angle of the vertical axis are horizontal surfaces, the rest vertical (degrees)."""
    level_max_iterations: int = 10
    """Most levelling iterations (rotate, reclassify, re-estimate) (count)."""
    level_tol_deg: float = 0.005
    """Levelling stops once an iteration's tilt correction is below this (degrees)."""
    peak_min_area_m2: float = 0.25
    """A histogram peak can be floor or ceiling if it rises this much area above its surroundings (m²)."""
    surface_search_m: float = 0.20
    """Floor (ceiling) peak must lie within this of where the walls end, else it is not captured (m)."""
    slice_min_m: float = 1.5
    """Furniture slice lower edge above the floor (m)."""
    slice_max_m: float = 2.5
    """Furniture slice upper edge above the floor (m)."""
    slice_ceiling_margin_m: float = 0.15
    """The slice stops at least this far below the ceiling: lamps, rooms lower than slice_max_m (m)."""

    def __post_init__(self) -> None:
        checks = [
            (self.outlier_neighbours >= 1, "outlier_neighbours must be at least 1"),
            (self.outlier_std_ratio > 0, "outlier_std_ratio must be positive"),
            (self.outlier_reference in ("global", "local"), "outlier_reference must be global or local"),
            (self.voxel_size_m > 0, "voxel_size_m must be positive"),
            (self.mls_radius_m > self.voxel_size_m, "mls_radius_m must exceed voxel_size_m"),
            (self.mls_degree in (1, 2), "mls_degree must be 1 or 2"),
            (0 < self.level_split_deg < 90, "level_split_deg must be between 0 and 90"),
            (self.level_max_iterations >= 1, "level_max_iterations must be at least 1"),
            (self.level_tol_deg > 0, "level_tol_deg must be positive"),
            (self.mls_edge_ratio >= 0, "mls_edge_ratio must be >= 0"),
            (self.peak_min_area_m2 > 0, "peak_min_area_m2 must be positive"),
            (self.surface_search_m > 0, "surface_search_m must be positive"),
            (0 <= self.slice_min_m < self.slice_max_m, "slice_min_m must be >= 0 and below slice_max_m"),
            (self.slice_ceiling_margin_m >= 0, "slice_ceiling_margin_m must be >= 0"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"preprocess: {message}")


class HeightHistogram(NamedTuple):
    """Point heights in the levelled frame; unpacks as `edges, counts`."""

    edges_m: NDArray[np.float64]
    """(B + 1,) bin edges, metres, ascending."""
    counts: NDArray[np.int64]
    """(B,) points per bin."""


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


# ------------------------------------------------------------------------------------------------- stage


def preprocess(cloud: Cloud, cfg: PreprocessConfig | None = None) -> Preprocessed:
    """The whole stage (thesis 5.1) on a registered room cloud in metres; see the module docstring."""
    cfg = cfg or PreprocessConfig()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    clock = time.perf_counter()
    start = clock

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = round(now - clock, 4)
        clock = now

    min_points = cfg.outlier_neighbours + 1
    require_finite(cloud, min_points=min_points)
    lap("check")

    voxels, voxel_counts = voxel_grid(cloud, cfg.voxel_size_m)
    if len(voxels) < min_points:
        raise DegenerateInputError(
            f"only {len(voxels)} voxels of {cfg.voxel_size_m} m are occupied, at least {min_points} needed"
        )
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

    rotation, level_stats = level_by_normals(surfaces.normals[~surfaces.edge], cfg)
    pivot = smoothed.points.mean(axis=0)
    levelling = np.eye(4)
    levelling[:3, :3] = rotation
    levelling[:3, 3] = pivot - rotation @ pivot
    levelled = smoothed.transformed(levelling)
    lap("level")

    z = levelled.points[:, 2]
    histogram, z_sums = height_histogram(z, cfg.voxel_size_m)
    floor_z, ceiling_z, peak_stats = floor_and_ceiling(histogram, z_sums, cfg, warnings)
    lap("histogram")

    height = ceiling_z - floor_z
    slice_low = floor_z + cfg.slice_min_m
    slice_high = min(floor_z + cfg.slice_max_m, ceiling_z - cfg.slice_ceiling_margin_m)
    if slice_high <= slice_low:
        raise DegenerateInputError(
            f"room height {height:.2f} m leaves no furniture slice between {cfg.slice_min_m} m above the "
            f"floor and {cfg.slice_ceiling_margin_m} m below the ceiling"
        )
    in_slice = (z >= slice_low) & (z <= slice_high)
    if not in_slice.any():
        raise DegenerateInputError(
            f"furniture slice {slice_low:.2f}-{slice_high:.2f} m (levelled frame) holds no points"
        )
    furniture_slice = levelled.subset(in_slice)
    lap("slice")

    picture = render_histogram(histogram, floor_z, ceiling_z, slice_low, slice_high)
    lap("render")
    timings["total"] = round(time.perf_counter() - start, 4)

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
        "slice_points": int(in_slice.sum()),
        "points_out": len(levelled),
        "warnings": warnings,
        "timings_s": timings,
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


# -------------------------------------------------------------------------------------------- voxel grid


def _cell_centroids(
    points: NDArray[np.float64],
    cell_m: float,
    colors: NDArray[np.uint8] | None = None,
    weights: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8] | None]:
    """Weighted centroid (K, 3), total weight (K,) (the point count by default) and mean colour (K, 3) of
    every occupied cell of an origin-anchored grid of edge `cell_m`, cells in (x, y, z) index order."""
    ijk = np.floor(points / cell_m).astype(np.int64)
    ijk -= ijk.min(axis=0)
    dims = ijk.max(axis=0) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0**62:
        extent = (dims * cell_m).max()
        raise DegenerateInputError(f"cloud extent {extent:.3g} m is too large for a {cell_m} m grid")
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    _, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.ravel()
    cells = int(inverse.max()) + 1
    totals = np.bincount(inverse, weights=weights, minlength=cells).astype(np.float64)

    def mean_of(values: NDArray[Any]) -> NDArray[np.float64]:
        columns = values if weights is None else values * weights[:, None]
        sums = [np.bincount(inverse, weights=columns[:, i], minlength=cells) for i in range(3)]
        return np.stack(sums, axis=1) / totals[:, None]

    centroids = mean_of(points)
    mean_colors = None if colors is None else np.rint(mean_of(colors)).astype(np.uint8)
    return centroids, totals, mean_colors


def voxel_grid(cloud: Cloud, voxel_size_m: float) -> tuple[Cloud, NDArray[np.float64]]:
    """The cloud with each occupied voxel's points replaced by their centroid, colours averaged (thesis
    5.1.2), and each voxel's point count (K,)."""
    centroids, counts, colors = _cell_centroids(cloud.points, voxel_size_m, cloud.colors)
    return Cloud(centroids, colors), counts


# ----------------------------------------------------------------------------------- outlier removal


def _clipped_mean_std(values: NDArray[np.float64]) -> tuple[float, float]:
    """μ and σ of the Gaussian the one-tailed test assumes, estimated with 3σ clipping: a few values far
    out (points metres away) would otherwise inflate σ so much that the test keeps them."""
    inlier = np.ones(len(values), bool)
    for _ in range(20):
        mu = float(values[inlier].mean())
        sigma = float(values[inlier].std(ddof=1)) if inlier.sum() > 1 else 0.0
        clipped = values <= mu + 3 * sigma
        if np.array_equal(clipped, inlier):
            break
        inlier = clipped
    return mu, sigma


def statistical_outliers(
    points: NDArray[np.float64],
    neighbours: int = 20,
    std_ratio: float = 1.0,
    reference: Literal["global", "local"] = "global",
) -> tuple[NDArray[np.bool_], dict[str, Any]]:
    """Keep-mask (N,) of the statistical outlier filter (thesis 5.1.1, eq 5.1) on points (N, 3) metres, and
    its statistics. Each point's statistic is its mean distance d to its `neighbours` nearest other points.

    reference "global" (eq 5.1 as PCL): points with d above μ + std_ratio · σ are outliers, μ and σ those
    of all d after 3σ clipping.

    reference "local" (density-aware): the sampling density of a range sensor falls with the range, so a far
    wall's d is large everywhere along it, and the global test trims it although its points are as
    regular as any; an outlier differs from its surroundings, not from the room. Two tests:
    - local: r = d / (median d of the point's neighbours) must pass eq 5.1 (μ_r + std_ratio · σ_r, 3σ
      clipped): an isolated point beside a surface (flying pixel, mixed pixel) has r >> 1; a point of a
      sparse surface has r ≈ 1 like its neighbours;
    - continuity: every kept point must be connected to the points passing the global test through a
      chain of neighbour links no longer than the smaller of the two points' d (`_LINK_RATIO`). A sparse
      wall is reached through its gradually thinning sampling; a cloud of outliers metres away (regular
      among themselves, r ≈ 1) is not.
    μ, σ and the threshold reported are the global test's (metres); the local test's are added."""
    if len(points) <= neighbours:
        raise DegenerateInputError(
            f"{len(points)} points are too few for a {neighbours}-neighbour outlier test"
        )
    if reference not in ("global", "local"):
        raise ValueError(f"outlier reference must be 'global' or 'local', got {reference!r}")
    tree = cKDTree(points)
    n = len(points)
    mean_dist = np.empty(n)
    local = reference == "local"
    idx = np.empty((n, neighbours), np.int32) if local else None
    link = np.empty((n, neighbours)) if local else None
    chunk = max(1, _CHUNK_ENTRIES // (neighbours + 1))
    for lo in range(0, n, chunk):
        dist, near = tree.query(points[lo : lo + chunk], k=neighbours + 1, workers=-1)
        mean_dist[lo : lo + chunk] = dist[:, 1:].mean(axis=1)  # column 0 is the point itself
        if local:
            idx[lo : lo + chunk] = near[:, 1:]
            link[lo : lo + chunk] = dist[:, 1:]
    mu, sigma = _clipped_mean_std(mean_dist)
    threshold = mu + std_ratio * sigma
    dense = mean_dist <= threshold
    stats: dict[str, Any] = {
        "outlier_reference": reference,
        "outlier_knn_mean_m": mu,
        "outlier_knn_std_m": sigma,
        "outlier_threshold_m": threshold,
        "outlier_knn_mean_unclipped_m": float(mean_dist.mean()),
        "outlier_knn_std_unclipped_m": float(mean_dist.std(ddof=1)),
    }
    if not local:
        return dense, stats
    assert idx is not None and link is not None
    ratio = mean_dist / np.maximum(np.median(mean_dist[idx], axis=1), 1e-12)
    mu_r, sigma_r = _clipped_mean_std(ratio)
    ratio_threshold = mu_r + std_ratio * sigma_r
    regular = ratio <= ratio_threshold
    # links between regular points no longer than the smaller mean neighbour distance of the two. The
    # anchors (dense and regular) are kept whatever links them, so links between two anchors are left out:
    # a chain from another point reaches its first anchor through links that all touch a non-anchor, and
    # the graph shrinks to the sparse parts of the cloud (a few per cent of the links on a room).
    anchor = dense & regular
    entry = (~anchor)[:, None] | (~anchor)[idx]  # (n, K)
    rows = np.nonzero(entry)[0]
    cols = idx[entry].astype(np.intp)
    short = link[entry] <= _LINK_RATIO * np.minimum(mean_dist[rows], mean_dist[cols])
    ok = short & regular[rows] & regular[cols]
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(int(ok.sum()), np.int8), (rows[ok], cols[ok])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    anchored = np.zeros(component.max() + 1, bool)
    anchored[component[anchor]] = True
    keep = regular & anchored[component]
    stats.update(
        {
            "outlier_ratio_mean": mu_r,
            "outlier_ratio_std": sigma_r,
            "outlier_ratio_threshold": ratio_threshold,
            "outlier_irregular": int((~regular).sum()),
            "outlier_unanchored": int((regular & ~keep).sum()),
            "outlier_sparse_kept": int((keep & ~dense).sum()),
        }
    )
    return keep, stats


# ------------------------------------------------------------------------------------ MLS smoothing


@dataclass(frozen=True)
class LocalSurfaces:
    """Result of MLS smoothing: the projected points and each point's local fit."""

    points: NDArray[np.float64]
    """(N, 3) points projected onto their local surface (unmoved where no fit was possible)."""
    normals: NDArray[np.float64]
    """(N, 3) unit normals of the local plane fits, arbitrary sign; NaN where no fit was possible."""
    curvature: NDArray[np.float64]
    """(N,) surface variation λ0/(λ0+λ1+λ2) of the fit (0 plane, 1/3 isotropic); NaN where unfit."""
    edge: NDArray[np.bool_]
    """(N,) points left in place: unfit, or on an edge (surface variation above edge ratio × median)."""
    stats: dict[str, float]
    """Shift statistics and fit counts."""


def mls_smooth(
    points: NDArray[np.float64],
    radius_m: float,
    degree: int = 1,
    edge_ratio: float = 0.0,
    weights: NDArray[np.float64] | None = None,
) -> LocalSurfaces:
    """Moving-least-squares projection (thesis 5.1.3, eq 5.2, as PCL's MLS with Gaussian weights
    exp(-d²/r²) within r): for each point a weighted plane (degree 1) or quadratic height field over that
    plane (degree 2) is fitted to the support points within `radius_m`, and the point is moved onto it.
    Support points are the centroids of cells of r/3 weighted by their total `weights` (per point, default
    1; pass the voxel counts so the fits see the raw points' moments, see the module doc).
    With `edge_ratio` > 0, points whose surface variation exceeds edge_ratio × the median stay in place:
    near an edge the plane fit mixes both faces and would round the edge. Vectorized over chunks of
    points (bounded memory)."""
    n = len(points)
    origin = points.mean(axis=0)  # local coordinates keep the moment sums well conditioned
    local = points - origin
    support, counts, _ = _cell_centroids(local, radius_m / _MLS_CELLS_PER_RADIUS, weights=weights)
    tree = cKDTree(support)
    k = min(_MLS_MAX_SUPPORT, len(support))
    min_support = 3 if degree == 1 else 6
    shifts = np.zeros((n, 3))
    normals = np.full((n, 3), np.nan)
    curvature = np.full(n, np.nan)
    capped = 0
    unfit = 0
    inv_r2 = 1.0 / radius_m**2
    chunk = max(1, _CHUNK_ENTRIES // k)
    for lo in range(0, n, chunk):
        hi = min(lo + chunk, n)
        p = local[lo:hi]
        dist, idx = tree.query(p, k=k, distance_upper_bound=radius_m, workers=-1)
        dist = dist.reshape(len(p), k)
        idx = idx.reshape(len(p), k)
        valid = idx < len(support)
        nvalid = valid.sum(axis=1)
        capped += int((nvalid == _MLS_MAX_SUPPORT).sum())
        idx[~valid] = 0
        # Gaussian weights (eq 5.2) times the support weights; a missing neighbour has dist inf, weight 0
        weight = np.take(counts, idx) * np.exp(-(dist * dist) * inv_r2)
        rel = np.take(support, idx, axis=0)
        rel -= p[:, None, :]  # (M, K, 3) support relative to the point
        wsum = weight.sum(axis=1)
        ok = (nvalid >= min_support) & (wsum > 0)
        wsum[~ok] = 1.0
        weighted = rel * weight[:, :, None]
        mean = weighted.sum(axis=1) / wsum[:, None]
        cov = (
            np.matmul(weighted.transpose(0, 2, 1), rel) / wsum[:, None, None]
            - mean[:, :, None] * mean[:, None, :]
        )
        evals, evecs = np.linalg.eigh(cov)
        normal = evecs[:, :, 0]
        # the point is the local origin: its foot on the plane through `mean` with normal `normal`
        foot = np.einsum("mj,mj->m", mean, normal)[:, None] * normal
        shift = foot
        if degree == 2:
            shift = (
                foot
                + _quadratic_offset(rel - foot[:, None, :], weight, evecs, radius_m, ok)[:, None] * normal
            )
        total = evals.sum(axis=1)
        ok &= total > 0
        unfit += int((~ok).sum())
        shifts[lo:hi][ok] = shift[ok]
        normals[lo:hi][ok] = normal[ok]
        curvature[lo:hi][ok] = evals[ok, 0] / total[ok]
    fitted = np.isfinite(curvature)
    edge = ~fitted
    median = float(np.median(curvature[fitted])) if fitted.any() else math.nan
    if edge_ratio > 0 and fitted.any():
        edge[fitted] = curvature[fitted] > edge_ratio * median
    shifts[edge] = 0.0
    moved = points + shifts
    step = np.linalg.norm(shifts, axis=1)
    stats = {
        "mls_mean_shift_m": float(step.mean()),
        "mls_rms_shift_m": float(np.sqrt(np.mean(step**2))),
        "mls_max_shift_m": float(step.max()),
        "mls_support_points": len(support),
        "mls_capped_fraction": capped / n,
        "mls_unfit_points": unfit,
        "mls_median_surface_variation": median,
        "mls_edge_points": int(edge.sum()) - unfit,
    }
    return LocalSurfaces(moved, normals, curvature, edge, stats)


def _quadratic_offset(
    rel: NDArray[np.float64],
    weight: NDArray[np.float64],
    frames: NDArray[np.float64],
    scale: float,
    ok: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Height at the foot point (u = v = 0) of the weighted quadratic
    w = c0 + c1 u + c2 v + c3 u² + c4 uv + c5 v²
    fitted to support points `rel` (M, K, 3), given relative to the foot, in each plane frame `frames`
    (M, 3, 3: columns normal, minor, major); 0 where the fit is not `ok`."""
    u = np.einsum("mkj,mj->mk", rel, frames[:, :, 2]) / scale
    v = np.einsum("mkj,mj->mk", rel, frames[:, :, 1]) / scale
    w = np.einsum("mkj,mj->mk", rel, frames[:, :, 0])
    design = np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=2)  # (M, K, 6)
    weighted = design * weight[:, :, None]
    normal_matrix = np.matmul(weighted.transpose(0, 2, 1), design)
    rhs = np.einsum("mki,mk->mi", weighted, w)
    ridge = 1e-9 * np.trace(normal_matrix, axis1=1, axis2=2) + 1e-300
    normal_matrix += ridge[:, None, None] * np.eye(6)
    coef = np.linalg.solve(normal_matrix, rhs[:, :, None])[:, :, 0]
    return np.where(ok, coef[:, 0], 0.0)


# ---------------------------------------------------------------------------------------------- levelling


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
    for _ in range(cfg.level_max_iterations):
        current = n @ rotation.T
        horizontal = np.abs(current[:, 2]) >= cos_split
        n_horizontal = int(horizontal.sum())
        n_vertical = len(current) - n_horizontal
        scatter = np.zeros((3, 3))
        if cfg.level_normals in ("horizontal", "both"):
            h = current[horizontal]
            scatter += h.T @ h
        if cfg.level_normals in ("vertical", "both"):
            v = current[~horizontal]
            scatter += len(v) * np.eye(3) - v.T @ v
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
    final = n @ rotation.T
    horizontal = np.abs(final[:, 2]) >= cos_split
    spread = np.degrees(np.arccos(np.clip(np.abs(final[horizontal, 2]), 0, 1))) if horizontal.any() else []
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


# ------------------------------------------------------------------------------------------ heights


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
    with a warning; neither captured is an error."""
    bottom, top = _band_edges(hist)
    span = top - bottom
    if span < cfg.slice_min_m:
        raise DegenerateInputError(
            f"the levelled cloud spans only {span:.2f} m in height (a single plane?); "
            f"a room needs more than slice_min_m = {cfg.slice_min_m} m"
        )
    bin_m = float(hist.edges_m[1] - hist.edges_m[0])
    min_count = cfg.peak_min_area_m2 / bin_m**2
    padded = np.concatenate([[0], hist.counts, [0]])
    found, _ = find_peaks(padded, prominence=min_count)
    peaks = [_refined_peak(int(i) - 1, hist, z_sums) for i in found]
    floor = peaks[0] if peaks and peaks[0] - bottom <= cfg.surface_search_m else None
    ceiling = peaks[-1] if peaks and top - peaks[-1] <= cfg.surface_search_m else None
    if floor is None and ceiling is None:
        raise DegenerateInputError(
            f"no floor or ceiling in the height histogram: no area of {cfg.peak_min_area_m2} m² within "
            f"{cfg.surface_search_m} m of the lowest or highest points"
        )
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
