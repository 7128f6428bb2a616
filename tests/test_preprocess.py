"""Preprocess stage (thesis 5.1): every step on inputs with known answers, then the whole stage on a
synthetic tilted box room (`tasks.synth.rooms.tilted_box_room`; issue 2, must-show 6)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from tasks.cloud import Cloud, DegenerateInputError
from tasks.preprocess import filters
from tasks.preprocess.config import PreprocessConfig
from tasks.preprocess.filters import mls_smooth, statistical_outliers, voxel_grid
from tasks.preprocess.levelling import floor_and_ceiling, height_histogram, level_by_normals
from tasks.preprocess.pipeline import preprocess
from tasks.synth.rooms import FAR_M, residual_tilt_deg, surface_distance, tilted_box_room, to_room_frame


@pytest.fixture(scope="module")
def room():
    """The must-show room: 2.70 m high, tilted 3° about a non-axis direction, 2 % outliers, furnished."""
    cloud, truth = tilted_box_room()
    return cloud, truth, preprocess(cloud, PreprocessConfig())


# ------------------------------------------------------------------------------- whole stage


@pytest.mark.slow
def test_tilted_room_height_within_2cm(room):
    _, truth, result = room
    assert abs(result.height_m - truth.height_m) < 0.02
    assert result.height_m == pytest.approx(result.ceiling_z_m - result.floor_z_m)
    assert result.metrics["warnings"] == []


@pytest.mark.slow
def test_tilted_room_residual_tilt_below_0_2_deg(room):
    _, truth, result = room
    assert residual_tilt_deg(result.levelling, truth) < 0.2
    assert result.metrics["level_tilt_deg"] == pytest.approx(3.0, abs=0.2)
    rotation = result.levelling[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)


@pytest.mark.slow
def test_tilted_room_outliers_gone(room):
    cloud, truth, result = room
    injected_far = int(truth.far_outliers.sum())
    assert injected_far > 0.01 * len(cloud)  # most of the 2 % are far from every surface
    distance = surface_distance(to_room_frame(result.cloud.points, result.levelling, truth), truth.boxes)
    assert int((distance > FAR_M).sum()) == 0
    assert np.percentile(distance, 99) < 0.01  # and the rest sits on the surfaces


@pytest.mark.slow
def test_outlier_filter_removes_the_far_voxels(room):
    """The filter itself, before MLS could pull anything onto a surface: far voxels in, none out."""
    cloud, truth, _ = room
    voxels, _ = voxel_grid(cloud, 0.02)
    room_frame = (voxels.points - truth.room_to_input[:3, 3]) @ truth.room_to_input[:3, :3]
    far = surface_distance(room_frame, truth.boxes) > FAR_M
    keep, stats = statistical_outliers(voxels.points, 20, 1.0)
    assert far.sum() > 5000
    assert int((far & keep).sum()) == 0
    assert stats["outlier_threshold_m"] == pytest.approx(
        stats["outlier_knn_mean_m"] + stats["outlier_knn_std_m"]
    )


@pytest.mark.slow
def test_tilted_room_frame_and_heights(room):
    """Rotation about the cleaned cloud's centroid: that point stays, x-y stay near the input's, and the
    floor keeps its input height (about -1.3 m here), not moved to z = 0."""
    _, truth, result = room
    pivot = np.array(result.metrics["levelling_pivot_m"])
    np.testing.assert_allclose(result.levelling[:3, :3] @ pivot + result.levelling[:3, 3], pivot, atol=1e-9)
    full = result.levelling @ truth.room_to_input
    centre = np.array([2.5, 2.0, 0.0])  # middle of the floor, room frame
    assert result.floor_z_m == pytest.approx((full[:3, :3] @ centre + full[:3, 3])[2], abs=0.01)
    assert result.floor_z_m == pytest.approx(-1.3, abs=0.1)
    assert result.ceiling_z_m == pytest.approx(result.floor_z_m + 2.70, abs=0.02)


@pytest.mark.slow
def test_tilted_room_slice_and_outputs(room):
    cloud, truth, result = room
    z = result.slice.points[:, 2]
    assert z.min() >= result.floor_z_m + 1.5 - 1e-9
    assert z.max() <= result.floor_z_m + 2.5 + 1e-9
    room_frame = to_room_frame(result.slice.points, result.levelling, truth)
    cabinet_top = (np.abs(room_frame[:, 2] - 1.95) < 0.02) & (room_frame[:, 0] > 4.6)
    assert cabinet_top.sum() > 100  # a 1.95 m cabinet reaches into the slice; the table does not
    assert not (np.abs(room_frame[:, 2] - 0.75) < 0.1).any()
    assert result.cloud.colors is not None and result.cloud.colors.dtype == np.uint8
    assert result.slice.colors.shape == result.slice.points.shape
    edges, counts = result.histogram
    assert len(edges) == len(counts) + 1 and np.allclose(np.diff(edges), 0.02)
    assert counts.sum() == pytest.approx(len(result.cloud), rel=0.01)
    picture = result.histogram_png
    assert picture.dtype == np.uint8 and picture.ndim == 3 and picture.shape[2] == 3
    for rgb in ((30, 80, 220), (220, 40, 40), (205, 235, 205)):  # floor, ceiling, slice marked
        assert (picture == rgb).all(axis=2).sum() > 100
    m = result.metrics
    assert m["points_in"] == len(cloud) and m["points_out"] == len(result.cloud)
    assert m["points_after_outliers"] == m["points_after_voxel"] - m["outliers_removed"]
    assert set(m["timings_s"]) >= {"voxel", "outliers", "mls", "level", "histogram", "slice", "total"}
    assert set(m["cpu_timings_s"]) == set(m["timings_s"])  # CPU seconds beside wall seconds, per step
    json.dumps(m)  # the manifest takes it as it is


@pytest.mark.slow
def test_room_without_ceiling_falls_back_with_a_warning():
    cloud, truth = tilted_box_room(200_000, seed=3, floor_fraction=0.3, ceiling_fraction=0.0)
    result = preprocess(cloud, PreprocessConfig())
    assert residual_tilt_deg(result.levelling, truth) < 0.2
    assert any("no ceiling" in w for w in result.metrics["warnings"])
    assert abs(result.height_m - truth.height_m) < 0.03


# ------------------------------------------------------------------------------- steps


def test_voxel_grid_centroids_and_colours():
    points = np.array(
        [
            [0.01, 0.02, 0.03],
            [0.05, 0.06, 0.07],  # same 0.1 m voxel as the first
            [0.101, 0.02, 0.03],  # next voxel in x: the grid is anchored at 0, not at the cloud
            [-0.05, -0.05, -0.05],  # voxel (-1, -1, -1)
        ]
    )
    colors = np.array([[10, 20, 30], [20, 40, 51], [7, 7, 7], [1, 2, 3]], np.uint8)
    out, counts = voxel_grid(Cloud(points, colors), 0.1)
    got = {
        tuple(np.round(p, 9)): (tuple(c), n) for p, c, n in zip(out.points, out.colors, counts, strict=True)
    }
    assert got == {
        (0.03, 0.04, 0.05): ((15, 30, 40), 2),  # 40.5 rounds to even
        (0.101, 0.02, 0.03): ((7, 7, 7), 1),
        (-0.05, -0.05, -0.05): ((1, 2, 3), 1),
    }
    assert voxel_grid(Cloud(points), 0.1)[0].colors is None


def test_voxel_grid_ranks_cells_as_a_sort_does_on_the_dense_and_the_hashed_path(rng, monkeypatch):
    # the occupancy-grid ranking must give np.unique's order and inverse exactly, and so the same cloud
    keys = rng.integers(0, 5000, size=20000)
    uniq, want = np.unique(keys, return_inverse=True)
    for extent in (5000, filters._DENSE_CELLS + 1):  # the occupancy grid, then hashing
        inverse, cells = filters._dense_ranks(keys, extent)
        assert cells == len(uniq) and np.array_equal(inverse, want.ravel())
    points = rng.uniform(-1, 3, size=(30000, 3))
    dense = voxel_grid(Cloud(points), 0.05)
    monkeypatch.setattr(filters, "_DENSE_CELLS", 0)  # every grid hashed
    hashed = voxel_grid(Cloud(points), 0.05)
    assert np.array_equal(dense[0].points, hashed[0].points) and np.array_equal(dense[1], hashed[1])


def test_plane_eigen_is_eigh_for_plane_fits_and_degenerate_ones(rng):
    m = 2000
    rot = np.linalg.qr(rng.normal(size=(m, 3, 3)))[0]
    lam = np.stack([rng.uniform(1e-8, 1e-5, m), rng.uniform(1e-3, 3e-3, m), rng.uniform(1e-3, 3e-3, m)], 1)
    cov = rot @ (lam[:, :, None] * rot.transpose(0, 2, 1))
    cov[:5] = np.eye(3) * 1e-3  # isotropic: no defined normal, handed to eigh
    cov[5:10] = np.diag([0.0, 0.0, 1e-3])  # a line: the two smallest coincide
    smallest, normal = filters._plane_eigen(cov)
    evals, evecs = np.linalg.eigh(cov)
    assert np.allclose(smallest, evals[:, 0], rtol=0, atol=1e-15)
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    planes = slice(10, None)
    # the same normal up to sign, and an eigenvector of the smallest eigenvalue everywhere
    assert np.allclose(np.abs(np.einsum("mi,mi->m", normal, evecs[:, :, 0]))[planes], 1.0, atol=1e-12)
    residual = np.einsum("mij,mj->mi", cov, normal) - smallest[:, None] * normal
    assert np.abs(residual).max() < 1e-15


def test_outlier_filter_is_eq_5_1(rng):
    """Mean distance to the 20 nearest other points; removed above μ + 1σ (one-tailed), μ and σ those of
    the mean distances after 3σ clipping: checked against a brute-force computation."""
    points = rng.normal(size=(1500, 3))
    keep, stats = statistical_outliers(points, 20, 1.0)
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    mean_knn = np.sort(d, axis=1)[:, 1:21].mean(axis=1)
    assert stats["outlier_knn_mean_unclipped_m"] == pytest.approx(mean_knn.mean(), rel=1e-12)
    inlier = np.ones(len(points), bool)
    while True:
        mu, sigma = mean_knn[inlier].mean(), mean_knn[inlier].std(ddof=1)
        if np.array_equal(inlier, mean_knn <= mu + 3 * sigma):
            break
        inlier = mean_knn <= mu + 3 * sigma
    assert inlier.sum() < len(points)  # the blob's sparse fringe is clipped
    assert stats["outlier_threshold_m"] == pytest.approx(mu + sigma, rel=1e-12)
    np.testing.assert_array_equal(keep, mean_knn <= mu + sigma)
    keep2, stats2 = statistical_outliers(points, 20, 2.0)
    assert stats2["outlier_threshold_m"] == pytest.approx(mu + 2 * sigma, rel=1e-12)
    assert keep2.sum() > keep.sum()


def _plane_with_scattered_points(rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A dense 2 m plane (20 000 points), then points scattered in a 4 m cube off it and 30 points 50-100 m
    away. Returns (plane, all points, plane first)."""
    plane = np.c_[rng.random((20000, 2)) * 2, rng.normal(0, 0.002, 20000)]
    scattered = rng.uniform(-2, 2, (300, 3)) + np.array([1.0, 1.0, 0.0])
    scattered = scattered[np.abs(scattered[:, 2]) > 0.2]
    far = rng.normal(size=(30, 3))
    far = far / np.linalg.norm(far, axis=1, keepdims=True) * rng.uniform(50, 100, (30, 1))
    points = np.concatenate([plane, scattered, far])
    return plane, points


