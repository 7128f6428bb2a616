"""2D line-segment geometry shared by wall modelling (thesis 5.2.4-5.2.5) and plan vectorization (4.2.3).

Segments are `(N, 4)` float64 arrays `x0 y0 x1 y1`. Nothing here knows about point clouds or images, and
nothing depends on the unit: every length threshold is read in the unit of the segments (metres for
walls, pixels for a plan raster). `LinesConfig` stores its lengths in metres; a caller working in another
unit converts once with `LinesConfig.scaled(units_per_metre)`.

Steps, as in the thesis:
- `merge_segments`: 3-level hierarchical clustering (orientation k-means on doubled angles with k from
  the explained variance, eq 5.8, then a per-cluster split of angles that are bimodal beyond their noise;
  offset; connectivity) and averaging by regression (5.2.4.2);
- `regularize`: parallel clusters made equal, near-perpendicular ones made exactly 90° (eq 5.9);
- then `tasks.connect.connect`: extension and trimming to intersections, perpendicular extension of free
  ends, removal of extensions without data (5.2.5.2);
- `wall_graph`, `room_polygons`: the graph (networkx) and the rooms (shapely) the segments enclose.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import networkx as nx
import numpy as np
from numpy.typing import NDArray

from tasks.lines_config import LinesConfig

Segments = NDArray[np.float64]
"""(N, 4) x0 y0 x1 y1."""


@dataclass(frozen=True)
class MergedLines:
    """Result of `merge_segments`."""

    segments: Segments
    """(M, 4) one averaged segment per wall cluster."""
    labels: NDArray[np.intp]
    """(N,) index into `segments` for every input segment (-1 where dropped)."""
    orientation_labels: NDArray[np.intp]
    """(N,) orientation cluster of every input segment."""
    orientation_deg: NDArray[np.float64]
    """(k,) mean direction of each orientation cluster, degrees in [0, 180)."""
    explained_variance: tuple[float, ...]
    """Eq 5.8 for k = 1, 2, ... as tried; the chosen k is `len(orientation_deg)`."""
    orientation_criterion: str = "eq 5.8"
    """What decided the orientation clusters (`cluster_orientations`)."""
    chain: NDArray[np.intp] | None = None
    """(M,) the chain of collinear pieces (orientation, offset and connectivity cluster) each line comes
    from. Lines sharing a chain are the walls either side of a step `merge_segments` found in it
    (`_step_cut`); lines of different chains were never one wall's pieces (e.g. a gap wider than
    `max_gap_m`, a door, lies between them). `tasks.connect` joins two lines closer than `offset_tol_m`
    by a step only when they share a chain."""


# ---------------------------------------------------------------- basic geometry


def as_segments(segments: Sequence[Sequence[float]] | NDArray) -> Segments:
    """A (N, 4) float64 copy; a flat 4-vector becomes (1, 4); an empty input becomes (0, 4)."""
    arr = np.asarray(segments, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 4))
    arr = arr.reshape(-1, 4)
    return np.ascontiguousarray(arr)


def lengths(segments: Segments) -> NDArray[np.float64]:
    """(N,) segment lengths."""
    return np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])


def angles(segments: Segments) -> NDArray[np.float64]:
    """(N,) undirected orientation in radians, in [0, pi)."""
    return np.mod(np.arctan2(segments[:, 3] - segments[:, 1], segments[:, 2] - segments[:, 0]), np.pi)


def midpoints(segments: Segments) -> NDArray[np.float64]:
    """(N, 2) segment midpoints."""
    return 0.5 * (segments[:, :2] + segments[:, 2:])


def angle_difference(a: NDArray | float, b: NDArray | float) -> NDArray | float:
    """Signed difference a - b of undirected orientations (radians), wrapped to [-pi/2, pi/2)."""
    return np.mod(np.asarray(a) - np.asarray(b) + np.pi / 2, np.pi) - np.pi / 2


def rotate_segments(
    segments: Segments, rotation_rad: NDArray | float, centres: NDArray | None = None
) -> Segments:
    """Each segment rotated by its angle about its centre (default: its midpoint)."""
    segments = as_segments(segments)
    rot = np.broadcast_to(np.asarray(rotation_rad, dtype=np.float64), (len(segments),))
    c = midpoints(segments) if centres is None else np.broadcast_to(centres, (len(segments), 2))
    cos, sin = np.cos(rot)[:, None], np.sin(rot)[:, None]
    out = np.empty_like(segments)
    for k in (0, 2):
        d = segments[:, k : k + 2] - c
        out[:, k] = c[:, 0] + cos[:, 0] * d[:, 0] - sin[:, 0] * d[:, 1]
        out[:, k + 1] = c[:, 1] + sin[:, 0] * d[:, 0] + cos[:, 0] * d[:, 1]
    return out


def transform_segments(segments: Segments, rotation: NDArray | float, translation: NDArray) -> Segments:
    """Segments mapped by the rigid 2D transform p -> R p + t; `rotation` is a 2x2 matrix or an angle."""
    segments = as_segments(segments)
    r = np.asarray(rotation, dtype=np.float64)
    if r.ndim == 0:
        c, s = math.cos(float(r)), math.sin(float(r))
        r = np.array([[c, -s], [s, c]])
    t = np.asarray(translation, dtype=np.float64).reshape(2)
    out = np.empty_like(segments)
    out[:, :2] = segments[:, :2] @ r.T + t
    out[:, 2:] = segments[:, 2:] @ r.T + t
    return out


def sample_segments(segments: Segments, step: float) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Points every `step` along each segment (ends included): ((P, 2) points, (P,) segment index)."""
    segments = as_segments(segments)
    if len(segments) == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=np.intp)
    n = np.maximum(np.ceil(lengths(segments) / step).astype(np.intp), 1) + 1
    owner = np.repeat(np.arange(len(segments)), n)
    starts = np.cumsum(n) - n
    t = (np.arange(owner.size) - starts[owner]) / (n[owner] - 1)
    seg = segments[owner]
    pts = seg[:, :2] + t[:, None] * (seg[:, 2:] - seg[:, :2])
    return pts, owner


