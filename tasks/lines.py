"""2D line-segment geometry shared by wall modelling (thesis 5.2.4-5.2.5) and plan vectorization (4.2.3).

Segments are `(N, 4)` float64 arrays `x0 y0 x1 y1`. Nothing here knows about point clouds or images, and
nothing depends on the unit: every length threshold is read in the unit of the segments (metres for
walls, pixels for a plan raster). `LinesConfig` stores its lengths in metres; a caller working in another
unit converts once with `LinesConfig.scaled(units_per_metre)`.

Steps, as in the thesis:
- `merge_segments`: 3-level hierarchical clustering (orientation k-means on doubled angles with k from
  the explained variance, eq 5.8; offset; connectivity) and averaging by regression (5.2.4.2);
- `regularize`: parallel clusters made equal, near-perpendicular ones made exactly 90° (eq 5.9);
- `connect`: extension and trimming to intersections, perpendicular extension of free ends, removal of
  extensions without data (5.2.5.2);
- `wall_graph`, `room_polygons`: the graph (networkx) and the rooms (shapely) the segments enclose.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import networkx as nx
import numpy as np
from numpy.typing import NDArray

Segments = NDArray[np.float64]
"""(N, 4) x0 y0 x1 y1."""

SupportFn = Callable[[NDArray[np.float64], NDArray[np.intp]], NDArray[np.float64]]
"""support_fn(pieces (P, 4), parent (P,) index into connect's input, -1 for new pieces) -> (P,) share 0..1
of each piece's length backed by data."""

OBSERVED = "observed"
EXTENDED = "extended"


@dataclass(frozen=True)
class LinesConfig:
    """Thresholds of the line stages. Lengths are metres as stored; see `scaled` for other units."""

    max_orientation_clusters: int = 8
    """Largest k tried by the orientation k-means."""
    explained_variance: float = 0.99
    """Elbow criterion (eq 5.8): the smallest k whose clusters explain this share of the length-weighted
    variance of the doubled-angle unit vectors."""
    kmeans_restarts: int = 4
    """Deterministic k-means restarts per k (farthest-point seeds from different starting segments)."""
    angle_tol_deg: float = 3.0
    """Parallel / perpendicular tolerance: orientation clusters closer than this are made parallel; pairs
    within this of 90° are made exactly perpendicular (eq 5.9). Other angles are kept."""
    offset_tol_m: float = 0.05
    """Offset clustering: parallel segments whose offsets (distance of the line from the origin) differ by
    less than this, in a chain, are one line."""
    max_gap_m: float = 0.8
    """Connectivity clustering: collinear pieces separated by at most this gap are one wall (the largest
    expected occlusion, doors and windows aside; like the thesis, the same as `extend_m`)."""
    extend_m: float = 0.8
    """Extension / trimming threshold: ends move at most this far to reach an intersection, and a free end
    is joined perpendicularly to a line at most this far away (the largest occlusion to close: thesis
    table 6.3 finds 0.5-1 m; a two-station TLS scan of an alcove leaves 0.65 m unseen)."""
    trim_m: float | None = None
    """Trimming threshold: an end is cut back to an intersection at most this far (None: `extend_m`, as in
    the thesis). Observed data past a partition's face is wall, not overshoot: a T-junction must not cut
    the wall it stands on back to it."""
    min_length_m: float = 0.0
    """Merged lines shorter than this are dropped."""
    min_overlap: float = 0.5
    """Extensions whose share of length backed by data is below this are removed (thesis: 50 %)."""

    def scaled(self, units_per_metre: float) -> LinesConfig:
        """The same config with every length expressed in another unit (e.g. pixels: 1 / pixel size)."""
        scaled = {
            f: getattr(self, f) * units_per_metre for f in _LENGTH_FIELDS if getattr(self, f) is not None
        }
        return replace(self, **scaled)


_LENGTH_FIELDS = ("offset_tol_m", "max_gap_m", "extend_m", "trim_m", "min_length_m")


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
    theta: NDArray, weights: NDArray, cfg: LinesConfig
) -> tuple[NDArray[np.intp], NDArray[np.float64], tuple[float, ...]]:
    """Orientation k-means on doubled angles (so 0° and 180° coincide), k = the smallest whose explained
    variance reaches `cfg.explained_variance` (elbow, eq 5.8). Clusters whose means lie within
    `angle_tol_deg` of each other are then joined. Returns (labels (N,), cluster means in radians [0, pi)
    (k,), explained variance for each k tried)."""
    n = len(theta)
    if n == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0), ()
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
    means = _cluster_mean_angles(theta, w, labels)
    labels, means = _join_close_clusters(theta, w, labels, means, math.radians(cfg.angle_tol_deg))
    return labels, means, tuple(evs)


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