def test_outlier_filter_on_plane_with_scattered_points(rng):
    """A dense plane (mean-distance statistic near Gaussian) plus 300 points scattered in a 4 m cube and
    30 points 50-100 m away: every scattered point goes, and about the one-tailed 1σ share (15.9 %) of
    the plane."""
    plane, points = _plane_with_scattered_points(rng)
    keep, _ = statistical_outliers(points, 20, 1.0)
    assert not keep[len(plane) :].any()
    removed_share = 1 - keep[: len(plane)].mean()
    assert 0.08 < removed_share < 0.22


def _range_sampled_wall(step_near: float = 0.02, step_far: float = 0.10) -> NDArray[np.float64]:
    """A 6 m x 1 m wall sampled like a range sensor's far surface: the spacing, along it and up, grows
    linearly from step_near at x = 0 to step_far at x = 6 (a fixed angular step seen from ever farther)."""
    columns, x = [], 0.0
    while x < 6.0:
        step = step_near + (step_far - step_near) * x / 6.0
        z = np.arange(0.0, 1.0, step)
        columns.append(np.column_stack([np.full(len(z), x), np.zeros(len(z)), z]))
        x += step
    return np.concatenate(columns)


def test_density_aware_outlier_filter_keeps_a_sparse_far_surface(rng):
    """A wall whose sampling thins out from 2 cm to 10 cm (a range sensor's far wall) with isolated points
    0.1-0.5 m off it and a loose cloud of 300 points metres away: the local test keeps the far part of the
    wall and removes every isolated and far point; eq 5.1's global test removes the far part. (Either
    test trims some of the wall's top and bottom rows: a border of a regular grid has r ~ 1.3.)"""
    wall = _range_sampled_wall()
    wall = wall + rng.normal(0, 0.002, wall.shape)
    base = wall[rng.choice(len(wall), 200, replace=False)]
    isolated = base + np.column_stack(
        [np.zeros(200), rng.choice([-1, 1], 200) * rng.uniform(0.1, 0.5, 200), np.zeros(200)]
    )
    far = rng.uniform(-5, 5, (300, 3)) + np.array([3.0, 12.0, 0.0])
    points = np.concatenate([wall, isolated, far])
    n = len(wall)
    x, z = wall[:, 0], wall[:, 2]
    far_part = (x > 4.5) & (x < 5.8) & (z > 0.2) & (z < 0.8)  # 7-10 cm spacing, away from the borders
    near_part = (x > 0.2) & (x < 1.5) & (z > 0.2) & (z < 0.8)
    for ratio in (1.0, 2.0):
        keep, stats = statistical_outliers(points, 20, ratio, "local")
        assert keep[:n][far_part].mean() > 0.95 and keep[:n][near_part].mean() > 0.9, (ratio, stats)
        assert not keep[n:].any(), (ratio, int(keep[n : n + 200].sum()), int(keep[n + 200 :].sum()))
        assert stats["outlier_sparse_kept"] > 0  # the far part fails the global test but stays
        global_keep, _ = statistical_outliers(points, 20, ratio, "global")
        assert global_keep[:n][far_part].mean() < 0.1


