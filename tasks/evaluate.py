"""Wall-model metrics with PIPELINE.md's definitions (ISPRS indoor-modelling benchmark style).

`evaluate_walls(pred, truth)` is pure: segments in, numbers out. Definitions:
- truth walls are sampled every `step_m` (1 cm); **completeness** is the share of those samples within
  `tol_m` (0.10 m) of a predicted wall; **correctness** the share of the predicted walls' samples within
  `tol_m` of a truth wall; **accuracy** the median (the ISPRS figure), mean and RMS distance of the truth
  samples lying within `tol_m`;
- **corners** are the points where two or more non-collinear walls meet (free wall ends are not corners);
  predicted and true corners are matched one-to-one within `corner_tol_m` (0.10 m) for precision, recall
  and F1;
- **angle error**: every truth wall is matched to the predicted wall nearest to most of its samples
  within `tol_m`; the mean absolute difference of their orientations (degrees);
- **room IoU**: rooms are the faces enclosed by the walls (shapely polygonize after noding; faces that
  fill a hole of another face, e.g. a free-standing column, are not rooms) unless given; each truth room
  takes its best intersection-over-union among the predicted rooms, and the mean is reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from tasks.lines import angle_difference, angles, as_segments, room_polygons, sample_segments, wall_graph


def _nearest(points: NDArray, segments: NDArray, chunk: int = 4096) -> tuple[NDArray, NDArray]:
    """Distance of every point to the nearest segment and that segment's index."""
    dist = np.full(len(points), np.inf)
    idx = np.full(len(points), -1, dtype=np.intp)
    if len(segments) == 0:
        return dist, idx
    a = segments[None, :, :2]
    d = segments[None, :, 2:] - a
    dd = np.maximum((d**2).sum(-1), 1e-300)
    for s in range(0, len(points), chunk):
        p = points[s : s + chunk, None, :]
        t = np.clip(((p - a) * d).sum(-1) / dd, 0.0, 1.0)
        r = np.hypot(*(p - (a + t[..., None] * d)).transpose(2, 0, 1))
        idx[s : s + chunk] = np.argmin(r, axis=1)
        dist[s : s + chunk] = r[np.arange(len(r)), idx[s : s + chunk]]
    return dist, idx


def wall_corners(segments: NDArray, min_angle_deg: float = 10.0, snap_m: float = 1e-3) -> NDArray[np.float64]:
    """(C, 2) points where two or more walls meet at more than `min_angle_deg`."""
    g = wall_graph(as_segments(segments), tol=snap_m)
    out = []
    for node, deg in g.degree():
        if deg < 2:
            continue
        th = [float(angles(data["segment"][None])[0]) for _, _, data in g.edges(node, data=True)]
        if max(abs(float(angle_difference(a, th[0]))) for a in th) >= np.radians(min_angle_deg):
            out.append(g.nodes[node]["xy"])
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def rooms(segments: NDArray) -> list:
    """The faces enclosed by the walls that are rooms (not the inside of a free-standing column)."""
    from shapely.geometry import Polygon

    faces = room_polygons(as_segments(segments))
    keep = []
    for f in faces:
        p = f.representative_point()
        in_hole = any(
            g is not f and len(g.interiors) and Polygon(g.exterior).contains(p) and not g.contains(p)
            for g in faces
        )
        if not in_hole:
            keep.append(f)
    return keep


def _f1(p: float, r: float) -> float:
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def evaluate_walls(
    pred: NDArray,
    truth: NDArray,
    tol_m: float = 0.10,
    *,
    corner_tol_m: float = 0.10,
    step_m: float = 0.01,
    pred_rooms: Sequence | None = None,
    truth_rooms: Sequence | None = None,
) -> dict[str, Any]:
    """Metrics of predicted walls (M, 4) against truth walls (K, 4), both in metres in one frame."""
    pred, truth = as_segments(pred), as_segments(truth)
    tp, _ = sample_segments(truth, step_m)
    pp, _ = sample_segments(pred, step_m)
    d_truth, near_pred = _nearest(tp, pred)
    d_pred, _ = _nearest(pp, truth)
    within = d_truth <= tol_m
    acc = d_truth[within]
    out: dict[str, Any] = {
        "completeness": float(within.mean()) if len(tp) else 0.0,
        "correctness": float((d_pred <= tol_m).mean()) if len(pp) else 0.0,
        "accuracy_median_m": float(np.median(acc)) if len(acc) else float("nan"),
        "accuracy_mean_m": float(acc.mean()) if len(acc) else float("nan"),
        "accuracy_rms_m": float(np.sqrt((acc**2).mean())) if len(acc) else float("nan"),
    }

    cp, ct = wall_corners(pred), wall_corners(truth)
    matched = 0
    if len(cp) and len(ct):
        dist = np.hypot(*(cp[:, None, :] - ct[None, :, :]).transpose(2, 0, 1))
        cost = np.where(dist <= corner_tol_m, dist, 1e6)
        r, c = linear_sum_assignment(cost)
        matched = int((cost[r, c] <= corner_tol_m).sum())
    prec = matched / len(cp) if len(cp) else 0.0
    rec = matched / len(ct) if len(ct) else 0.0
    out.update(corner_precision=prec, corner_recall=rec, corner_f1=_f1(prec, rec))

    # angle error: each truth wall against the predicted wall nearest to most of its samples
    _, owner = sample_segments(truth, step_m)
    errs = []
    for k in range(len(truth)):
        m = (owner == k) & within
        if not m.any():
            continue
        j = np.bincount(near_pred[m]).argmax()
        errs.append(
            abs(float(np.degrees(angle_difference(angles(truth[k : k + 1])[0], angles(pred[j : j + 1])[0]))))
        )
    out["angle_error_deg"] = float(np.mean(errs)) if errs else float("nan")
    out["walls_matched"] = len(errs)

    pr = list(pred_rooms) if pred_rooms is not None else rooms(pred)
    tr = list(truth_rooms) if truth_rooms is not None else rooms(truth)
    ious = []
    for t in tr:
        best = 0.0
        for p in pr:
            inter = t.intersection(p).area
            if inter > 0:
                best = max(best, inter / t.union(p).area)
        ious.append(best)
    out["room_iou"] = float(np.mean(ious)) if ious else float("nan")
    out.update(
        walls_pred=len(pred),
        walls_truth=len(truth),
        length_pred_m=float(np.hypot(pred[:, 2] - pred[:, 0], pred[:, 3] - pred[:, 1]).sum()),
        length_truth_m=float(np.hypot(truth[:, 2] - truth[:, 0], truth[:, 3] - truth[:, 1]).sum()),
        corners_pred=len(cp),
        corners_truth=len(ct),
        rooms_pred=len(pr),
        rooms_truth=len(tr),
    )
    return out
