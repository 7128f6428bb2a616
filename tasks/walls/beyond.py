"""Walls of the next rooms seen through the room's doors, for a slice with nothing seen above it (a handheld
scan): the lines behind a wall of the room that run along it (`beyond_the_room`) or across it
(`across_beyond_the_room`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tasks.lines import angles, lengths, line_intersection, point_segment_distances, sample_segments
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import collinear_with, walked_round


def _judged(lines: NDArray, gone: NDArray | None) -> tuple[NDArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """The lines (M, 4) as floats, the (M,) result with none found yet, and `gone` as an (M,) mask."""
    lines = np.asarray(lines, dtype=np.float64)
    none = np.zeros(len(lines), dtype=bool)
    return lines, none, none.copy() if gone is None else np.asarray(gone, dtype=bool)


def _line_frames(lines: NDArray, interior: NDArray) -> tuple[NDArray, ...]:
    """Per line (M, 4): length, whether it has any, unit direction, unit normal, the normal pointing away
    from `interior` (the line's back) and its angle."""
    L = lengths(lines)
    ok = L > 0
    u = np.zeros((len(lines), 2))
    u[ok] = (lines[ok, 2:] - lines[ok, :2]) / L[ok, None]
    normal = np.column_stack([-u[:, 1], u[:, 0]])
    back = normal.copy()
    back[((np.asarray(interior) - lines[:, :2]) * back).sum(axis=1) > 0] *= -1
    return L, ok, u, normal, back, angles(lines)


def beyond_the_room(
    lines: NDArray,
    interior: NDArray | None,
    cfg: WallsConfig,
    angle_tol_deg: float,
    gone: NDArray | None = None,
) -> NDArray[np.bool_]:
    """(M,) lines seen beyond the room, for a slice with nothing seen above it (a handheld scan): a wall of
    the next room seen through a door whose own wall the capture barely saw (`seen_through_gaps` needs that
    wall's data in front of it). A line L is such a wall when it lies wholly more than
    `beyond_room_min_depth_m` behind the line of a line W of the room (on its side away from the room's
    `interior`: deeper than furniture stands before a wall) and runs along W (within 45°: a wall drawn from
    the few points seen through a door may lie some degrees off), the room's other lines run along the whole
    of L (to within `lines.max_gap_m`: the next room's wall goes on past this room's by the partition's
    thickness and as far as the door's view reaches; a wing further out has side walls), and no line of the
    room lies between W's line and L's (more than `thin_wall_max_m` from either) within `lines.max_gap_m` of
    L's span: an L-shaped room's far wing or an alcove is joined to the rest by its side walls, which lie
    there; and no wall across W's line, seen only in pieces in line with each other, crosses it away from W
    and reaches behind it as deep as L (`_pieces_cross`: the wing's side wall seen near its ends). W must
    bound the room: no line of the room runs on from W's line to behind it (the room goes on there: an
    L-room's wing, the far side of a partition), and L is shorter than W or W's collinear pieces together (a
    wall with a door in it), or W ends at a corner (a line across it at one of its ends, running into the room
    only: a free-standing counter has none; the two lines may cross up to `thin_wall_max_m` past W's end and
    `lines.max_gap_m` past the other's, the corner's last stretch unseen, as a sparse capture leaves it).
    W bounds the room only when the lines across it reach behind its line (more than `thin_wall_max_m`)
    over less in all than W's collinear pieces span: a short line far out (a piece of the next room seen
    through a door) has the room's own walls behind it, and an L-room's inner wall has the wing's sides.
    `gone` (M,) are lines already found beyond the room (`across_beyond_the_room`): they are no line of the
    room, so they neither stop W nor join L to it (the building's wall going on past the room's corner is
    no wing's side wall). `beyond_room_min_depth_m` 0 switches the test off."""
    lines, out, gone = _judged(lines, gone)
    m = len(lines)
    if cfg.beyond_room_min_depth_m <= 0 or interior is None or m < 3:
        return out
    L, ok, u, normal, back, ang = _line_frames(lines, interior)
    cos_tol = math.cos(math.radians(angle_tol_deg))
    sin_loose = math.sin(math.radians(2 * angle_tol_deg))
    pts, owner = sample_segments(lines, 0.05)
    thin = cfg.thin_wall_max_m
    end_tol = cfg.thin_wall_end_tol_m
    # the room's side of a line is judged by the interior: a line passing nearer it than a thin wall's
    # thickness (a short piece in a corridor, whose lines' centre lies by its long wall) has no side to tell;
    # the walls seen through a door pull the centre towards the door's wall, by more than half a metre in a
    # room seen mostly along that wall
    clear = np.abs(((np.asarray(interior) - lines[:, :2]) * normal).sum(axis=1)) >= cfg.thin_wall_max_m
    step = np.bincount(owner, minlength=m)
    step = np.where(step > 1, L / np.maximum(step - 1, 1), 0.0)  # each sample's share of its line's length
    # a partition the capture walked round bounds nothing: the room lies on both its sides
    partition = walked_round(lines, thin, cfg.lines.offset_tol_m)
    for w in np.argsort(-L):
        if not ok[w] or out[w] or gone[w] or not clear[w] or partition[w]:
            continue
        rel = pts - lines[w, :2]
        depth, t = rel @ back[w], rel @ u[w]
        deepest = np.full(m, -np.inf)
        np.maximum.at(deepest, owner, depth)
        nearest = np.full(m, np.inf)
        np.minimum.at(nearest, owner, depth)
        crossing = (nearest <= end_tol) & (deepest > thin) & ~gone
        crossing[w] = False
        if crossing.any():
            continue  # a line of the room runs on from W's line behind it: the room goes on there
        # ...or a wall's pieces in line do, the stretch between them unseen: the room goes on behind W as
        # deep as they reach
        same = collinear_with(lines, ang, normal, w, cos_tol, cfg.lines.offset_tol_m)
        span = np.concatenate(
            [(lines[same, :2] - lines[w, :2]) @ u[w], (lines[same, 2:] - lines[w, :2]) @ u[w]]
        )
        wing = _pieces_cross(
            lines, ang, normal, w, span, nearest, deepest, ~gone, cos_tol, end_tol, thin, cfg
        )
        shallow = np.bincount(owner, depth <= cfg.beyond_room_min_depth_m, m) > 0
        # W is the room's boundary, not a free-standing thing in it, when it is longer than L, its collinear
        # pieces (a wall with a door in it) together are, or it ends at a corner: a line across it at one of
        # its ends that runs into the room only
        sides = (np.abs(np.cos(ang - ang[w])) < math.sqrt(0.5)) & ~gone & ~out
        if float(step[owner][(depth > thin) & sides[owner]].sum()) >= max(L[w], float(np.ptp(span))):
            continue  # the room's walls across W reach behind it as far as W runs: W does not bound the room
        across = (np.abs(np.cos(ang - ang[w])) <= sin_loose) & (deepest <= end_tol)
        across[w] = False
        corner = bool(across.any()) and _meets_at_end(
            lines[w], lines[across], end_tol, thin, cfg.lines.max_gap_m
        )
        # where the lines across W that reach its line stand along it: the room's corners on W's line (the
        # room goes on behind W past none of them: a wing there would leave that wall's end inside it)
        ends_on_w = across & (deepest >= -end_tol)
        corner_t = np.array([float(np.median(t[owner == a])) for a in np.flatnonzero(ends_on_w)])
        # L runs along W (closer to its direction than to its normal; a wall drawn from the few points seen
        # through a door may lie some degrees off), not across it: a line across W's line is a wall joining it
        along = np.abs(np.cos(ang - ang[w])) >= math.sqrt(0.5)
        cand = ~shallow & ~out & ~gone & along & ((L < max(L[w], float(np.ptp(span)))) | corner)
        cand[w] = False
        joins = nearest <= cfg.beyond_room_min_depth_m + cfg.lines.max_gap_m
        for c in np.flatnonzero(cand):
            others = ~collinear_with(lines, ang, normal, c, cos_tol, cfg.lines.offset_tol_m) & ~out & ~gone
            others[w] = True
            mine = owner == c
            lo, hi = float(t[mine].min()), float(t[mine].max())
            rest = others[owner]
            if not rest.any():
                continue
            reach = cfg.lines.max_gap_m
            first, last = float(t[rest].min()), float(t[rest].max())
            if (first > lo + reach and not (corner_t <= first + end_tol).any()) or (
                last < hi - reach and not (corner_t >= last - end_tol).any()
            ):
                continue  # beyond the end of the room's lines, where no corner ends them: an L-room's wing
            far = float(depth[mine].min())
            if far <= wing + thin:
                continue  # a wing's wall: its side wall's pieces reach it from in front of W's line
            # a line joining L to the room (a wing's side wall) starts within furniture's depth and the
            # largest occlusion (`lines.max_gap_m`) of W's line: one that stays deeper behind it (the next
            # room's wall across, seen through the same door) joins nothing of this room to L
            between = (
                rest
                & joins[owner]
                & (owner != w)
                & (depth > thin)
                & (depth < far - thin)
                & (t >= lo - cfg.lines.max_gap_m)
                & (t <= hi + cfg.lines.max_gap_m)
            )
            if not between.any():
                out[c] = True
    return out | past_a_corner(lines, interior, cfg, out | gone)


def _pieces_cross(
    lines: NDArray,
    ang: NDArray,
    normal: NDArray,
    w: int,
    span: NDArray,
    nearest: NDArray,
    deepest: NDArray,
    live: NDArray,
    cos_tol: float,
    end_tol: float,
    thin: float,
    cfg: WallsConfig,
) -> float:
    """How deep behind line w a wall across it reaches, seen in pieces in line with each other (`live`
    lines only) from w's line (`nearest`: a piece's least depth behind it, at most `end_tol`) to behind it
    (`deepest`: more than `thin`), crossing it further than the largest occlusion (`lines.max_gap_m`) from
    w and its pieces in line: an L-room's side wall seen near both its ends, running on past the line of the
    wing's inner wall w as far as the wing's far wall (-inf when none does). Where it crosses w's line by
    w, it meets w's wall at a corner: its piece behind is the next room's wall, in line with this one's
    (seen through a door in w's wall). `span`: where w and its pieces in line lie along w's line, from its
    first end. Lines within acos(`cos_tol`) of parallel are in line."""
    length = float(np.hypot(*(lines[w, 2:] - lines[w, :2])))
    reach = cfg.lines.max_gap_m
    across = live & (np.abs(np.cos(ang - ang[w])) < math.sqrt(0.5))
    wing = -math.inf
    for k in np.flatnonzero(across):
        if not across[k]:
            continue  # in a group judged already
        group = collinear_with(lines, ang, normal, k, cos_tol, cfg.lines.offset_tol_m) & live
        across &= ~group
        if nearest[group].min() > end_tol or deepest[group].max() <= thin:
            continue
        hit = line_intersection(lines[w], lines[k])
        if hit is not None and not span.min() - reach <= hit[1] * length <= span.max() + reach:
            wing = max(wing, float(deepest[group].max()))
    return wing


def past_a_corner(
    lines: NDArray, interior: NDArray, cfg: WallsConfig, gone: NDArray | None = None
) -> NDArray[np.bool_]:
    """(M,) lines seen past a corner of the room, for a slice with nothing seen above it: wholly behind the
    lines of two walls of the room across each other (more than `thin_wall_end_tol_m` behind both, more
    than `beyond_room_min_depth_m` behind one of them; behind: away from the room's `interior`), each of which
    lies wholly in front of the other's line (to within `thin_wall_end_tol_m`): a corner of the room,
    however much of it went unseen, with nothing of the room past it. An L-room's inner walls do not make
    one (the wing's inner wall runs from their crossing to behind the other), nor do the pieces of a wall
    crossing the other's line. Lines in `gone` are no walls of the room. The walls judged by lie more than
    `beyond_room_min_depth_m` from the interior (a line through it has no side to tell), and a line is judged
    past them only when it is shorter than the longer of the two: the room's walls are seen along more than
    a door shows of the next room's, and a furniture face and a door's jamb, a few decimetres each, make no
    corner to judge the room's far walls by."""
    lines, out, gone = _judged(lines, gone)
    m = len(lines)
    if cfg.beyond_room_min_depth_m <= 0 or interior is None or m < 3:
        return out
    L, ok, _, normal, back, ang = _line_frames(lines, interior)
    end_tol, deep = cfg.thin_wall_end_tol_m, cfg.beyond_room_min_depth_m
    clear = np.abs(((np.asarray(interior) - lines[:, :2]) * normal).sum(axis=1)) >= deep
    walls = np.flatnonzero(ok & clear & ~gone)
    ends = lines.reshape(-1, 2)
    # depth[i, j, k]: how far end k of line j lies behind line i
    depth = ((ends[None, :, :] - lines[:, None, :2]) * back[:, None, :]).sum(axis=2).reshape(m, m, 2)
    lo, hi = depth.min(axis=2), depth.max(axis=2)
    for i, a in enumerate(walls):
        for b in walls[i + 1 :]:
            if abs(math.cos(ang[a] - ang[b])) >= math.sqrt(0.5) or hi[a, b] > end_tol or hi[b, a] > end_tol:
                continue
            past = (
                ok
                & ~gone
                & ~out
                & (lo[a] > end_tol)
                & (lo[b] > end_tol)
                & (np.maximum(lo[a], lo[b]) > deep)
                & (L < max(L[a], L[b]))
            )
            out |= past
    return out


def _meets_at_end(w: NDArray, others: NDArray, tol_m: float, w_reach_m: float, reach_m: float) -> bool:
    """Whether one of `others` (K, 4) meets segment `w` at one of w's ends: an end of w within `tol_m` of
    the other segment, or the two lines crossing within `w_reach_m` of an end of w and `reach_m` of an end
    of the other (a corner whose last stretch neither wall's data reached)."""
    if (point_segment_distances(w.reshape(2, 2), others) <= tol_m).any():
        return True
    for o in others:
        hit = line_intersection(w, o)
        if hit is None:
            continue
        x = hit[0]
        if (
            min(np.hypot(*(x - w[:2])), np.hypot(*(x - w[2:]))) <= w_reach_m
            and min(np.hypot(*(x - o[:2])), np.hypot(*(x - o[2:]))) <= reach_m
        ):
            return True
    return False


def _in_front(live: NDArray, depth: NDArray, along: NDArray, end_tol: float) -> tuple[float, float] | None:
    """How far along W's line the room's lines in front of it (`live`, no end more than `end_tol` behind its
    line: `depth` (M, 2); their ends `along` W's line) reach: (least, most), None without such lines."""
    front = live & (depth.max(axis=1) <= end_tol)
    if not front.any():
        return None
    reach = along[front]
    return float(reach.min()), float(reach.max())


def _to_the_room_s_ends(
    lo: float,
    hi: float,
    foot: NDArray,
    depth: NDArray,
    across: NDArray,
    outward: NDArray,
    live: NDArray,
    along: NDArray,
    end_tol: float,
    deep: float,
) -> tuple[float, float]:
    """The span (`lo`, `hi`, along W's line) of a wall W seen in pieces, run on to the room's end walls: a
    line across (`across`) that reaches W's line or runs through it (`depth` (M, 2) of its ends behind that
    line: more than `end_tol` in front at one end, at most `end_tol` in front at the other, but no more than
    `deep` behind: a wall running on further behind may be an L-room's outer wall, its wing behind W; one
    ending on W's line is the room's corner, seen) whose `foot` on W's line lies past the span, where
    none of the room's lines in front (`live`, ends `along` W's line) goes further: the room's end, up to
    which W's wall ran unseen. Only for a W whose pieces span at least half of the room in front of it, and
    not past a line leaving W's line outward (`outward`) there: an L-room's wing starts where its inner wall
    turns away."""
    reach = _in_front(live, depth, along, end_tol)
    if reach is None:
        return lo, hi
    r0, r1 = reach
    if hi - lo < 0.5 * (r1 - r0):
        return lo, hi
    ends = (
        across
        & (depth.min(axis=1) < -end_tol)
        & (depth.max(axis=1) >= -end_tol)
        & (depth.max(axis=1) <= deep)
    )
    turns = foot[outward]
    new_lo = foot[ends & (foot < lo - end_tol) & (foot <= r0 + end_tol)]
    if len(new_lo) and not ((turns >= new_lo.min() - end_tol) & (turns <= lo + end_tol)).any():
        lo = float(new_lo.min())
    new_hi = foot[ends & (foot > hi + end_tol) & (foot >= r1 - end_tol)]
    if len(new_hi) and not ((turns <= new_hi.max() + end_tol) & (turns >= hi - end_tol)).any():
        hi = float(new_hi.max())
    return lo, hi


def across_beyond_the_room(
    lines: NDArray,
    interior: NDArray | None,
    cfg: WallsConfig,
    angle_tol_deg: float,
    gone: NDArray | None = None,
) -> tuple[NDArray, NDArray[np.bool_]]:
    """For a slice with nothing seen above it (a handheld scan): the walls of the next rooms that run
    *across* a wall W of this room behind W's line (away from the room's `interior`), seen through a door
    in W (`beyond_the_room` takes those that run along W). Returns (the lines, with those running on past
    a corner of the room cut there; (M,) lines beyond the room).

    W is a line of the room more than `lines.offset_tol_m` from the interior (a line through it has no
    side to tell; a corridor seen mostly along one wall has its lines' centre a few decimetres from that
    wall, on the room's side) that bounds the room: no line across it runs from the room through its line
    and on behind it other than at its ends (the room goes on there: a partition's face, an L-room's inner
    wall). Its collinear pieces are the lines parallel to it within `thin_wall_end_tol_m` of its line.
    Only lines shorter than their span are judged (the room's wall is seen along more than a wall seen
    through its door, and a short line across a wall, a door's jamb or a box's side, is no wall to judge
    by). The span runs on past W's pieces to the room's end wall where that crosses W's line no deeper than
    `beyond_room_min_depth_m` (`_to_the_room_s_ends`: W's wall went unseen up to the corner, and the end
    wall's data run on a little past it). A line L across W (nearer its normal than its direction) whose
    foot (where its line meets W's) lies within that span is beyond the room when
    - it lies wholly more than `thin_wall_end_tol_m` behind W's line and its foot lies on W's data, that
      far inside one of the pieces: nothing of the room lies behind the room's seen wall (the next room's
      partition standing on W's back face);
    - or it lies wholly that far behind in a gap of the pieces (a door; the next room's partition standing
      on W's back face at the door's jamb, or any deeper), and no other line comes within `lines.max_gap_m`
      of it (an alcove's back wall or a wing's far wall would hold it; the partition's other face, parallel
      within `thin_wall_max_m` and behind W too, does not, nor do W's pieces: the next room's wall seen
      beside a door's jamb comes within a door's width of it) nor leaves W's line outward within that of the
      foot (an alcove's or a wing's side);
    - or it stands on W's line (within `thin_wall_end_tol_m`) and reaches more than `thin_wall_max_m`
      behind, away from the span's ends, held by nothing but W's pieces and with no other line leaving W's
      line near it (no back wall or other side, as an alcove or a wing has): a partition at a door's jamb;
    - or it lies wholly behind in line with a wall of the room that ends on W's line at an end of the span
      (the room's corner) and reaches more than `beyond_room_min_depth_m` behind (deeper than furniture
      stands before a wall): the building's wall going on past the room's corner;
    - or it stands on W's line at a jamb (a piece of W ends there, nothing of W beside it on one side) and
      reaches behind it by more than `thin_wall_end_tol_m` but no more than `thin_wall_max_m`, held by
      nothing behind W's line but W's pieces and the other such lines: a door's reveal, the wall's own end
      face. At an end of the span (W seen only up to the door) only where no line of the room runs along W
      behind its line: there the room goes on behind it (W an alcove's side, the line the room's wall
      beside the alcove, the room's wall beyond it standing behind W's line).
    A line L whose foot lies past the span (where W's wall went unseen) is beyond the room when it lies
    wholly more than `beyond_room_min_depth_m` behind, held by nothing, with no line leaving W's line outward
    near its foot, and in line with no line of the room that comes within `lines.max_gap_m` of W's line: a
    wing's outer wall, whose other walls went unseen, goes on from a wall of the room near the line the wing
    opens through (an end wall seen only at its far corner is no such wall: the building's wall in line with
    it goes). So is a door's reveal there (standing on W's line, no deeper than `thin_wall_max_m`, held as
    above), where the room's lines in front of W's line reach past its foot on both sides (W's wall went
    unseen up to the door, the room still before it) and none runs along W behind its line.
    A line that runs from the room (more than `thin_wall_end_tol_m` in front of W's line) through W's line
    at an end of the span (or past it by less than `lines.max_gap_m`: W's wall unseen up to the corner; a
    wing opens wider than that) and on more than `beyond_room_min_depth_m` behind it is that corner's wall
    and the building's wall beyond it seen as one: it is cut at W's line. `gone` (M,) are lines already
    found beyond the room (`beyond_the_room`): they are no line of the room, so they are not judged, judge
    nothing and hold nothing (the next room's corner seen through a door, its other wall gone, holds this one
    no more). `beyond_room_min_depth_m` 0 switches the test off."""
    lines, out, gone = _judged(lines, gone)
    lines = lines.copy()
    m = len(lines)
    if cfg.beyond_room_min_depth_m <= 0 or interior is None or m < 3:
        return lines, out
    L, ok, u, normal, back, ang = _line_frames(lines, interior)
    cos_tol = math.cos(math.radians(angle_tol_deg))
    thin, end_tol, gap = cfg.thin_wall_max_m, cfg.thin_wall_end_tol_m, cfg.lines.max_gap_m
    deep = cfg.beyond_room_min_depth_m
    clear = np.abs(((np.asarray(interior) - lines[:, :2]) * normal).sum(axis=1)) >= cfg.lines.offset_tol_m
    apart = point_segment_distances(lines.reshape(-1, 2), lines).reshape(m, 2, m).min(axis=1)
    apart = np.minimum(apart, apart.T)  # the segments' distance: an end of either to the other
    # a partition the capture walked round bounds nothing: the room lies on both its sides
    partition = walked_round(lines, thin, cfg.lines.offset_tol_m)
    for w in np.argsort(-L):
        if not ok[w] or out[w] or gone[w] or not clear[w] or partition[w]:
            continue
        # its pieces: a wall at a few tenths of a degree off the next piece's angle misses it by centimetres
        same = collinear_with(lines, ang, normal, w, cos_tol, end_tol) & ~gone
        t0 = (lines[same, :2] - lines[w, :2]) @ u[w]
        t1 = (lines[same, 2:] - lines[w, :2]) @ u[w]
        pieces = np.column_stack([np.minimum(t0, t1), np.maximum(t0, t1)])
        lo, hi = float(pieces[:, 0].min()), float(pieces[:, 1].max())
        rel = lines.reshape(-1, 2) - lines[w, :2]
        depth = (rel @ back[w]).reshape(m, 2)
        along = (rel @ u[w]).reshape(m, 2)
        across = ok & ~out & ~gone & (np.abs(np.cos(ang - ang[w])) < math.sqrt(0.5))
        # where each line across meets W's line
        dd = depth[:, 1] - depth[:, 0]
        safe = np.where(np.abs(dd) > 1e-12, dd, 1.0)
        foot = np.where(
            np.abs(dd) > 1e-12, along[:, 0] - depth[:, 0] * (along[:, 1] - along[:, 0]) / safe, along[:, 0]
        )
        # the room's walls ending on W's line from the room's side, and those leaving it outward
        inside = across & (depth.min(axis=1) < -end_tol) & (depth.max(axis=1) <= end_tol)
        outward = across & (np.abs(depth.min(axis=1)) <= end_tol) & (depth.max(axis=1) > thin)
        lo, hi = _to_the_room_s_ends(
            lo, hi, foot, depth, across, outward, ok & ~out & ~gone, along, end_tol, deep
        )
        # at an end of the span, or past it by less than a wing's width (`lines.max_gap_m`: W's wall unseen
        # up to the corner; a wing opens wider than that)
        at_corner = ((foot >= lo - gap) & (foot <= lo + end_tol)) | (
            (foot >= hi - end_tol) & (foot <= hi + gap)
        )
        reveals = across & (np.abs(depth.min(axis=1)) <= end_tol) & (depth.max(axis=1) <= thin)
        # a line of the room along W behind W's line: the room goes on behind it (W an alcove's side, and the
        # room's wall beyond the alcove standing behind its line)
        behind = (
            ok & ~out & ~gone & (np.abs(np.cos(ang - ang[w])) >= cos_tol) & (depth.min(axis=1) > end_tol)
        ).any()
        if (across & (depth.min(axis=1) < -end_tol) & (depth.max(axis=1) > thin) & ~at_corner).any():
            continue  # a wall of the room runs on from the room through W's line: the room goes on behind it
        for c in np.flatnonzero(across & (L < hi - lo)):
            if depth[c].min() < -end_tol and depth[c].max() > deep:
                if at_corner[c]:
                    k = int(np.argmax(depth[c]))
                    a, b = lines[c, 2 * (1 - k) : 4 - 2 * k], lines[c, 2 * k : 2 * k + 2]
                    lines[c, 2 * k : 2 * k + 2] = a + (b - a) * (
                        -depth[c, 1 - k] / (depth[c, k] - depth[c, 1 - k])
                    )
                continue
            # the partition's other face (parallel, within a thin wall's thickness, behind W too) holds nothing
            face = collinear_with(lines, ang, normal, c, cos_tol, thin) & (depth.min(axis=1) > end_tol)
            near = (apart[c] <= gap) & ~face & ~gone
            near[c] = False
            wing = outward & (np.abs(foot - foot[c]) <= gap)
            wing[c] = False
            # what holds a door's reveal: a line near it behind W's line, other than W's pieces and the reveals
            held = (near & ~same & ~reveals & (depth.max(axis=1) > end_tol)).any()
            if not lo - end_tol <= foot[c] <= hi + end_tol:
                # beyond the span's end (where W's wall went unseen): deeper than furniture, held by nothing
                # and in line with no line of the room coming within a gap of W's line (the wall of a wing,
                # whose other walls went unseen, goes on from one of the room's near the line it opens by)
                in_line = collinear_with(lines, ang, normal, c, cos_tol, end_tol) & ~out & ~gone
                in_line &= depth.max(axis=1) >= -gap
                in_line[c] = False
                # ...and not past an end of W where a wall of the room leaves W's line outward: the room goes on
                # behind W's line there (W is an L-room's inner step, the line the wing's far wall)
                end = lo if foot[c] < lo else hi
                turned = outward & (np.abs(foot - end) <= end_tol)
                if depth[c].min() > deep and not (near | wing | in_line | turned).any():
                    out[c] = True
                # a door's reveal where W's wall went unseen up to the door, the room still in front of W's line
                room = _in_front(ok & ~out & ~gone, depth, along, end_tol)
                if (
                    reveals[c]
                    and depth[c].max() > end_tol
                    and room is not None
                    and room[0] < foot[c] < room[1]
                    and not (held or wing.any() or behind)
                ):
                    out[c] = True
                continue
            if outward[c]:
                # standing on W's line at a door's jamb, away from the room's corners, and held by nothing but
                # W's own pieces: no back wall or other side as an alcove or a wing has
                if lo + end_tol < foot[c] < hi - end_tol and not (near & ~same).any() and not wing.any():
                    out[c] = True
                continue
            if depth[c].min() <= end_tol:
                # a door's reveal: standing on W's line at a jamb (a gap of the pieces beside it; at an end of
                # the span, the room not going on behind W's line), reaching behind it no more than a wall's
                # thickness, and held by nothing behind W's line but W's pieces and the other reveals (the
                # room's walls meeting W's line from the room's side hold nothing behind it): the wall's own
                # end face, no wall of the room
                beside = foot[c] + np.array([-2 * end_tol, 2 * end_tol])
                open_side = ~((pieces[:, :1] <= beside) & (beside <= pieces[:, 1:])).any(axis=0)
                jamb = (open_side[0] and bool((np.abs(pieces[:, 0] - foot[c]) <= end_tol).any())) or (
                    open_side[1] and bool((np.abs(pieces[:, 1] - foot[c]) <= end_tol).any())
                )
                at_end = not lo + end_tol < foot[c] < hi - end_tol
                if (
                    jamb
                    and abs(depth[c].min()) <= end_tol
                    and end_tol < depth[c].max() <= thin
                    and not held
                    and not wing.any()
                    and not (at_end and behind)
                ):
                    out[c] = True
                continue
            on_data = bool(((pieces[:, 0] + end_tol <= foot[c]) & (foot[c] <= pieces[:, 1] - end_tol)).any())
            lined = (
                inside
                & at_corner
                & (np.abs(np.cos(ang - ang[c])) >= cos_tol)
                & (np.abs((lines[:, :2] - lines[c, :2]) @ normal[c]) <= cfg.lines.offset_tol_m)
            )
            if (
                on_data
                or (not (near & ~same).any() and not wing.any())
                or (lined.any() and depth[c].max() > deep)
            ):
                out[c] = True
    return lines, out