def test_density_aware_outlier_filter_on_plane_with_scattered_points(rng):
    """The global test's case: a dense plane, points scattered in a 4 m cube and 30 points 50-100 m away.
    The local test removes every scattered point too, and at 2σ keeps nearly all of the plane."""
    plane, points = _plane_with_scattered_points(rng)
    keep, stats = statistical_outliers(points, 20, 2.0, "local")
    assert not keep[len(plane) :].any()
    assert keep[: len(plane)].mean() > 0.9
    assert stats["outlier_reference"] == "local"
    with pytest.raises(ValueError, match="reference"):
        statistical_outliers(points, 20, 2.0, "nearby")  # type: ignore[arg-type]


def test_outlier_search_is_the_same_whatever_its_bound_threads_and_chunks(rng, monkeypatch):
    """The K-NN search is bounded (a row left short is searched again) and shared among threads in fixed
    chunks: no bound, a bound that leaves every row short, one that leaves none, one thread or two and
    smaller chunks give the same keep-mask and statistics; and the global statistic is the mean distance
    to the K nearest, written out."""
    wall = _range_sampled_wall() + rng.normal(0, 0.002, (len(_range_sampled_wall()), 3))
    points = np.concatenate([wall, rng.uniform(-5, 5, (300, 3)) + np.array([3.0, 12.0, 0.0])])
    results = []
    for ratio, threads, entries in (
        (np.inf, 1, 1_000_000),
        (1e-6, 2, 1_000_000),
        (1e6, 2, 20_000),
        (1.5, 3, 7_000),
    ):
        monkeypatch.setattr(filters, "_BOUND_RATIO", ratio)
        monkeypatch.setattr(filters, "_THREADS", threads)
        monkeypatch.setattr(filters, "_CHUNK_ENTRIES", entries)
        results.append(statistical_outliers(points, 20, 2.0, "local"))
    for keep, stats in results[1:]:
        assert np.array_equal(keep, results[0][0]) and stats == results[0][1]
    d = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=2))
    mean_dist = np.sort(d, axis=1)[:, 1:21].mean(axis=1)
    assert results[0][1]["outlier_knn_mean_unclipped_m"] == pytest.approx(mean_dist.mean(), rel=1e-12)