def point_segment_distances(points: NDArray, segments: Segments) -> NDArray[np.float64]:
    """(P, N) distance of every point to every segment (use for small N)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    segments = as_segments(segments)
    a = segments[None, :, :2]
    d = segments[None, :, 2:] - a
    dd = np.maximum((d**2).sum(-1), 1e-300)
    t = np.clip(((points[:, None, :] - a) * d).sum(-1) / dd, 0.0, 1.0)
    proj = a + t[..., None] * d
    return np.hypot(*(points[:, None, :] - proj).transpose(2, 0, 1))


def line_intersection(s1: NDArray, s2: NDArray) -> tuple[NDArray, float, float] | None:
    """Intersection of the infinite lines through two segments: (point, t1, t2) with the point at
    s1[:2] + t1 (s1[2:] - s1[:2]), likewise t2; None for parallel lines."""
    p, r = s1[:2], s1[2:] - s1[:2]
    q, s = s2[:2], s2[2:] - s2[:2]
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) <= 1e-12 * (np.hypot(*r) * np.hypot(*s) + 1e-300):
        return None
    qp = q - p
    t1 = (qp[0] * s[1] - qp[1] * s[0]) / den
    t2 = (qp[0] * r[1] - qp[1] * r[0]) / den
    return p + t1 * r, float(t1), float(t2)


# ---------------------------------------------------------------- orientation clustering (eq 5.7, 5.8)


def _weighted_kmeans(
    x: NDArray, w: NDArray, k: int, seed_index: int, iters: int = 50
) -> tuple[NDArray, NDArray]:
    """Lloyd's k-means (eq 5.7) with farthest-point seeding from x[seed_index]; returns (labels, centres)."""
    centres = [x[seed_index]]
    d2 = ((x - centres[0]) ** 2).sum(1)
    for _ in range(1, k):
        i = int(np.argmax(d2 * (w > 0)))
        centres.append(x[i])
        d2 = np.minimum(d2, ((x - x[i]) ** 2).sum(1))
    c = np.array(centres)
    labels = np.zeros(len(x), dtype=np.intp)
    for it in range(iters):
        new = np.argmin(((x[:, None, :] - c[None]) ** 2).sum(-1), axis=1)
        if it > 0 and np.array_equal(new, labels):
            break
        labels = new
        for j in range(k):
            m = labels == j
            if w[m].sum() > 0:
                c[j] = (w[m, None] * x[m]).sum(0) / w[m].sum()
    return labels, c


def explained_variance(x: NDArray, labels: NDArray, weights: NDArray | None = None) -> float:
    """Eq 5.8: between-groups over total (weighted) sum of squares of observations x (N, D); 1 when all
    observations coincide. The thesis' degrees-of-freedom factors are left out so that the share stays in
    [0, 1] (its quoted 97.5 % / 99.5 % are of this kind)."""
    x = np.asarray(x, dtype=np.float64).reshape(len(labels), -1)
    w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64)
    grand = (w[:, None] * x).sum(0) / w.sum()
    total = (w * ((x - grand) ** 2).sum(1)).sum()
    if total <= 1e-15 * w.sum():
        return 1.0
    between = 0.0
    for j in np.unique(labels):
        m = labels == j
        cj = (w[m, None] * x[m]).sum(0) / w[m].sum()
        between += w[m].sum() * ((cj - grand) ** 2).sum()
    return float(between / total)