def merge_segments(segments: Segments, cfg: LinesConfig, weights: NDArray | None = None) -> MergedLines:
    """Group segments into walls (orientation -> offset -> connectivity) and average every group.

    `weights` (N,) multiply the segment lengths in all weighted steps (e.g. Hough votes); default 1."""
    segments = as_segments(segments)
    n = len(segments)
    L = lengths(segments)
    keep = L > 0
    w = L * (1.0 if weights is None else np.asarray(weights, dtype=np.float64).reshape(n))
    labels_out = np.full(n, -1, dtype=np.intp)
    orient_out = np.full(n, -1, dtype=np.intp)
    if not keep.any():
        return MergedLines(np.zeros((0, 4)), labels_out, orient_out, np.zeros(0), ())
    idx = np.flatnonzero(keep)
    seg, wk = segments[idx], w[idx]
    theta = angles(seg)
    o_labels, o_means, evs = cluster_orientations(theta, wk, cfg)
    orient_out[idx] = o_labels

    merged: list[NDArray] = []
    for c, phi in enumerate(o_means):
        members = np.flatnonzero(o_labels == c)
        u = np.array([math.cos(phi), math.sin(phi)])
        nrm = np.array([-u[1], u[0]])
        offsets = midpoints(seg[members]) @ nrm
        for og in np.unique(off_groups := _chains_1d(offsets, cfg.offset_tol_m)):
            om = members[off_groups == og]
            ta, tb = seg[om, :2] @ u, seg[om, 2:] @ u
            chains = _intervals_chains(np.minimum(ta, tb), np.maximum(ta, tb), cfg.max_gap_m)
            for ch in np.unique(chains):
                cm = om[chains == ch]
                line = fit_line(seg[cm], wk[cm] / np.maximum(lengths(seg[cm]), 1e-300))
                if lengths(line)[0] < cfg.min_length_m:
                    continue
                labels_out[idx[cm]] = len(merged)
                merged.append(line[0])
    out = np.array(merged).reshape(-1, 4)
    return MergedLines(out, labels_out, orient_out, np.degrees(o_means), evs)


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
    labels, means, _ = cluster_orientations(theta, w, cfg)
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


# ---------------------------------------------------------------- topology (5.2.5.2)


@dataclass(frozen=True)
class Connected:
    """Result of `connect_detailed`."""

    segments: Segments
    """(M, 4) walls after extension, trimming, perpendicular joins and pruning."""
    origin: NDArray[np.str_]
    """(M,) "observed" for walls from the input, "extended" for walls made only of extensions."""
    parent: NDArray[np.intp]
    """(M,) input segment each wall continues, -1 for perpendicular joins."""
    removed: Segments
    """(R, 4) extension pieces removed for lack of data."""


@dataclass
class _Wall:
    a: NDArray  # start point
    u: NDArray  # unit direction
    t0: float  # extent along u (a + t u)
    t1: float
    obs0: float  # observed extent (from the input segment)
    obs1: float
    parent: int
    perpendicular: bool = False

    def end(self, e: int) -> NDArray:
        return self.a + (self.t0 if e == 0 else self.t1) * self.u

    def as_segment(self) -> NDArray:
        return np.concatenate([self.end(0), self.end(1)])