def _noisy_plane(rng, n=60_000, sigma=0.005, size=3.0):
    normal = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])
    xy = rng.random((n, 2)) * size
    z = 1.0 - (normal[0] * xy[:, 0] + normal[1] * xy[:, 1]) / normal[2]
    points = np.c_[xy, z] + normal * rng.normal(0, sigma, (n, 1))
    return points, normal


def _plane_distance(points, normal):
    return (points - [0, 0, 1.0]) @ normal


def test_mls_reduces_noise_on_a_plane_and_keeps_it(rng):
    points, normal = _noisy_plane(rng)
    inner = np.all((points[:, :2] > 0.2) & (points[:, :2] < 2.8), axis=1)  # away from the free border
    before = _plane_distance(points, normal)
    for degree, factor in ((1, 5.0), (2, 4.0)):
        result = mls_smooth(points, 0.10, degree)
        after = _plane_distance(result.points, normal)
        rms_before, rms_after = np.sqrt(np.mean(before[inner] ** 2)), np.sqrt(np.mean(after[inner] ** 2))
        assert rms_before / rms_after > factor, (degree, rms_before, rms_after)
        assert abs(after[inner].mean()) < 2e-4  # the plane does not move
        # points move across the plane, hardly along it (only as far as the local normal is off)
        step = result.points - points
        across = step @ normal
        along = np.linalg.norm(step - across[:, None] * normal, axis=1)
        assert np.sqrt(np.mean(along**2)) < 0.05 * np.sqrt(np.mean(across**2))
        off = np.degrees(np.arccos(np.minimum(np.abs(result.normals[inner] @ normal), 1)))
        assert off.mean() < 1.0 and np.percentile(off, 99) < 2.5
        assert np.nanmax(result.curvature[inner]) < 0.01