def cluster_orientations(
    theta: NDArray, weights: NDArray, cfg: LinesConfig, seg_lengths: NDArray | None = None
) -> tuple[NDArray[np.intp], NDArray[np.float64], tuple[float, ...], str]:
    """Orientation k-means on doubled angles (so 0° and 180° coincide), k = the smallest whose explained
    variance reaches `cfg.explained_variance` (elbow, eq 5.8). Eq 5.8 is global: two clusters a few degrees
    apart add almost nothing to the variance when clusters 90° apart dominate it, so every cluster is then
    tested on its own (`_split_bimodal`): it is split when its members' angles fall into two groups further
    apart than the parallelism tolerance and well beyond the spread of line angles within each group, each
    holding a segment of `cfg.split_min_length_m` (`seg_lengths` (N,); the weights when not given).
    Clusters whose means lie within `angle_tol_deg` of each other are then joined. Returns (labels (N,),
    cluster means in radians [0, pi) (k,), explained variance for each k tried, the criterion that decided
    k: "eq 5.8" or "eq 5.8 + per-cluster split (n)")."""
    n = len(theta)
    if n == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0), (), "eq 5.8"
    x = np.column_stack([np.cos(2 * theta), np.sin(2 * theta)])
    w = np.asarray(weights, dtype=np.float64)
    kmax = max(1, min(cfg.max_orientation_clusters, n))
    seeds = np.argsort(-w, kind="stable")[: max(1, cfg.kmeans_restarts)]
    evs: list[float] = []
    best_labels = np.zeros(n, dtype=np.intp)
    for k in range(1, kmax + 1):
        best_sse, best = np.inf, None
        for s in seeds:
            labels, c = _weighted_kmeans(x, w, k, int(s))
            sse = (w * ((x - c[labels]) ** 2).sum(1)).sum()
            if sse < best_sse - 1e-12:
                best_sse, best = sse, labels
        assert best is not None
        best_labels = best
        evs.append(explained_variance(x, best_labels, w))
        if evs[-1] >= cfg.explained_variance:
            break
    labels = np.unique(best_labels, return_inverse=True)[1].astype(np.intp)
    tol = math.radians(cfg.angle_tol_deg)
    labels, splits = _split_bimodal(
        theta, w, labels, tol, cfg.max_orientation_clusters, cfg.split_min_length_m, seg_lengths
    )
    means = _cluster_mean_angles(theta, w, labels)
    labels, means = _join_close_clusters(theta, w, labels, means, tol)
    criterion = "eq 5.8" if splits == 0 else f"eq 5.8 + per-cluster split ({splits})"
    return labels, means, tuple(evs), criterion


SPLIT_SEPARATION = 4.0
"""A cluster's two angle groups must lie this many pooled within-group standard deviations apart. Splitting
one Gaussian group at its best point gives 2.65 (1.60 sigma between the halves' means, 0.60 sigma within
them), so 4 asks for two modes, not the two halves of one noisy mode."""
SPLIT_MIN_SHARE = 0.1
"""Each group of a split must hold at least this share of its cluster's weight (a few short skeleton
segments a few degrees off a long wall are noise of that wall, not a second direction)."""


def _split_bimodal(
    theta: NDArray,
    w: NDArray,
    labels: NDArray,
    tol: float,
    max_clusters: int,
    min_length: float = 0.0,
    seg_lengths: NDArray | None = None,
) -> tuple[NDArray[np.intp], int]:
    """Split clusters whose member angles are bimodal: the best weighted two-group split of a cluster's
    angles (exact in 1D: sorted angles, every cut) is taken when the groups' means are more than `tol`
    apart, more than SPLIT_SEPARATION pooled within-group standard deviations apart (the noise of the
    line angles, measured on the cluster itself), each group holds SPLIT_MIN_SHARE of the weight and a
    segment at least `min_length` long (`seg_lengths` (N,), else the weights). Repeats until no cluster
    splits. Returns (labels, number of splits)."""
    seg_lengths = w if seg_lengths is None else np.asarray(seg_lengths, dtype=np.float64)
    labels = labels.copy()
    splits = 0
    queue = list(np.unique(labels))
    while queue and int(labels.max()) + 1 < max_clusters + 8:
        c = queue.pop(0)
        m = np.flatnonzero(labels == c)
        if len(m) < 2:
            continue
        ww = w[m]
        mean = _cluster_mean_angles(theta[m], ww, np.zeros(len(m), dtype=np.intp))[0]
        rel = np.asarray(angle_difference(theta[m], mean), dtype=np.float64)
        order = np.argsort(rel, kind="stable")
        r, q = rel[order], ww[order]
        cw, cx, cx2 = np.cumsum(q), np.cumsum(q * r), np.cumsum(q * r * r)
        W, X, X2 = cw[-1], cx[-1], cx2[-1]
        if W <= 0:
            continue
        w1, x1, x21 = cw[:-1], cx[:-1], cx2[:-1]
        w2, x2, x22 = W - w1, X - x1, X2 - x21
        ok = (w1 > 0) & (w2 > 0)
        if not ok.any():
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            ssw = (x21 - x1**2 / w1) + (x22 - x2**2 / w2)
        ssw = np.where(ok, ssw, np.inf)
        cut = int(np.argmin(ssw))
        m1, m2 = x1[cut] / w1[cut], x2[cut] / w2[cut]
        sd = math.sqrt(max(float(ssw[cut]), 0.0) / W)
        sep = abs(m2 - m1)
        share = min(w1[cut], w2[cut]) / W
        longest = min(seg_lengths[m[order[: cut + 1]]].max(), seg_lengths[m[order[cut + 1 :]]].max())
        if sep > tol and sep > SPLIT_SEPARATION * sd and share >= SPLIT_MIN_SHARE and longest >= min_length:
            new = int(labels.max()) + 1
            labels[m[order[cut + 1 :]]] = new
            splits += 1
            queue += [c, new]
    return np.unique(labels, return_inverse=True)[1].astype(np.intp), splits