def connect(
    segments: Segments,
    cfg: LinesConfig,
    support_fn: SupportFn | None = None,
    interior_xy: NDArray | None = None,
) -> tuple[Segments, NDArray[np.str_]]:
    """Extend or trim ends to intersections within `cfg.extend_m`, join remaining free ends
    perpendicularly to a line within `cfg.extend_m`, and (with `support_fn`) remove pieces made by
    extension whose data support is below `cfg.min_overlap`. Returns (segments, origin).

    `interior_xy` (2,), a point inside the room, decides which of two facing free ends places a join
    (see `connect_detailed`); without it the ends are taken in input order."""
    res = connect_detailed(segments, cfg, support_fn, interior_xy)
    return res.segments, res.origin


def connect_detailed(
    segments: Segments,
    cfg: LinesConfig,
    support_fn: SupportFn | None = None,
    interior_xy: NDArray | None = None,
) -> Connected:
    """`connect` with the parent of every wall and the removed pieces.

    Perpendicular joins: where two parallel walls end facing each other (an alcove, a recess, a chimney
    breast) and the wall between them was not seen, the join goes at the end of the wall nearer the room's
    interior (`interior_xy`) and the other wall is extended to it. That end is the room's reflex corner,
    whose data runs up to it seen from anywhere in the room; the farther wall's data stops where the unseen
    wall hides it from the room, short of its corner.

    Every wall is cut where other walls end on it and where its observed span ends, so that each
    extension is a piece of its own. With `support_fn`, a piece is removed when its support is below
    `cfg.min_overlap` and it is either an extension in the original direction that does not close a
    corner (a corner: both its ends meet exactly one other piece, so removing it would open the room,
    typically where the data stops short of a corner) or a span bridged between two junctions (a wall
    behind a column). Perpendicular joins are kept, as in the thesis. Kept pieces of one wall are joined
    again."""
    segments = as_segments(segments)
    walls: list[_Wall] = []
    for i, s in enumerate(segments):
        d = s[2:] - s[:2]
        L = float(np.hypot(*d))
        if L <= 0:
            continue
        walls.append(_Wall(s[:2].copy(), d / L, 0.0, L, 0.0, L, i))
    T = float(cfg.extend_m)
    eps = max(T, 1e-9) * 1e-6
    sin_tol = math.sin(math.radians(max(cfg.angle_tol_deg, 1e-3)))

    _extend_and_trim(walls, T, T if cfg.trim_m is None else min(T, float(cfg.trim_m)), sin_tol)
    _join_free_ends(walls, T, eps, sin_tol, max(cfg.offset_tol_m, eps), interior_xy, support_fn)
    pieces, piece_parent, piece_wall, extended = _node_pieces(walls, eps)

    removed = np.zeros(len(pieces), dtype=bool)
    if support_fn is not None and len(pieces):
        removed = _remove_unsupported(pieces, piece_parent, extended, support_fn, cfg.min_overlap, eps)
    out, origin, parent = _rejoin(pieces[~removed], piece_wall[~removed], extended[~removed], walls, eps)
    return Connected(out, origin, parent, pieces[removed])


