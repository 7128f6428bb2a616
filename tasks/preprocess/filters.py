"""The point-level steps of the preprocess stage: the voxel grid (thesis 5.1.2), the statistical outlier
filter (5.1.1, eq 5.1) and moving-least-squares smoothing (5.1.3, eq 5.2)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from tasks.cloud import Cloud, DegenerateInputError
from tasks.threads import THREADS, imap_ordered

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
# The outlier test's K-NN search is bounded at this x the median K-th neighbour distance of a sample: it
# prunes from the start. On the 5 M point bench room's 672 k voxels 86 % have their K within it; the rest
# (isolated points, sparse surfaces) are searched again unbounded. CPU of the search, unbounded 2.71 s;
# bounded at 1.2x 2.61, 1.5x 2.35, 2x 2.47, 3x 2.49 (one measurement each, a shared machine).
_BOUND_RATIO = 1.5
_BOUND_SAMPLE = 4096
# Largest grid (cells) ranked through an occupancy array (5 bytes a cell) rather than a sort.
_DENSE_CELLS = 1 << 24
# Neighbour entries per chunk of the MLS and outlier queries: bounds memory (~25 MB per (M, K, 3) array).
_CHUNK_ENTRIES = 1_000_000
# Threads the MLS fits share their chunks among: this machine's cores, at most two (one room's stage; rooms
# run in parallel besides). The chunks are fixed, so the result does not depend on it.
_THREADS = THREADS

_T = TypeVar("_T")


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
    # per column: a min or max over axis 0 of the (N, 3) array costs five times as much (the same numbers)
    ijk -= np.array([ijk[:, i].min() for i in range(3)])
    dims = np.array([ijk[:, i].max() for i in range(3)]) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0**62:
        extent = (dims * cell_m).max()
        raise DegenerateInputError(f"cloud extent {extent:.3g} m is too large for a {cell_m} m grid")
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    inverse, cells = _dense_ranks(key, int(dims[0]) * int(dims[1]) * int(dims[2]))
    # the cells' sums of the weights, then of each weighted coordinate and colour: one bincount each,
    # shared among the threads (each sum is the same whichever thread makes it)
    sources: list[NDArray[Any] | None] = [weights]
    for values in (points,) if colors is None else (points, colors):
        sources += [values[:, i] if weights is None else values[:, i] * weights for i in range(3)]
    sums = _map_chunks(
        lambda i: np.bincount(inverse, weights=sources[i], minlength=cells).astype(np.float64),
        range(len(sources)),
    )
    totals = sums[0]
    centroids = np.stack(sums[1:4], axis=1) / totals[:, None]
    mean_colors = (
        None if colors is None else np.rint(np.stack(sums[4:7], axis=1) / totals[:, None]).astype(np.uint8)
    )
    return centroids, totals, mean_colors


def _dense_ranks(key: NDArray[np.int64], extent: int) -> tuple[NDArray[np.intp], int]:
    """Each key's rank among the distinct keys (N,) (the inverse of np.unique, the same numbers) and their
    number, for keys in [0, extent), without sorting the N keys: up to `_DENSE_CELLS` cells (a room at
    2 cm: 10 M) an occupancy grid ranks them in linear time; a larger grid (a few outliers metres away
    stretch it) is hashed (Arrow's dictionary encoding) and only the distinct keys are sorted. 5 M points:
    np.unique 1.0 s CPU, hashed 0.5 s, occupancy grid 0.1 s."""
    if extent > _DENSE_CELLS:
        import pyarrow as pa

        encoded = pa.array(key).dictionary_encode()
        codes = encoded.indices.to_numpy(zero_copy_only=False)
        distinct = encoded.dictionary.to_numpy(zero_copy_only=False)
        rank = np.empty(len(distinct), np.intp)
        rank[np.argsort(distinct)] = np.arange(len(distinct))
        return rank[codes], len(distinct)
    occupied = np.zeros(extent, bool)
    occupied[key] = True
    cells = np.flatnonzero(occupied)
    rank = np.empty(extent, np.int32 if len(cells) < 2**31 else np.int64)
    rank[cells] = np.arange(len(cells), dtype=rank.dtype)
    return rank[key].astype(np.intp), len(cells)


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


def _row_median(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """np.median(values, axis=1) of (N, K) values without NaNs, the same numbers: a sort of each short row
    and the middle one (the mean of the middle two) costs a fifth of numpy's partition (672 k rows of 20:
    0.10 s against 0.49 s CPU)."""
    k = values.shape[1]
    ordered = np.sort(values, axis=1)
    if k % 2:
        return ordered[:, k // 2].copy()
    return ordered[:, k // 2 - 1 : k // 2 + 1].mean(axis=1)


def _search_bound(tree: cKDTree, points: NDArray[np.float64], k: int) -> float:
    """A distance within which most points have their k nearest (k including the point itself):
    `_BOUND_RATIO` x the median k-th distance of a spread sample of ~`_BOUND_SAMPLE` points. Only the
    search's cost depends on it, not its answers."""
    sample = points[:: max(1, len(points) // _BOUND_SAMPLE)]
    kth = tree.query(sample, k=k, workers=1)[0][:, -1]
    return float(_BOUND_RATIO * np.median(kth))


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
    # unbalanced (sliding-midpoint splits): the same neighbours from a cheaper build and query
    tree = cKDTree(points, balanced_tree=False)
    n = len(points)
    mean_dist = np.empty(n)
    local = reference == "local"
    idx = np.empty((n, neighbours), np.int32) if local else None
    link = np.empty((n, neighbours)) if local else None
    chunk = max(1, _CHUNK_ENTRIES // (neighbours + 1))

    bound = _search_bound(tree, points, neighbours + 1)

    def search(lo: int) -> None:
        # queried in the tree's leaf order, so that consecutive queries walk the same nodes: the same
        # answers; on the 1 M point bench room 5-15 % less CPU than the voxels' own order (already local; a
        # random order costs 2.6x). Each chunk on one thread, its rows' statistics with it: both cores
        # busy, the same rows written whichever thread runs the chunk. The search is bounded (it prunes
        # from the start); a row it leaves short (a sparse or isolated point) is searched again unbounded.
        rows = tree.indices[lo : lo + chunk]
        query = points[rows]
        dist, near = tree.query(query, k=neighbours + 1, distance_upper_bound=bound, workers=1)
        short = np.flatnonzero(np.isinf(dist[:, -1]))
        if len(short):
            dist[short], near[short] = tree.query(query[short], k=neighbours + 1, workers=1)
        mean_dist[rows] = dist[:, 1:].mean(axis=1)  # column 0 is the point itself
        if local:
            idx[rows] = near[:, 1:]
            link[rows] = dist[:, 1:]

    _map_chunks(search, range(0, n, chunk))
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
    median = np.empty(n)

    def neighbour_median(lo: int) -> None:
        median[lo : lo + chunk] = _row_median(mean_dist[idx[lo : lo + chunk]])

    _map_chunks(neighbour_median, range(0, n, chunk))
    ratio = mean_dist / np.maximum(median, 1e-12)
    mu_r, sigma_r = _clipped_mean_std(ratio)
    ratio_threshold = mu_r + std_ratio * sigma_r
    regular = ratio <= ratio_threshold
    # links between regular points no longer than the smaller mean neighbour distance of the two. The
    # anchors (dense and regular) are kept whatever links them, so links between two anchors are left out:
    # a chain from another point reaches its first anchor through links that all touch a non-anchor, and
    # the graph shrinks to the sparse parts of the cloud (a few per cent of the links on a room).
    anchor = dense & regular
    # the links touching a non-anchor between two regular points, as flat (n, K) positions; then the short
    # ones among them (the same links, in the same order, as testing length first: the row and column
    # indices and the distances are gathered for fewer links)
    candidate = (~anchor)[idx]
    candidate |= ~anchor[:, None]
    candidate &= regular[idx]
    candidate &= regular[:, None]
    entry = np.flatnonzero(candidate)
    rows = entry // neighbours
    cols = idx.ravel()[entry].astype(np.intp)
    ok = link.ravel()[entry] <= _LINK_RATIO * np.minimum(mean_dist[rows], mean_dist[cols])
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
    near an edge the plane fit mixes both faces and would round the edge. Vectorized over fixed chunks of
    points (bounded memory), the chunks shared among `_THREADS` threads: each chunk writes its own rows,
    so the result is the same bytes whatever the number of threads."""
    n = len(points)
    origin = points.mean(axis=0)  # local coordinates keep the moment sums well conditioned
    local = points - origin
    support, counts, _ = _cell_centroids(local, radius_m / _MLS_CELLS_PER_RADIUS, weights=weights)
    tree = cKDTree(support, balanced_tree=False)  # sliding-midpoint splits: the same neighbours, cheaper
    k = min(_MLS_MAX_SUPPORT, len(support))
    # the support's coordinates as three contiguous columns: the fits gather and sum (M, K) arrays along
    # their contiguous last axis, three times faster than (M, K, 3) ones summed along the middle axis
    columns = [np.ascontiguousarray(support[:, i]) for i in range(3)]
    shifts = np.zeros((n, 3))
    normals = np.full((n, 3), np.nan)
    curvature = np.full(n, np.nan)
    chunk = max(1, _CHUNK_ENTRIES // k)

    def fit(lo: int) -> tuple[int, int]:
        hi = min(lo + chunk, n)
        capped, unfit, shift, normal, variation = _mls_chunk(
            local[lo:hi], tree, columns, support, counts, k, radius_m, degree
        )
        shifts[lo:hi] = shift
        normals[lo:hi] = normal
        curvature[lo:hi] = variation
        return capped, unfit

    tallies = _map_chunks(fit, range(0, n, chunk))
    capped = sum(c for c, _ in tallies)
    unfit = sum(u for _, u in tallies)
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


def _map_chunks(work: Callable[[int], _T], starts: Iterable[int]) -> list[_T]:
    """`work` on every chunk start (or item), results in order, on up to `_THREADS` threads
    (`tasks.threads.imap_ordered`: numpy and the KD-tree release the GIL); each call must touch only its
    own rows."""
    return list(imap_ordered(work, starts, _THREADS))


def _mls_chunk(
    p: NDArray[np.float64],
    tree: cKDTree,
    columns: list[NDArray[np.float64]],
    support: NDArray[np.float64],
    counts: NDArray[np.float64],
    k: int,
    radius_m: float,
    degree: int,
) -> tuple[int, int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The local fits of points p (M, 3) (local coordinates) on the support (its KD-tree, its coordinate
    columns, its weights `counts`): fits capped at k support points, fits not possible, and per point the
    shift onto the fit (M, 3), the fit's normal (M, 3) and surface variation (M,) (0 and NaN where unfit)."""
    m = len(p)
    dist, idx = tree.query(p, k=k, distance_upper_bound=radius_m, workers=1)
    dist = dist.reshape(m, k)
    idx = idx.reshape(m, k)
    valid = idx < len(support)
    nvalid = valid.sum(axis=1)
    capped = int((nvalid == _MLS_MAX_SUPPORT).sum())
    idx[~valid] = 0
    # Gaussian weights (eq 5.2) times the support weights; a missing neighbour has dist inf, weight 0
    dist *= dist
    dist *= -1.0 / radius_m**2
    weight = np.take(counts, idx)
    weight *= np.exp(dist, out=dist)
    # support relative to the point, one (M, K) array per axis
    rel = [np.take(columns[i], idx) for i in range(3)]
    for i in range(3):
        rel[i] -= p[:, i, None]
    wsum = weight.sum(axis=1)
    ok = (nvalid >= (3 if degree == 1 else 6)) & (wsum > 0)
    wsum[~ok] = 1.0
    weighted = [weight * rel[i] for i in range(3)]
    mean = np.stack([weighted[i].sum(axis=1) / wsum for i in range(3)], axis=1)
    cov = np.empty((m, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = np.einsum("mk,mk->m", weighted[i], rel[j]) / wsum - mean[:, i] * mean[:, j]
            cov[:, j, i] = cov[:, i, j]
    if degree == 2:
        evals, evecs = np.linalg.eigh(cov)
        smallest, normal = evals[:, 0], evecs[:, :, 0]
    else:
        smallest, normal = _plane_eigen(cov)
    # the point is the local origin: its foot on the plane through `mean` with normal `normal`
    foot = np.einsum("mj,mj->m", mean, normal)[:, None] * normal
    shift = foot
    if degree == 2:
        stacked = np.stack(rel, axis=2)
        shift = (
            foot
            + _quadratic_offset(stacked - foot[:, None, :], weight, evecs, radius_m, ok)[:, None] * normal
        )
    total = np.trace(cov, axis1=1, axis2=2)  # the sum of the eigenvalues
    ok &= total > 0
    shift[~ok] = 0.0
    normal[~ok] = np.nan
    variation = np.full(m, np.nan)
    variation[ok] = smallest[ok] / total[ok]
    return capped, int((~ok).sum()), shift, normal, variation


def _plane_eigen(cov: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The smallest eigenvalue (M,) and its unit eigenvector (M, 3) (sign arbitrary) of symmetric 3x3
    matrices (M, 3, 3), in closed form: the eigenvalue by the trigonometric solution of the characteristic
    cubic, the vector as the largest cross product of two rows of cov - λ I. The same as numpy's eigh to
    float rounding for the plane fits here (a batched eigh costs ~1.6 µs a matrix, this ~0.2); rows whose
    two smallest eigenvalues (nearly) coincide, where the vector is not determined, go to eigh."""
    a00, a11, a22 = cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2]
    a01, a02, a12 = cov[:, 0, 1], cov[:, 0, 2], cov[:, 1, 2]
    q = (a00 + a11 + a22) / 3.0
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    p = np.sqrt(((a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1) / 6.0)
    safe = np.where(p > 0, p, 1.0)
    b00, b11, b22 = (a00 - q) / safe, (a11 - q) / safe, (a22 - q) / safe
    b01, b02, b12 = a01 / safe, a02 / safe, a12 / safe
    det = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
    phi = np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0
    smallest = np.where(p > 0, q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0), q)
    largest = np.where(p > 0, q + 2.0 * p * np.cos(phi), q)
    shifted = cov - smallest[:, None, None] * np.eye(3)
    r0, r1, r2 = shifted[:, 0], shifted[:, 1], shifted[:, 2]
    crosses = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)  # (M, 3, 3)
    norms = np.einsum("mij,mij->mi", crosses, crosses)
    best = np.argmax(norms, axis=1)
    vector = crosses[np.arange(len(cov)), best]
    length = np.sqrt(norms[np.arange(len(cov)), best])
    # |cross| is (λ1 - λ0)(λ2 - λ0) for the best pair: against (λ2 - λ0)² it says how well λ0 stands apart
    spread = largest - smallest
    unsure = ~(length > 1e-6 * spread * spread) | ~np.isfinite(length)
    normal = vector / np.where(unsure, 1.0, length)[:, None]
    if unsure.any():
        evals, evecs = np.linalg.eigh(cov[unsure])
        smallest[unsure] = evals[:, 0]
        normal[unsure] = evecs[:, :, 0]
    return smallest, normal


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