def test_mls_support_grid_matches_the_full_neighbourhood_fit(rng):
    """The support-cell shortcut against the textbook fit (every point within r, Gaussian weights)."""
    points, normal = _noisy_plane(rng, n=30_000, sigma=0.005, size=2.0)
    result = mls_smooth(points, 0.10, 1)
    tree = cKDTree(points)
    probe = rng.choice(np.flatnonzero(np.all((points[:, :2] > 0.3) & (points[:, :2] < 1.7), axis=1)), 300)
    exact = []
    for i in probe:
        nb = points[tree.query_ball_point(points[i], 0.10)]
        w = np.exp(-np.sum((nb - points[i]) ** 2, axis=1) / 0.10**2)
        mean = (w[:, None] * nb).sum(0) / w.sum()
        cov = ((nb - mean) * w[:, None]).T @ (nb - mean)
        n = np.linalg.eigh(cov)[1][:, 0]
        exact.append(points[i] - ((points[i] - mean) @ n) * n)
    diff = np.linalg.norm(result.points[probe] - np.array(exact), axis=1)
    noise_removed = np.abs(_plane_distance(points[probe], normal)).mean()
    assert diff.mean() < 0.1 * noise_removed and diff.max() < 1e-3


def test_mls_is_the_same_bytes_whatever_the_threads_and_chunks_and_is_the_direct_fit(rng, monkeypatch):
    """The fits are shared among threads in fixed chunks: one thread or two, the same bytes; smaller
    chunks change nothing either; and each fit is the weighted plane fit written out per point."""
    points, _ = _noisy_plane(rng, n=6_000, sigma=0.004, size=1.0)
    points = np.concatenate([points, rng.uniform(0, 1, (300, 3))])  # a few points with a loose support
    weights = rng.integers(1, 6, len(points)).astype(np.float64)
    results = []
    for threads, entries in ((1, 1_000_000), (2, 1_000_000), (2, 20_000), (3, 7_000)):
        monkeypatch.setattr(filters, "_THREADS", threads)
        monkeypatch.setattr(filters, "_CHUNK_ENTRIES", entries)
        results.append(mls_smooth(points, 0.10, 1, 10.0, weights))
    for other in results[1:]:
        for name in ("points", "normals", "curvature", "edge"):
            assert np.array_equal(getattr(other, name), getattr(results[0], name), equal_nan=True), name
        assert other.stats == results[0].stats
    # the direct fit on the same support cells (cell centroids, their total weights, the 64 nearest in r)
    result = results[0]
    local = points - points.mean(axis=0)
    support, totals, _ = filters._cell_centroids(local, 0.10 / 3, weights=weights)
    tree = cKDTree(support)
    for i in rng.choice(np.flatnonzero(~result.edge), 50, replace=False):
        dist, idx = tree.query(local[i], k=64, distance_upper_bound=0.10)
        idx = idx[np.isfinite(dist)]
        w = totals[idx] * np.exp(-np.sum((support[idx] - local[i]) ** 2, axis=1) / 0.10**2)
        mean = (w[:, None] * support[idx]).sum(0) / w.sum()
        cov = ((support[idx] - mean) * w[:, None]).T @ (support[idx] - mean) / w.sum()
        evals, evecs = np.linalg.eigh(cov)
        n = evecs[:, 0]
        assert abs(abs(result.normals[i] @ n) - 1) < 1e-9
        assert np.allclose(result.points[i], points[i] - ((local[i] - mean) @ n) * n, atol=1e-12)
        assert result.curvature[i] == pytest.approx(evals[0] / evals.sum(), rel=1e-6, abs=1e-12)