def _remove_unsupported(
    pieces: Segments,
    parent: NDArray[np.intp],
    extended: NDArray[np.bool_],
    support_fn: SupportFn,
    min_overlap: float,
    eps: float,
) -> NDArray[np.bool_]:
    """(P,) pieces removed for want of data. Candidates: pieces of input walls (not the perpendicular
    joins) with support below `min_overlap`. A candidate goes when it is a span bridged between two
    junctions (behind a column: its removal leaves no free end) or an extension in the original
    direction that does not close a corner (both its ends meeting exactly one other piece: removing it
    would open the room). Removals are made one at a time, spans between junctions first, then the
    least supported, and each is judged on the pieces still there: two pieces meeting at one node
    (the span of a wall between a partition's two faces, and one face's unseen root) must not both go,
    which would leave the face and the wall with free ends."""
    removed = np.zeros(len(pieces), dtype=bool)
    candidates = np.flatnonzero(parent >= 0)
    if len(candidates) == 0:
        return removed
    support = np.asarray(support_fn(pieces[candidates], parent[candidates]), dtype=np.float64)
    weak = support < min_overlap
    candidates, support = candidates[weak], support[weak]
    if len(candidates) == 0:
        return removed
    node = _point_clusters(np.concatenate([pieces[:, :2], pieces[:, 2:]]), eps)
    n = len(pieces)
    ends = np.column_stack([node[:n], node[n:]])
    deg = np.bincount(node)
    initially_junction = (deg[ends[candidates, 0]] >= 3) & (deg[ends[candidates, 1]] >= 3)
    for k in candidates[np.lexsort((support, ~initially_junction))]:
        d0, d1 = deg[ends[k, 0]], deg[ends[k, 1]]
        junction = d0 >= 3 and d1 >= 3
        corner = d0 == 2 and d1 == 2
        if junction or (extended[k] and not corner):
            removed[k] = True
            deg[ends[k]] -= 1
    return removed


def _extend_and_trim(walls: list[_Wall], T: float, trim: float, sin_tol: float) -> None:
    """Move every end to the best intersection with a non-parallel line when the end moves out at most T
    or back at most `trim`, and the intersection lies within T of the other segment (5.2.5.2, fig 5.14
    a-c). All walls are judged against the segments as they were before this step."""
    if len(walls) < 2:
        return
    segs = np.array([w.as_segment() for w in walls])
    A, D = segs[:, :2], segs[:, 2:] - segs[:, :2]
    Lv = np.hypot(D[:, 0], D[:, 1])
    U = np.array([w.u for w in walls])
    for i, w in enumerate(walls):
        ok = np.abs(U[i, 0] * U[:, 1] - U[i, 1] * U[:, 0]) >= sin_tol
        ok[i] = False
        if not ok.any():
            continue
        den = np.where(ok, U[i, 0] * D[:, 1] - U[i, 1] * D[:, 0], 1.0)
        qp = A - w.a
        t = (qp[:, 0] * D[:, 1] - qp[:, 1] * D[:, 0]) / den  # along wall i (unit direction)
        sj = (qp[:, 0] * U[i, 1] - qp[:, 1] * U[i, 0]) / den  # along segment j (0..1)
        beyond = np.maximum(0.0, np.maximum(-sj, sj - 1.0)) * Lv  # distance of the hit outside segment j
        length = w.t1 - w.t0
        new = {}
        for e, t_end, outward in ((0, w.t0, -1.0), (1, w.t1, 1.0)):
            move = (t - t_end) * outward  # > 0 extends, < 0 trims
            valid = (
                ok & (move <= T) & (-move <= trim) & (beyond <= T) & ~((move < 0) & (-move > 0.5 * length))
            )
            if valid.any():
                score = np.where(valid, np.abs(move) + beyond, np.inf)
                new[e] = float(t[int(np.argmin(score))])
        w.t0 = new.get(0, w.t0)
        w.t1 = new.get(1, w.t1)


def _free_ends(walls: list[_Wall], eps: float) -> list[tuple[int, int]]:
    segs = np.array([w.as_segment() for w in walls]).reshape(-1, 4)
    ends = np.concatenate([segs[:, :2], segs[:, 2:]])
    owner = np.concatenate([np.arange(len(walls))] * 2)
    which = np.repeat([0, 1], len(walls))
    dist = point_segment_distances(ends, segs)
    dist[np.arange(len(ends)), owner] = np.inf
    free = dist.min(axis=1) > eps if len(walls) > 1 else np.ones(len(ends), dtype=bool)
    return [(int(owner[k]), int(which[k])) for k in np.flatnonzero(free)]


