"""Comparing a parsed plan with CAD ground truth that stores walls as rectangles (MLSTRUCT-FP)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tasks import lines


def rectangle_centrelines(rects: NDArray[np.float64]) -> NDArray[np.float64]:
    """Centrelines (K, 4) of wall rectangles given as (K, 4, 2) corners in order: the segment joining the
    midpoints of the two short sides (how CAD data such as MLSTRUCT-FP store walls)."""
    p = np.asarray(rects, dtype=np.float64).reshape(-1, 4, 2)
    e01 = np.hypot(*(p[:, 1] - p[:, 0]).T)
    e12 = np.hypot(*(p[:, 2] - p[:, 1]).T)
    long01 = (e01 >= e12)[:, None]
    a = np.where(long01, (p[:, 0] + p[:, 3]) / 2, (p[:, 0] + p[:, 1]) / 2)
    b = np.where(long01, (p[:, 1] + p[:, 2]) / 2, (p[:, 2] + p[:, 3]) / 2)
    return np.concatenate([a, b], axis=1)


def thickness_errors(
    pred: NDArray, pred_thickness: NDArray, truth: NDArray, truth_thickness: NDArray, tol_m: float = 0.10
) -> NDArray[np.float64]:
    """|thickness error| (m) of every truth wall against the predicted wall nearest to most of its
    samples within tol_m (walls (M, 4) / (K, 4) metres); truth walls without a match are left out."""
    pts, owner = lines.sample_segments(lines.as_segments(truth), 0.02)
    pred = lines.as_segments(pred)
    if len(pred) == 0 or len(pts) == 0:
        return np.zeros(0)
    d = lines.point_segment_distances(pts, pred)
    near, dmin = d.argmin(axis=1), d.min(axis=1)
    errs = []
    for k in range(len(truth)):
        m = (owner == k) & (dmin <= tol_m)
        if m.sum() < 3:
            continue
        j = np.bincount(near[m]).argmax()
        errs.append(abs(float(pred_thickness[j]) - float(truth_thickness[k])))
    return np.array(errs)