def test_row_median_is_numpys(rng):
    for k in (1, 2, 5, 20, 21):
        values = rng.random((500, k))
        assert np.array_equal(filters._row_median(values), np.median(values, axis=1))


def test_mls_with_voxel_counts_sees_the_raw_surface(rng):
    """Voxel centroids of a dense, noisy, tilted plane form terraces along the grid (a voxel holding a few
    points of the noise's tail counts as much as a full one). Fitting with the voxel counts as weights
    recovers the raw points' moments: the true orientation and a flat surface; without, the terraces stay."""
    n, tilt = 400_000, math.radians(3.0)
    normal = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    xy = rng.random((n, 2)) * 1.5
    points = np.c_[xy, -normal[0] * xy[:, 0] / normal[2]] + normal * rng.normal(0, 0.005, (n, 1))
    voxels, counts = voxel_grid(Cloud(points), 0.02)
    inner = np.all((voxels.points[:, :2] > 0.2) & (voxels.points[:, :2] < 1.3), axis=1)
    found = {}
    for name, weights in (("unweighted", None), ("counts", counts)):
        fit = mls_smooth(voxels.points, 0.10, 1, 0.0, weights)
        normals = fit.normals[inner] * np.sign(fit.normals[inner, 2:3])
        mean = normals.mean(axis=0) / np.linalg.norm(normals.mean(axis=0))
        rms = np.sqrt(np.mean((fit.points[inner] @ normal) ** 2))
        found[name] = (math.degrees(math.acos(mean[2])), rms)
    # measured: counts 2.992° and 0.08 mm RMS off the plane; unweighted 3.041° and 1.3 mm
    assert found["counts"][0] == pytest.approx(3.0, abs=0.02)
    assert found["counts"][1] < 0.0003
    assert found["unweighted"][1] > 5 * found["counts"][1]