def _cluster_mean_angles(theta: NDArray, w: NDArray, labels: NDArray) -> NDArray[np.float64]:
    k = int(labels.max()) + 1 if len(labels) else 0
    c = np.bincount(labels, w * np.cos(2 * theta), k)
    s = np.bincount(labels, w * np.sin(2 * theta), k)
    return np.mod(0.5 * np.arctan2(s, c), np.pi)


def _join_close_clusters(
    theta: NDArray, w: NDArray, labels: NDArray, means: NDArray, tol: float
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Single-linkage join of cluster means closer than tol (parallel within tolerance)."""
    while len(means) > 1:
        diff = np.abs(angle_difference(means[:, None], means[None, :]))
        np.fill_diagonal(diff, np.inf)
        i, j = np.unravel_index(np.argmin(diff), diff.shape)
        if diff[i, j] > tol:
            break
        labels = np.where(labels == j, i, labels)
        labels = np.unique(labels, return_inverse=True)[1].astype(np.intp)
        means = _cluster_mean_angles(theta, w, labels)
    return labels, means


# ---------------------------------------------------------------- merging (5.2.4.2)


def _chains_1d(values: NDArray, tol: float) -> NDArray[np.intp]:
    """Single-linkage groups of 1D values: sorted neighbours closer than tol share a group."""
    order = np.argsort(values, kind="stable")
    breaks = np.diff(values[order]) > tol
    group_sorted = np.concatenate([[0], np.cumsum(breaks)])
    out = np.empty(len(values), dtype=np.intp)
    out[order] = group_sorted
    return out


def _intervals_chains(t0: NDArray, t1: NDArray, gap: float) -> NDArray[np.intp]:
    """Groups of intervals [t0, t1] (t0 <= t1) that overlap or are separated by at most gap."""
    order = np.argsort(t0, kind="stable")
    out = np.empty(len(t0), dtype=np.intp)
    group, reach = -1, -np.inf
    for i in order:
        if t0[i] - reach > gap:
            group += 1
            reach = t1[i]
        else:
            reach = max(reach, t1[i])
        out[i] = group
    return out


def fit_line(segments: Segments, weights: NDArray | None = None) -> Segments:
    """Average of segments by total-least-squares regression over points sampled densely and uniformly
    along them (computed in closed form: a segment of length L from a to b contributes L points with mean
    (a+b)/2 and scatter L (b-a)(b-a)^T / 12), cropped to the projection of all endpoints. Returns (1, 4)."""
    segments = as_segments(segments)
    L = lengths(segments) * (1.0 if weights is None else np.asarray(weights, dtype=np.float64))
    if L.sum() <= 0:
        L = np.ones(len(segments))
    m = midpoints(segments)
    centre = (L[:, None] * m).sum(0) / L.sum()
    d = segments[:, 2:] - segments[:, :2]
    dm = m - centre
    scatter = (
        L[:, None, None] * (dm[:, :, None] * dm[:, None, :] + d[:, :, None] * d[:, None, :] / 12.0)
    ).sum(0)
    evals, evecs = np.linalg.eigh(scatter)
    u = evecs[:, int(np.argmax(evals))]
    if (d @ u) @ L < 0:  # keep the members' prevailing direction
        u = -u
    ends = np.concatenate([segments[:, :2], segments[:, 2:]]) - centre
    t = ends @ u
    a, b = centre + t.min() * u, centre + t.max() * u
    return np.array([[a[0], a[1], b[0], b[1]]])


def _scatter(segments: Segments, w: NDArray) -> tuple[float, NDArray, NDArray]:
    """(weight, centroid (2,), scatter (2, 2) about it) of points spread uniformly along the segments, each
    segment weighing `w` (as in `fit_line`)."""
    m = midpoints(segments)
    W = float(w.sum())
    c = (w[:, None] * m).sum(0) / W
    d, dm = segments[:, 2:] - segments[:, :2], m - c
    S = (w[:, None, None] * (dm[:, :, None] * dm[:, None, :] + d[:, :, None] * d[:, None, :] / 12.0)).sum(0)
    return W, c, S


def _main_axis(scatter: NDArray) -> NDArray:
    return np.linalg.eigh(scatter)[1][:, 1]


def _step_cut(
    segments: Segments,
    w: NDArray,
    t0: NDArray,
    t1: NDArray,
    quantum: float,
    sin_tol: float,
    window: float | None = None,
) -> int | None:
    """Where a chain of parallel pieces is two walls with a step between them: the cut (members sorted by
    start `t0` along the line, the first `cut` on one side) such that the two sides do not overlap along
    the line (beyond the step itself and `STEP_MIN_CELLS` cells: a skeleton rounds a step's corners, and a
    Hough segment's end runs on a cell or two past it) and two parallel lines, one per
    side (common direction, own offsets, fitted by total least squares), lie further apart than
    SPLIT_SEPARATION standard deviations of the data about them, each side's own direction within the
    parallel tolerance (sine `sin_tol`) of the common one; the deviation is at least the rounding
    noise of a position on a grid of `quantum`, quantum / sqrt(12). Returns the cut with the least
    scatter about the two lines, or None. The data's noise decides, not a threshold on the step.

    With `window`, a cut the whole sides do not show is also looked for on the stretch of `window` either
    side of it (`_local_step`): a long wall whose far part holds a second, doubled face (a drifting
    registration) or a slow bend has a large spread about one line, which hides a jog of a few cm that
    the data beside it show plainly."""
    n = len(segments)
    floor = quantum / math.sqrt(12.0)
    reach = np.maximum.accumulate(t1)
    # the direction in which t grows (for cutting pieces at a position along the line)
    u = _main_axis(_scatter(segments, np.ones(n))[2])
    if float((midpoints(segments) @ u) @ (0.5 * (t0 + t1) - (t0 + t1).mean() / 2)) < 0:
        u = -u
    best, best_ssw = None, np.inf
    for k in range(1, n):
        wa, ca, sa = _scatter(segments[:k], w[:k])
        wb, cb, sb = _scatter(segments[k:], w[k:])
        if wa <= 0 or wb <= 0:
            continue
        evals, evecs = np.linalg.eigh(sa + sb)
        ssw, nrm = float(evals[0]), evecs[:, 0]  # the common normal: least scatter about two parallels
        step = abs(float((cb - ca) @ nrm))
        if reach[k - 1] - t0[k] > step + STEP_MIN_CELLS * quantum:
            continue  # the sides overlap along the line: parallel pieces of one wall
        if max(abs(float(_main_axis(sa) @ nrm)), abs(float(_main_axis(sb) @ nrm))) > sin_tol:
            continue  # a side is not parallel to the other (clutter of the cluster): no step to speak of
        sd = max(math.sqrt(max(ssw, 0.0) / (wa + wb)), floor)
        if ssw >= best_ssw:
            continue
        if step <= STEP_MIN_CELLS * quantum:
            continue  # a cell or two: the skeleton's rounding, not a step
        if step > SPLIT_SEPARATION * sd or (
            window is not None
            and _local_step(segments, w, t0, t1, u, k, 0.5 * (reach[k - 1] + t0[k]), window, quantum, sin_tol)
        ):
            best, best_ssw = k, ssw
    return best


STEP_MIN_CELLS = 2.5
"""A step must exceed this many grid cells (more than two): a skeleton's line lies on whole cells, so two pieces of one wall
may sit a cell or two apart with almost no spread each (a side of one or two long pieces, or the few
pieces beside a cut, hold too little to average that rounding out)."""


def _clip_along(
    segments: Segments, w: NDArray, t0: NDArray, t1: NDArray, u: NDArray, lo: float, hi: float
) -> tuple[Segments, NDArray, float]:
    """The parts of `segments` whose position along the line (`t0` to `t1`, growing along `u`) lies within
    [lo, hi], their weights (`w` in proportion to the part kept) and their summed length along the line."""
    span = np.maximum(t1 - t0, 1e-300)
    a, b = np.clip((lo - t0) / span, 0.0, 1.0), np.clip((hi - t0) / span, 0.0, 1.0)
    keep = b - a > 0
    if not keep.any():
        return np.zeros((0, 4)), np.zeros(0), 0.0
    s, a, b = segments[keep], a[keep], b[keep]
    # the end of each segment at t0: the one whose position along the line is the smaller
    flip = ((s[:, 2:] - s[:, :2]) @ u) < 0
    p0 = np.where(flip[:, None], s[:, 2:], s[:, :2])
    p1 = np.where(flip[:, None], s[:, :2], s[:, 2:])
    q = p1 - p0
    parts = np.concatenate([p0 + a[:, None] * q, p0 + b[:, None] * q], axis=1)
    frac = b - a
    return parts, w[keep] * frac, float(((t1 - t0)[keep] * frac).sum())


def _local_step(
    segments: Segments,
    w: NDArray,
    t0: NDArray,
    t1: NDArray,
    u: NDArray,
    k: int,
    at: float,
    window: float,
    quantum: float,
    sin_tol: float,
) -> bool:
    """Whether the pieces within `window` before the cut at `at` (the first `k` members) and within
    `window` after it (the others) are two parallel lines further apart than SPLIT_SEPARATION standard
    deviations of those pieces about them, each side backed over at least half the window (a jog between
    two walls, each seen over a stretch beside it, not a short piece of clutter against a wall), and more
    than STEP_MIN_CELLS cells of the grid `quantum` apart."""
    floor = quantum / math.sqrt(12.0)
    sa_seg, wa, la = _clip_along(segments[:k], w[:k], t0[:k], t1[:k], u, at - window, at)
    sb_seg, wb, lb = _clip_along(segments[k:], w[k:], t0[k:], t1[k:], u, at, at + window)
    if min(la, lb) < 0.5 * window or wa.sum() <= 0 or wb.sum() <= 0:
        return False
    wa_, ca, sa = _scatter(sa_seg, wa)
    wb_, cb, sb = _scatter(sb_seg, wb)
    evals, evecs = np.linalg.eigh(sa + sb)
    ssw, nrm = float(evals[0]), evecs[:, 0]
    if max(abs(float(_main_axis(sa) @ nrm)), abs(float(_main_axis(sb) @ nrm))) > sin_tol:
        return False
    sd = max(math.sqrt(max(ssw, 0.0) / (wa_ + wb_)), floor)
    step = abs(float((cb - ca) @ nrm))
    return step > SPLIT_SEPARATION * sd and step > STEP_MIN_CELLS * quantum


def _split_steps(
    segments: Segments,
    w: NDArray,
    t0: NDArray,
    t1: NDArray,
    quantum: float,
    sin_tol: float,
    window: float | None = None,
) -> list[NDArray]:
    """Positions into `segments` of each wall of a chain of parallel pieces split, recursively, at every
    step (`_step_cut`)."""
    order = np.argsort(t0, kind="stable")
    cut = _step_cut(segments[order], w[order], t0[order], t1[order], quantum, sin_tol, window)
    if cut is None:
        return [np.arange(len(segments))]
    out = []
    for side in (order[:cut], order[cut:]):
        out += [
            side[p]
            for p in _split_steps(segments[side], w[side], t0[side], t1[side], quantum, sin_tol, window)
        ]
    return out


def merge_segments(
    segments: Segments, cfg: LinesConfig, weights: NDArray | None = None, quantum: float | None = None
) -> MergedLines:
    """Group segments into walls (orientation -> offset -> connectivity) and average every group.

    `weights` (N,) multiply the segment lengths in all weighted steps (e.g. Hough votes); default 1.
    With `quantum` (the grid the segments were found on, in their unit), offset clustering is aware of
    overlap: a chain of parallel pieces within `offset_tol_m` of each other whose pieces on either side of
    some point do not overlap along the line, and whose offsets there differ by more than their noise
    (`_step_cut`), is two walls with a step (a jog of a few cm where two rooms' walls meet), not one."""
    segments = as_segments(segments)
    n = len(segments)
    L = lengths(segments)
    keep = L > 0
    w = L * (1.0 if weights is None else np.asarray(weights, dtype=np.float64).reshape(n))
    labels_out = np.full(n, -1, dtype=np.intp)
    orient_out = np.full(n, -1, dtype=np.intp)
    if not keep.any():
        return MergedLines(
            np.zeros((0, 4)), labels_out, orient_out, np.zeros(0), (), chain=np.zeros(0, dtype=np.intp)
        )
    idx = np.flatnonzero(keep)
    seg, wk = segments[idx], w[idx]
    theta = angles(seg)
    o_labels, o_means, evs, criterion = cluster_orientations(theta, wk, cfg, L[idx])
    orient_out[idx] = o_labels

    sin_tol = math.sin(math.radians(cfg.angle_tol_deg))
    merged: list[NDArray] = []
    chain_of: list[int] = []
    n_chains = 0
    for c, phi in enumerate(o_means):
        members = np.flatnonzero(o_labels == c)
        u = np.array([math.cos(phi), math.sin(phi)])
        nrm = np.array([-u[1], u[0]])
        offsets = midpoints(seg[members]) @ nrm
        for og in np.unique(off_groups := _chains_1d(offsets, cfg.offset_tol_m)):
            om = members[off_groups == og]
            ta, tb = seg[om, :2] @ u, seg[om, 2:] @ u
            t0, t1 = np.minimum(ta, tb), np.maximum(ta, tb)
            chains = _intervals_chains(t0, t1, cfg.max_gap_m)
            for ch in np.unique(chains):
                # the walls of one chain, split at its steps (one wall where there is no step)
                p = np.flatnonzero(chains == ch)
                walls = [p]
                if quantum is not None:
                    walls = [
                        p[q]
                        for q in _split_steps(
                            seg[om[p]], wk[om[p]], t0[p], t1[p], quantum, sin_tol, cfg.step_window_m
                        )
                    ]
                for cm in (om[q] for q in walls):
                    line = fit_line(seg[cm], wk[cm] / np.maximum(lengths(seg[cm]), 1e-300))
                    if lengths(line)[0] < cfg.min_length_m:
                        continue
                    labels_out[idx[cm]] = len(merged)
                    merged.append(line[0])
                    chain_of.append(n_chains)
                n_chains += 1
    out = np.array(merged).reshape(-1, 4)
    chain = np.array(chain_of, dtype=np.intp)
    return MergedLines(out, labels_out, orient_out, np.degrees(o_means), evs, criterion, chain)


# ---------------------------------------------------------------- regularization (5.2.5.1, eq 5.9)


def regularize(
    segments: Segments, cfg: LinesConfig, weights: NDArray | None = None
) -> tuple[Segments, NDArray]:
    """Parallel and perpendicular constraints (eq 5.9).

    Segments are clustered by orientation as in `merge_segments`; every member takes its cluster's mean
    (parallel). Cluster means within `angle_tol_deg` of 90° apart are then turned to exactly 90°, the
    correction shared between the clusters in proportion to the other's length (for two clusters of
    equal length this is eq 5.9's Δα = (90° - (α2 - α1)) / 2 each way). Other angles are kept.
    Each segment is rotated about its midpoint. Returns (segments (N, 4), rotation (N,) radians applied
    to each), so that `rotate_segments(out, -rotation)` undoes it."""
    segments = as_segments(segments)
    n = len(segments)
    if n == 0:
        return segments.copy(), np.zeros(0)
    theta = angles(segments)
    w = lengths(segments) * (1.0 if weights is None else np.asarray(weights, dtype=np.float64))
    w = np.where(w > 0, w, 1e-12)
    labels, means, _, _ = cluster_orientations(theta, w, cfg, lengths(segments))
    target = _perpendicular_targets(
        means, np.bincount(labels, w, len(means)), math.radians(cfg.angle_tol_deg)
    )
    rotation = angle_difference(target[labels], theta)
    return rotate_segments(segments, rotation), np.asarray(rotation, dtype=np.float64)


def _perpendicular_targets(means: NDArray, weight: NDArray, tol: float) -> NDArray[np.float64]:
    """Cluster orientations after snapping near-perpendicular pairs to 90°. Clusters linked by ~90°
    relations form a group sharing one frame angle phi; a member's target is phi or phi + 90°."""
    k = len(means)
    g = nx.Graph()
    g.add_nodes_from(range(k))
    for i in range(k):
        for j in range(i + 1, k):
            if abs(abs(angle_difference(means[i], means[j])) - np.pi / 2) <= tol:
                g.add_edge(i, j)
    target = means.astype(np.float64).copy()
    for comp in nx.connected_components(g):
        comp = sorted(comp)
        if len(comp) < 2:
            continue
        ref = means[comp[0]]
        # every member's angle reduced modulo 90° to near ref (doubling makes the period 90°)
        phis = np.array([ref + angle_difference(2 * means[i], 2 * ref) / 2 for i in comp])
        ww = weight[comp]
        phi = float((ww * phis).sum() / ww.sum())
        for i in comp:
            target[i] = np.mod(
                phi + round(float(angle_difference(means[i], phi)) / (np.pi / 2)) * np.pi / 2, np.pi
            )
    return target


def overlapping_parallels(segments: Segments, offset_tol: float, quantum: float) -> NDArray[np.intp]:
    """(N,) a group per segment: parallel segments (directions within 1e-6 rad, as `regularize` leaves a
    cluster's members) whose lines lie within `offset_tol` of each other and which overlap along them by
    more than their separation and `STEP_MIN_CELLS` cells of the grid `quantum` share a group (single
    linkage). `merge_segments`' rule for one wall, asked again after the regularization: pieces of one wall
    drawn a few degrees apart (the skeleton of a wide band of noisy points) fall into two orientation
    clusters, and meet only once both are turned to one direction; a jog's two walls do not overlap."""
    segments = as_segments(segments)
    n = len(segments)
    group = np.arange(n)
    theta, mid = angles(segments), midpoints(segments)
    for i in range(n):
        u = np.array([math.cos(theta[i]), math.sin(theta[i])])
        nrm = np.array([-u[1], u[0]])
        ti = np.sort(segments[i].reshape(2, 2) @ u)
        for j in range(i + 1, n):
            if abs(math.sin(theta[j] - theta[i])) > 1e-6 or group[j] == group[i]:
                continue
            sep = abs(float((mid[j] - mid[i]) @ nrm))
            tj = np.sort(segments[j].reshape(2, 2) @ u)
            overlap = min(ti[1], tj[1]) - max(ti[0], tj[0])
            if sep <= offset_tol and overlap > sep + STEP_MIN_CELLS * quantum:
                group[group == group[j]] = group[i]
    return np.unique(group, return_inverse=True)[1].astype(np.intp)


# ---------------------------------------------------------------- graph and rooms


def point_clusters(points: NDArray, tol: float) -> NDArray[np.intp]:
    """(P,) cluster label of every point: points chained closer than tol share one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    pairs = cKDTree(points).query_pairs(max(tol, 0.0), output_type="ndarray")
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(adj, directed=False)[1].astype(np.intp)


def _split_points(segments: Segments, tol: float) -> list[NDArray]:
    """For every segment, the parameters t in (0, 1) where another segment's end lies within tol of it
    or another segment crosses it."""
    n = len(segments)
    a, d = segments[:, :2], segments[:, 2:] - segments[:, :2]
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-300)
    cuts: list[list[float]] = [[] for _ in range(n)]
    # other segments' ends on a segment (T-junctions)
    ends = np.concatenate([segments[:, :2], segments[:, 2:]])
    owner = np.concatenate([np.arange(n), np.arange(n)])
    dist = point_segment_distances(ends, segments)  # (2n, n)
    t = ((ends[:, None, :] - a[None]) * d[None]).sum(-1) / (L**2)[None]
    hit = (
        (dist <= tol)
        & (t * L[None] > tol)
        & ((1 - t) * L[None] > tol)
        & (owner[:, None] != np.arange(n)[None])
    )
    for e, i in zip(*np.nonzero(hit), strict=True):
        cuts[i].append(float(t[e, i]))
    # proper crossings
    den = d[:, None, 0] * d[None, :, 1] - d[:, None, 1] * d[None, :, 0]
    qp = a[None, :, :] - a[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (qp[..., 0] * d[None, :, 1] - qp[..., 1] * d[None, :, 0]) / den
        t2 = (qp[..., 0] * d[:, None, 1] - qp[..., 1] * d[:, None, 0]) / den
    inner = lambda tt, ll: (tt * ll > tol) & ((1 - tt) * ll > tol)  # noqa: E731
    cross = (np.abs(den) > 1e-12 * L[:, None] * L[None, :]) & inner(t1, L[:, None]) & inner(t2, L[None, :])
    for i, j in zip(*np.nonzero(cross), strict=True):
        cuts[i].append(float(t1[i, j]))
    return [np.unique(c) for c in cuts]


def _noded(segments: Segments, tol: float) -> tuple[Segments, NDArray[np.intp], NDArray[np.float64]]:
    """Segments split at junctions and crossings, with ends closer than tol merged into one node.
    Returns (pieces (K, 4) whose ends are exactly their nodes' positions, node index (K, 2), node xy)."""
    segments = as_segments(segments)
    segments = segments[lengths(segments) > tol]
    if len(segments) == 0:
        return np.zeros((0, 4)), np.zeros((0, 2), dtype=np.intp), np.zeros((0, 2))
    pieces = []
    for s, c in zip(segments, _split_points(segments, tol), strict=True):
        ts = np.concatenate([[0.0], c, [1.0]])
        p = s[:2] + ts[:, None] * (s[2:] - s[:2])
        pieces.append(np.concatenate([p[:-1], p[1:]], axis=1))
    pieces = np.concatenate(pieces)
    pts = np.concatenate([pieces[:, :2], pieces[:, 2:]])
    label = point_clusters(pts, tol)
    count = np.bincount(label)
    xy = np.column_stack([np.bincount(label, pts[:, k]) / count for k in (0, 1)])
    k = len(pieces)
    nodes = np.column_stack([label[:k], label[k:]]).astype(np.intp)
    keep = nodes[:, 0] != nodes[:, 1]
    nodes = nodes[keep]
    snapped = np.concatenate([xy[nodes[:, 0]], xy[nodes[:, 1]]], axis=1)
    return snapped, nodes, xy


def node_segments(segments: Segments, tol: float = 1e-6) -> Segments:
    """Segments split wherever another segment's end (within tol) or a crossing lies on them, with ends
    closer than tol snapped together."""
    return _noded(segments, tol)[0]


def wall_graph(segments: Segments, tol: float = 1e-6) -> nx.Graph:
    """Undirected graph of the walls: nodes are ends and junctions (ends closer than `tol` are one node;
    attribute `xy`), edges are wall pieces between them (attributes `length`, `segment`)."""
    g = nx.Graph()
    pieces, nodes, xy = _noded(segments, tol)
    for i in np.unique(nodes):
        g.add_node(int(i), xy=(float(xy[i, 0]), float(xy[i, 1])))
    for s, (a, b) in zip(pieces, nodes, strict=True):
        g.add_edge(int(a), int(b), length=float(np.hypot(s[2] - s[0], s[3] - s[1])), segment=s.copy())
    return g


def is_closed(graph: nx.Graph) -> bool:
    """True when the graph has a cycle and no free end (node of degree 1)."""
    if graph.number_of_edges() == 0:
        return False
    return min(d for _, d in graph.degree()) >= 2 and len(nx.cycle_basis(graph)) > 0


def room_polygons(segments: Segments, tol: float = 1e-6) -> list:
    """Shapely polygons enclosed by the segments (after noding), largest first."""
    import shapely
    from shapely.ops import polygonize

    noded = node_segments(segments, tol)  # ends snapped exactly together, as polygonize needs
    if len(noded) == 0:
        return []
    polys = list(polygonize(shapely.linestrings(noded.reshape(-1, 2, 2)).tolist()))
    return sorted(polys, key=lambda p: -p.area)


def share_along(
    segment: NDArray,
    hit_at: Callable[[NDArray[np.float64]], NDArray[np.bool_]],
    margin_m: float,
    step_m: float = 0.05,
) -> float:
    """Share of a segment's (x0, y0, x1, y1) length, sampled every step_m, beside which `hit_at` ((K, 2)
    points -> (K,) bool, e.g. a grid's lookup) holds somewhere within margin_m across it (in 2.5 cm
    steps); 0 for a segment of no length."""
    a, b = segment[:2], segment[2:]
    length = float(np.hypot(*(b - a)))
    u = (b - a) / max(length, 1e-12)
    n = np.array([-u[1], u[0]])
    pts = a + np.arange(step_m / 2, length, step_m)[:, None] * u
    hit = np.zeros(len(pts), dtype=bool)
    for o in np.arange(-margin_m, margin_m + 1e-9, 0.025):
        hit |= hit_at(pts + o * n)
    return float(hit.mean()) if len(hit) else 0.0


def true_runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, end) of every run of True in a 1-D boolean array, in order."""
    m = np.concatenate([[False], mask, [False]]).astype(int)
    d = np.diff(m)
    return [(int(a), int(b)) for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)]