def _join_free_ends(
    walls: list[_Wall],
    T: float,
    eps: float,
    sin_tol: float,
    offset_tol: float,
    interior_xy: NDArray | None = None,
    support_fn: SupportFn | None = None,
) -> None:
    """Join each free end perpendicularly to the nearest parallel line within T whose segment (lengthened by
    T at a free end) it meets; that end of the other wall is moved to the foot when needed (fig 5.14 d-e,
    a step between parallel walls). With `interior_xy`, the ends of walls whose lines pass nearer that point
    go first; with `support_fn`, a join that could go anywhere between the two walls' ends goes where its
    data is (at least 0.1 more support than at the first end)."""
    n_orig = len(walls)
    done: set[tuple[int, int]] = set()
    ends = _free_ends(walls, eps)
    if interior_xy is not None and len(ends) > 1:
        c = np.asarray(interior_xy, dtype=np.float64).reshape(2)
        dist = [abs(float((c - walls[i].a) @ np.array([-walls[i].u[1], walls[i].u[0]]))) for i, _ in ends]
        ends = [ends[k] for k in np.argsort(dist, kind="stable")]
    for i, e in ends:
        if (i, e) in done:
            continue
        w = walls[i]
        p = w.end(e)
        nrm = np.array([-w.u[1], w.u[0]])
        best = None
        for j in range(n_orig):
            if j == i:
                continue
            v = walls[j]
            if abs(w.u[0] * v.u[1] - w.u[1] * v.u[0]) >= sin_tol:
                # not parallel: a perpendicular wall is never met by the ray along the normal, and an oblique
                # one meets it at the corner's intersection, where extension closes it (with the wider reach
                # when needed); a join there would make a wall at neither direction
                continue
            hit = line_intersection(np.concatenate([p, p + nrm]), v.as_segment())
            if hit is None:
                continue
            x, s, _ = hit
            if abs(s) > T or abs(s) < offset_tol:
                continue  # too far, or the same line (collinear pieces are joined by merge_segments)
            tv = float((x - v.a) @ v.u)
            lo, hi = v.t0, v.t1
            need = 0.0
            if tv < lo - eps:
                need = lo - tv
                if need > T or (j, 0) in done or not _is_free(walls, j, 0, eps):
                    continue
            elif tv > hi + eps:
                need = tv - hi
                if need > T or (j, 1) in done or not _is_free(walls, j, 1, eps):
                    continue
            score = abs(s) + need
            if best is None or score < best[0]:
                best = (score, j, x, tv)
        if best is None:
            continue
        _, j, x, tv = best
        v = walls[j]
        need = max(v.t0 - tv, tv - v.t1, 0.0)
        if support_fn is not None and need > eps:
            # the join may go anywhere between our end and the other wall's: where the data holds most of it
            # (the unseen wall's own few points), else at our end (the interior side's, taken first)
            out = w.u if e == 1 else -w.u
            steps = np.linspace(0.0, need, int(np.clip(math.ceil(need / (offset_tol / 5)), 2, 50)) + 1)
            cand = np.column_stack([p + steps[:, None] * out, x + steps[:, None] * out])
            sup = np.asarray(support_fn(cand, np.full(len(cand), -1, dtype=np.intp)), dtype=np.float64)
            if sup.max() > sup[0] + 0.1:
                k = int(np.argmax(sup))
                if e == 1:
                    w.t1 += steps[k]
                else:
                    w.t0 -= steps[k]
                p, x = cand[k, :2], cand[k, 2:]
                tv = float((x - v.a) @ v.u)
        if tv < v.t0 + eps:
            v.t0 = min(v.t0, tv)
            done.add((j, 0))
        elif tv > v.t1 - eps:
            v.t1 = max(v.t1, tv)
            done.add((j, 1))
        d = x - p
        L = float(np.hypot(*d))
        walls.append(_Wall(p.copy(), d / L, 0.0, L, 0.0, 0.0, -1, perpendicular=True))
        done.add((i, e))