def test_mls_quadratic_keeps_a_curved_surface(rng):
    """On a 0.5 m sphere the plane fit flattens (moves points inwards); the quadratic does not."""
    d = rng.normal(size=(40_000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = d * (0.5 + rng.normal(0, 0.002, (len(d), 1)))
    bias = {}
    for degree in (1, 2):
        r = np.linalg.norm(mls_smooth(points, 0.10, degree).points, axis=1) - 0.5
        bias[degree] = r.mean()
        assert r.std() < 0.002
    assert bias[1] < -0.002  # pulled towards the centre by about r²/(4R)
    assert abs(bias[2]) < 0.2 * abs(bias[1])


def _tilted_normals(rng, tilt: Rotation, horizontal=20000, walls=(15000, 10000), noise_deg=0.5):
    """Unit normals of floor/ceiling (random sign) and of two walls at 90°, tilted."""
    up = np.tile([0, 0, 1.0], (horizontal, 1)) * rng.choice([-1, 1], (horizontal, 1))
    wall_a = np.tile([1.0, 0, 0], (walls[0], 1))
    wall_b = np.tile([0, 1.0, 0], (walls[1], 1))
    normals = np.concatenate([up, wall_a, wall_b]) + rng.normal(
        0, math.radians(noise_deg), (sum(walls) + horizontal, 3)
    )
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return tilt.apply(normals)


@pytest.mark.parametrize("mode", ["horizontal", "vertical", "both"])
@pytest.mark.parametrize("tilt_deg", [3.0, 30.0])
def test_levelling_recovers_a_known_tilt(rng, mode, tilt_deg):
    tilt = Rotation.from_rotvec(
        math.radians(tilt_deg) * np.array([1.0, 2.0, 0.3]) / np.linalg.norm([1.0, 2.0, 0.3])
    )
    normals = _tilted_normals(rng, tilt)
    cfg = PreprocessConfig(level_normals=mode)
    rotation, stats = level_by_normals(normals, cfg)
    true_up = tilt.apply([0, 0, 1.0])
    up = rotation @ true_up
    assert math.degrees(math.acos(min(1.0, up[2]))) < 0.02
    true_tilt = math.degrees(math.acos(true_up[2]))  # a little under tilt_deg: the axis is not horizontal
    assert stats["level_tilt_deg"] == pytest.approx(true_tilt, abs=0.02)
    assert stats["level_converged"]
    assert stats["level_tilt_per_iteration_deg"][0] == pytest.approx(true_tilt, abs=0.02)


@pytest.mark.parametrize("mode", ["horizontal", "vertical", "both"])
def test_levelling_is_the_matrix_form_of_eq_5_4(rng, mode):
    """The column-wise sums give the up vector of Σ_h n nᵀ + Σ_v (I - n nᵀ) written with matrices."""
    normals = _tilted_normals(rng, Rotation.from_rotvec([0.05, -0.03, 0.4]))
    cfg = replace(PreprocessConfig(), level_normals=mode, level_max_iterations=1)
    rotation, _ = level_by_normals(normals, cfg)
    horizontal = np.abs(normals[:, 2]) >= math.cos(math.radians(cfg.level_split_deg))
    h, v = normals[horizontal], normals[~horizontal]
    scatter = {"horizontal": h.T @ h, "vertical": len(v) * np.eye(3) - v.T @ v}
    scatter["both"] = scatter["horizontal"] + scatter["vertical"]
    up = np.linalg.eigh(scatter[mode])[1][:, 2]
    assert abs(abs(rotation[2] @ up) - 1) < 1e-12


def test_levelling_of_a_single_wall_is_an_error(rng):
    normals = _tilted_normals(rng, Rotation.identity(), horizontal=0, walls=(5000, 0))
    with pytest.raises(DegenerateInputError, match="ill-determined"):
        level_by_normals(normals, PreprocessConfig())


def _heights(rng, floor=0.3071, ceiling=2.8437, floor_area=10.0, ceiling_area=1.0, bin_m=0.02):
    """Heights of a voxelized room: a floor and a ceiling of given areas (one point per bin² of area),
    walls (1000 points per bin between them), a 2 m² table top at floor + 0.75 m."""
    per_m2 = 1 / bin_m**2
    parts = [
        floor + rng.normal(0, 0.002, int(floor_area * per_m2)),
        ceiling + rng.normal(0, 0.002, int(ceiling_area * per_m2)),
        rng.uniform(floor, ceiling, int(1000 * (ceiling - floor) / bin_m)),
        floor + 0.75 + rng.normal(0, 0.002, int(2.0 * per_m2)),
    ]
    return np.concatenate(parts)


def test_histogram_peaks_give_floor_and_ceiling(rng):
    cfg = PreprocessConfig()
    z = _heights(rng)
    hist, sums = height_histogram(z, cfg.voxel_size_m)
    assert np.allclose(np.diff(hist.edges_m), 0.02) and hist.counts.sum() <= len(z)
    assert np.allclose(hist.edges_m / 0.02, np.round(hist.edges_m / 0.02))  # bins on multiples of the size
    warnings: list[str] = []
    floor, ceiling, stats = floor_and_ceiling(hist, sums, cfg, warnings)
    assert floor == pytest.approx(0.3071, abs=0.002)  # sub-bin: the bin is 2 cm
    assert ceiling == pytest.approx(2.8437, abs=0.002)  # 1 m² of ceiling is enough
    assert warnings == []
    assert len(stats["histogram_peaks_z_m"]) == 3  # floor, table, ceiling


def test_histogram_without_ceiling_warns_and_falls_back(rng):
    cfg = PreprocessConfig()
    z = _heights(rng, ceiling_area=0.0)
    hist, sums = height_histogram(z, cfg.voxel_size_m)
    warnings: list[str] = []
    floor, ceiling, _ = floor_and_ceiling(hist, sums, cfg, warnings)
    assert floor == pytest.approx(0.3071, abs=0.002)
    assert ceiling == pytest.approx(2.8437, abs=0.03)
    assert len(warnings) == 1 and "no ceiling" in warnings[0]


def test_histogram_without_floor_or_ceiling_falls_back_to_the_walls_ends(rng):
    """Walls and a table top only (a handheld scan's floor seen too sparsely to make a peak, cut below the
    ceiling): the walls still show, so floor and ceiling are the walls' bottom and top, each with a
    warning, instead of a refusal."""
    cfg = PreprocessConfig()
    z = _heights(rng, floor_area=0.0, ceiling_area=0.0)
    z = z[(z > 0.5) & (z < 2.6) | (np.abs(z - 1.0571) < 0.01)]  # walls and the table top only
    hist, sums = height_histogram(z, cfg.voxel_size_m)
    warnings: list[str] = []
    floor, ceiling, stats = floor_and_ceiling(hist, sums, cfg, warnings)
    assert floor == pytest.approx(0.5, abs=0.02) and ceiling == pytest.approx(2.6, abs=0.02)
    assert not stats["floor_captured"] and not stats["ceiling_captured"]
    assert len(warnings) == 2 and "no floor" in warnings[0] and "no ceiling" in warnings[1]


# ------------------------------------------------------------------------------- bad input


def _plane_cloud(rng, vertical: bool) -> Cloud:
    uv = rng.random((20_000, 2)) * 3
    noise = rng.normal(0, 0.003, 20_000)
    pts = np.c_[uv[:, 0], noise, uv[:, 1]] if vertical else np.c_[uv, noise]
    return Cloud(pts)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda rng: Cloud(np.zeros((0, 3))), "0 points"),
        (lambda rng: Cloud(np.r_[rng.random((1000, 3)), [[np.nan, 0, 0]]]), "NaN"),
        (lambda rng: Cloud(rng.random((10, 3))), "10 points"),
        (lambda rng: _plane_cloud(rng, vertical=False), "single plane"),
        (lambda rng: _plane_cloud(rng, vertical=True), "ill-determined"),
    ],
    ids=["empty", "nan", "ten-points", "floor-only", "wall-only"],
)
def test_degenerate_input_gives_one_clear_line(rng, make, message):
    with pytest.raises(DegenerateInputError, match=message) as info:
        preprocess(make(rng), PreprocessConfig())
    assert "\n" not in str(info.value)


def test_config_rejects_impossible_values():
    with pytest.raises(ValueError, match="mls_radius_m"):
        PreprocessConfig(voxel_size_m=0.2, mls_radius_m=0.1)
    with pytest.raises(ValueError, match="slice_min_m"):
        PreprocessConfig(slice_min_m=2.6)
    assert replace(PreprocessConfig(), voxel_size_m=0.03).voxel_size_m == 0.03
