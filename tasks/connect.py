"""Wall topology from regularized lines (thesis 5.2.5.2), shared by wall modelling and plan vectorization:
ends extended or trimmed to intersections, free ends joined perpendicularly to parallel walls, extensions
without data removed. Like `tasks.lines`, it reads every length in the unit of the segments.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tasks.lines import (
    LinesConfig,
    Segments,
    as_segments,
    line_intersection,
    point_clusters,
    point_segment_distances,
)

SupportFn = Callable[[NDArray[np.float64], NDArray[np.intp]], NDArray[np.float64]]
"""support_fn(pieces (P, 4), parent (P,) index into connect's input, -1 for new pieces) -> (P,) share 0..1
of each piece's length backed by data."""

OBSERVED = "observed"
EXTENDED = "extended"


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
    step_chain: NDArray | None = None,
) -> Connected:
    """`connect` with the parent of every wall and the removed pieces.

    Two parallel walls closer than `cfg.offset_tol_m` are pieces of one line (`merge_segments` joins them
    when their gap allows) and are not joined by a perpendicular wall, unless `step_chain` (N,), each
    segment's chain of collinear pieces (`MergedLines.chain`), says that merging split them at a step (the
    same chain, which its data showed to be two walls a few cm apart): that step is joined. Two pieces of
    different chains a little apart (the two sides of a door, offset by registration noise) stay unjoined:
    nothing showed a step between them.

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

    _extend_and_trim(
        walls, T, T if cfg.trim_m is None else min(T, float(cfg.trim_m)), sin_tol, max(cfg.offset_tol_m, eps)
    )
    chain = None if step_chain is None else np.asarray(step_chain, dtype=np.intp).reshape(len(segments))
    _join_free_ends(walls, T, eps, sin_tol, max(cfg.offset_tol_m, eps), interior_xy, support_fn, chain)
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
    node = point_clusters(np.concatenate([pieces[:, :2], pieces[:, 2:]]), eps)
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


def _extend_and_trim(
    walls: list[_Wall], T: float, trim: float, sin_tol: float, offset_tol: float = 0.0
) -> None:
    """Move every end to the best intersection with a non-parallel line when the end moves out at most T
    or back at most `trim`, and the intersection lies within T of the other segment (5.2.5.2, fig 5.14
    a-c). An end does not move out past where a parallel line closer than `offset_tol` begins (the other
    side of a step of a few cm, or the same wall's next piece: the extension would run along it, and the
    room's outline double back). All walls are judged against the segments as they were before this
    step."""
    if len(walls) < 2:
        return
    segs = np.array([w.as_segment() for w in walls])
    A, D = segs[:, :2], segs[:, 2:] - segs[:, :2]
    Lv = np.hypot(D[:, 0], D[:, 1])
    U = np.array([w.u for w in walls])
    for i, w in enumerate(walls):
        cross = np.abs(U[i, 0] * U[:, 1] - U[i, 1] * U[:, 0])
        ok = cross >= sin_tol
        ok[i] = False
        if not ok.any():
            continue
        # parallel lines within offset_tol: how far each end may move out before running along one
        near = (cross < sin_tol) & (
            np.abs((0.5 * (A + segs[:, 2:]) - w.a) @ np.array([-w.u[1], w.u[0]])) <= offset_tol
        )
        near[i] = False
        tn = np.sort(np.stack([(A[near] - w.a) @ w.u, (segs[near, 2:] - w.a) @ w.u]), axis=0)  # (2, K)
        # (end 0, end 1): up to the nearest such line beyond the end; none where one already runs past it
        room = (
            float(np.min(np.maximum(w.t0 - tn[1], 0.0)[tn[0] < w.t0], initial=np.inf)),
            float(np.min(np.maximum(tn[0] - w.t1, 0.0)[tn[1] > w.t1], initial=np.inf)),
        )
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
                ok
                & (move <= min(T, room[e]))
                & (-move <= trim)
                & (beyond <= T)
                & ~((move < 0) & (-move > 0.5 * length))
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
    chain: NDArray | None = None,
) -> None:
    """Join each free end perpendicularly to the nearest parallel line within T whose segment (lengthened by
    T at a free end) it meets; that end of the other wall is moved to the foot when needed (fig 5.14 d-e,
    a step between parallel walls). A line closer than `offset_tol` is the same line, unless `chain` (by
    input index) puts both walls in one chain split at a step. With `interior_xy`, the ends of walls whose lines pass nearer that point
    go first; with `support_fn`, a join that could go anywhere between the two walls' ends goes where its
    data is (at least 0.1 more support than at the first end), unless it is no longer than twice
    `offset_tol` (a step of a few cm, whose support is the two walls' own data)."""
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
            step = chain is not None and chain[w.parent] >= 0 and chain[w.parent] == chain[v.parent]
            if abs(s) > T or abs(s) < (eps if step else offset_tol):
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
        # a join no longer than twice `offset_tol` (a step of a few cm) lies that near one wall's data or the
        # other's all along: its support is theirs, and says nothing of where the step is. It stays at our
        # end, the interior side's wall's: its end is a convex corner, seen wherever that wall is, while the
        # other wall's stretch beside the step is in the step's shadow from along the wall
        if support_fn is not None and need > eps and abs(float((x - p) @ nrm)) > 2 * offset_tol:
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
        else:
            # the foot lies inside the other wall: where two parallel walls a step apart overlap past the
            # step (each one's data ran on a little into the step's corner), the other wall's free end
            # behind the foot is cut back to it, else it would be joined a second time, making two steps
            out = w.u if e == 1 else -w.u
            k = 0 if float(out @ v.u) > 0 else 1
            back = abs(tv - (v.t0 if k == 0 else v.t1))
            if (j, k) not in done and back <= min(T, 0.5 * (v.t1 - v.t0)) and _is_free(walls, j, k, eps):
                if k == 0:
                    v.t0 = tv
                else:
                    v.t1 = tv
                done.add((j, k))
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
