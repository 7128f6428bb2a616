"""The wall stage's faster image steps give the numbers of their plain forms (issue #18: speed with the same
wall models)."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.distance import cdist

from tasks.walls.config import WallsConfig
from tasks.walls.image import binarize, projection_image
from tasks.walls.model import point_spacing


def test_binarize_alpha_is_the_whole_image_formula() -> None:
    """Eq 5.5 on the wall-like cells only: the same cells as the gray image computed everywhere, for
    integer counts (a projection) and fractional ones, at every α."""
    rng = np.random.default_rng(3)
    cfg = WallsConfig()
    for counts in (rng.integers(0, 97, (60, 80)).astype(np.float64), rng.random((60, 80)) * 13.7):
        wall_like = rng.random(counts.shape) < 0.3
        for alpha in (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.97):
            gray = counts / counts.max() * cfg.gray_levels
            expected = (gray >= alpha * cfg.gray_levels) & wall_like
            got = binarize(counts, wall_like, cfg, alpha)
            assert got.dtype == np.bool_ and got.shape == counts.shape
            assert np.array_equal(got, expected), alpha
    assert not binarize(np.zeros((4, 5)), np.ones((4, 5), bool), cfg, 0.1).any()


def test_projection_grid_spans_the_points_with_two_empty_cells() -> None:
    """The raster's origin is the points' x and y minimum less two cells, and every point lands in a cell
    holding its count of occupied voxels."""
    rng = np.random.default_rng(5)
    pts = np.column_stack(
        [rng.uniform(-3.2, 1.7, 5000), rng.uniform(0.4, 2.9, 5000), rng.uniform(1.5, 2.5, 5000)]
    )
    cfg = WallsConfig(grid_size_m=0.05, top_reach_m=None)
    proj = projection_image(pts, cfg)
    g = cfg.grid_size_m
    assert np.array_equal(proj.grid.origin, pts[:, :2].min(axis=0) - 2 * g)
    hi = pts[:, :2].max(axis=0) + 2 * g
    assert proj.grid.shape == (
        math.ceil((hi[1] - proj.grid.origin[1]) / g),
        math.ceil((hi[0] - proj.grid.origin[0]) / g),
    )
    assert (proj.counts.ravel()[proj.cell] >= 1).all()
    assert proj.counts.sum() == len(
        np.unique(np.column_stack([proj.cell, np.floor((pts[:, 2] - pts[:, 2].min()) / g)]), axis=0)
    )


def test_point_spacing_is_the_brute_force_median() -> None:
    """The k-th neighbour distances from the leaf-ordered query are the brute-force ones: the spacing is
    the same number, for a sample of every point and of every step-th one."""
    rng = np.random.default_rng(7)
    # two noisy walls and some clutter, 3 000 points
    a = np.column_stack([rng.uniform(0, 3, 1500), rng.normal(0, 0.004, 1500), rng.uniform(1.5, 2.5, 1500)])
    b = np.column_stack([rng.normal(3, 0.004, 1200), rng.uniform(0, 2, 1200), rng.uniform(1.5, 2.5, 1200)])
    c = rng.uniform((0, 0, 1.5), (3, 2, 2.5), (300, 3))
    pts = np.concatenate([a, b, c])
    for k, max_points in ((6, 20000), (6, 700), (4, 1000)):
        step = max(1, len(pts) // max_points)
        d = np.sort(cdist(pts[::step], pts), axis=1)[:, k]
        assert point_spacing(pts, k=k, max_points=max_points) == float(np.median(d) * math.sqrt(math.pi / k))
    # a regular grid of 1 cm: about 1 cm
    g = np.stack(np.meshgrid(np.arange(100), np.arange(60), indexing="ij"), -1).reshape(-1, 2) * 0.01
    grid = np.column_stack([g, np.zeros(len(g))])
    assert 0.009 < point_spacing(grid) < 0.012