def _is_free(walls: list[_Wall], j: int, e: int, eps: float) -> bool:
    p = walls[j].end(e)
    others = np.array([w.as_segment() for k, w in enumerate(walls) if k != j]).reshape(-1, 4)
    return len(others) == 0 or float(point_segment_distances(p[None], others).min()) > eps


def _node_pieces(walls: list[_Wall], eps: float) -> tuple[Segments, NDArray, NDArray, NDArray]:
    """Split every wall at the ends of other walls lying on it and at the ends of its observed span. Returns pieces (P, 4), the input index of
    each piece's wall (-1 for perpendicular joins), the wall list index, and whether the piece lies
    (mostly) outside its wall's observed span."""
    segs = np.array([w.as_segment() for w in walls]).reshape(-1, 4)
    ends = np.concatenate([segs[:, :2], segs[:, 2:]])
    pieces, parent, wall_idx, extended = [], [], [], []
    for k, w in enumerate(walls):
        t = (ends - w.a) @ w.u
        off = np.abs((ends - w.a) @ np.array([-w.u[1], w.u[0]]))
        on = (off <= eps) & (t > w.t0 + eps) & (t < w.t1 - eps)
        # the observed ends cut too, so that every extension is a piece of its own (judged on its data)
        obs = np.array([w.obs0, w.obs1])
        obs = obs[(obs > w.t0 + eps) & (obs < w.t1 - eps)] if not w.perpendicular else obs[:0]
        cuts = np.unique(np.concatenate([[w.t0, w.t1], t[on], obs]))
        for ta, tb in itertools.pairwise(cuts):
            if tb - ta <= eps:
                continue
            pa, pb = w.a + ta * w.u, w.a + tb * w.u
            pieces.append([pa[0], pa[1], pb[0], pb[1]])
            parent.append(w.parent)
            wall_idx.append(k)
            overlap = max(0.0, min(tb, w.obs1) - max(ta, w.obs0))
            extended.append(w.perpendicular or overlap < 0.5 * (tb - ta))
    return (
        np.array(pieces).reshape(-1, 4),
        np.array(parent, dtype=np.intp),
        np.array(wall_idx, dtype=np.intp),
        np.array(extended, dtype=bool),
    )


def _point_clusters(points: NDArray, tol: float) -> NDArray[np.intp]:
    """(P,) cluster label of every point: points chained closer than tol share one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    pairs = cKDTree(points).query_pairs(max(tol, 0.0), output_type="ndarray")
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(adj, directed=False)[1].astype(np.intp)


def _rejoin(
    pieces: Segments, wall_idx: NDArray, extended: NDArray, walls: list[_Wall], eps: float
) -> tuple[Segments, NDArray[np.str_], NDArray[np.intp]]:
    """Consecutive kept pieces of the same wall become one wall again."""
    out, origin, parent = [], [], []
    for k in np.unique(wall_idx):
        m = np.flatnonzero(wall_idx == k)
        w = walls[k]
        ta = (pieces[m, :2] - w.a) @ w.u
        tb = (pieces[m, 2:] - w.a) @ w.u
        order = np.argsort(ta)
        run_start, run_end, run_obs = ta[order[0]], tb[order[0]], not extended[m[order[0]]]
        for o in [*order[1:], None]:
            if o is not None and ta[o] <= run_end + eps:
                run_end = max(run_end, tb[o])
                run_obs = run_obs or not extended[m[o]]
                continue
            pa, pb = w.a + run_start * w.u, w.a + run_end * w.u
            out.append([pa[0], pa[1], pb[0], pb[1]])
            origin.append(OBSERVED if run_obs else EXTENDED)
            parent.append(w.parent)
            if o is not None:
                run_start, run_end, run_obs = ta[o], tb[o], not extended[m[o]]
    return np.array(out).reshape(-1, 4), np.array(origin, dtype=str), np.array(parent, dtype=np.intp)


# ---------------------------------------------------------------- graph and rooms


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
    label = _point_clusters(pts, tol)
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
