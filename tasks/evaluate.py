"""Wall-model metrics with PIPELINE.md's definitions (ISPRS indoor-modelling benchmark style).

`evaluate_walls(pred, truth)` is pure: segments in, numbers out. Definitions:
- truth walls are sampled every `step_m` (1 cm); **completeness** is the share of those samples within
  `tol_m` (0.10 m) of a predicted wall; **correctness** the share of the predicted walls' samples within
  `tol_m` of a truth wall; **accuracy** the median (the ISPRS figure), mean and RMS distance of the truth
  samples lying within `tol_m`;
- **corners** are the points where two or more non-collinear walls meet (free wall ends are not corners);
  corners closer together than `step_m` (1 cm) count as one (a jog that short, such as where the inner
  faces of walls of different thickness meet at a slanted corner, is below any capture's resolution);
  predicted and true corners are matched one-to-one within `corner_tol_m` (0.10 m) for precision, recall
  and F1;
- **angle error**: every truth wall at least `tol_m` long is matched to the predicted wall nearest to most
  of its samples within `tol_m`; the mean absolute difference of their orientations (degrees). A shorter
  wall (a jog of a few cm) lies wholly within `tol_m` of its neighbours, so its nearest predicted wall
  says nothing of its direction;
- **room IoU**: rooms are the faces enclosed by the walls (shapely polygonize after noding; faces that
  fill a hole of another face, e.g. a free-standing column, are not rooms) unless given; each truth room
  takes its best intersection-over-union among the predicted rooms, and the mean is reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
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


def merge_close(points: NDArray, tol_m: float) -> NDArray[np.float64]:
    """(C', 2) `points` with each one closer than `tol_m` to an earlier kept point dropped (in order)."""
    kept: list[NDArray] = []
    for p in np.asarray(points, dtype=np.float64).reshape(-1, 2):
        if all(np.hypot(*(p - q)) >= tol_m for q in kept):
            kept.append(p)
    return np.array(kept, dtype=np.float64).reshape(-1, 2)


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

    cp, ct = merge_close(wall_corners(pred), step_m), merge_close(wall_corners(truth), step_m)
    matched = 0
    if len(cp) and len(ct):
        dist = np.hypot(*(cp[:, None, :] - ct[None, :, :]).transpose(2, 0, 1))
        cost = np.where(dist <= corner_tol_m, dist, 1e6)
        r, c = linear_sum_assignment(cost)
        matched = int((cost[r, c] <= corner_tol_m).sum())
    prec = matched / len(cp) if len(cp) else 0.0
    rec = matched / len(ct) if len(ct) else 0.0
    out.update(corner_precision=prec, corner_recall=rec, corner_f1=_f1(prec, rec))

    # angle error: each truth wall (tol_m or longer) against the predicted wall nearest to most of its samples
    _, owner = sample_segments(truth, step_m)
    long_enough = np.hypot(truth[:, 2] - truth[:, 0], truth[:, 3] - truth[:, 1]) >= tol_m
    errs = []
    for k in np.flatnonzero(long_enough):
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


# ------------------------------------------------------------------------------- labelled points

WALL_CLASSES = ("wall",)
"""Labels of the points a model's walls should explain (completeness, accuracy)."""
STRUCTURAL_CLASSES = ("wall", "column", "door", "window")
"""Labels of the points that back a model wall (correctness): a wall line across a door is still right."""


def evaluate_walls_on_points(
    pred: NDArray,
    points_xy: NDArray,
    labels: Sequence[str] | NDArray,
    tol_m: float = 0.10,
    step_m: float = 0.01,
) -> dict[str, Any]:
    """Metrics of predicted walls (M, 4) against labelled points (a real room has no polygon truth), in
    plan view (x-y, metres, one frame):
    - completeness: the share of wall-labelled points within `tol_m` of a predicted wall;
    - correctness: the share of the predicted walls' length (samples every `step_m`) within `tol_m` of a
      structural point (wall, column, door, window);
    - accuracy: the mean and median distance of the wall points within `tol_m`."""
    from scipy.spatial import cKDTree

    pred = as_segments(pred)
    xy = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    lab = np.char.lower(np.asarray(labels, dtype=str))
    if len(lab) != len(xy):
        raise ValueError(f"{len(xy)} points but {len(lab)} labels")
    wall = xy[np.isin(lab, WALL_CLASSES)]
    structural = xy[np.isin(lab, STRUCTURAL_CLASSES)]
    d_wall, _ = _nearest(wall, pred)
    within = d_wall <= tol_m
    acc = d_wall[within]
    pp, _ = sample_segments(pred, step_m)
    if len(pp) and len(structural):
        backed = np.isfinite(cKDTree(structural).query(pp, distance_upper_bound=tol_m)[0])
    else:
        backed = np.zeros(len(pp), dtype=bool)
    return {
        "completeness": float(within.mean()) if len(wall) else float("nan"),
        "correctness": float(backed.mean()) if len(pp) else 0.0,
        "accuracy_mean_m": float(acc.mean()) if len(acc) else float("nan"),
        "accuracy_median_m": float(np.median(acc)) if len(acc) else float("nan"),
        "wall_points": len(wall),
        "structural_points": len(structural),
        "walls_pred": len(pred),
        "length_pred_m": float(np.hypot(pred[:, 2] - pred[:, 0], pred[:, 3] - pred[:, 1]).sum()),
    }


def read_labelled_points(path: Path) -> tuple[NDArray[np.float64], NDArray[np.str_]]:
    """Labelled points: ((N, 3) x y z in metres, (N,) class names). `path` is either
    - a folder of one text file per object named `<class>_<n>.txt` (rows `x y z ...`, the common indoor
      annotation layout: wall_1.txt, door_2.txt, clutter_5.txt), or
    - one text or CSV file of rows `x y z label` (label a class name; a header line is skipped).
    Raises ValueError (one line, naming the file) for anything else."""
    import re

    path = Path(path)
    if path.is_dir():
        files = sorted(path.glob("*.txt"))
        if not files:
            raise ValueError(f"{path}: no <class>_<n>.txt files in this folder")
        pts, labels = [], []
        for f in files:
            m = re.fullmatch(r"([A-Za-z]+)(?:_\d+)?", f.stem)
            if m is None:
                raise ValueError(f"{f}: name is not <class>_<n>.txt")
            try:
                arr = np.loadtxt(f, ndmin=2, usecols=(0, 1, 2))
            except ValueError as exc:
                raise ValueError(f"{f}: rows must start with x y z numbers ({exc})") from None
            pts.append(arr)
            labels += [m.group(1).lower()] * len(arr)
        return np.concatenate(pts).astype(np.float64), np.asarray(labels)
    if not path.is_file():
        raise ValueError(f"{path}: no such file or folder")
    delim = "," if path.suffix.lower() == ".csv" else None
    rows = []
    with path.open() as fh:
        for k, line in enumerate(fh, 1):
            parts = [p for p in (line.split(delim) if delim else line.split()) if p.strip()]
            if not parts:
                continue
            try:
                xyz = [float(p) for p in parts[:3]]
            except ValueError:
                if k == 1:
                    continue  # a header
                raise ValueError(f"{path}: line {k} does not start with x y z numbers") from None
            if len(parts) < 4:
                raise ValueError(f"{path}: line {k} has no label (rows are x y z label)")
            rows.append((*xyz, parts[3].strip().lower()))
    if not rows:
        raise ValueError(f"{path}: no labelled points")
    pts = np.array([r[:3] for r in rows], dtype=np.float64)
    return pts, np.array([r[3] for r in rows])
