"""The vector side of plan parsing: skeleton and Hough segments, straight walls from the line code shared
with the walls stage (`tasks.lines`: clustering, regularization; `tasks.connect`: extension and trimming),
each wall centred on its ink band and its thickness measured across it."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray
from skimage.morphology import skeletonize

from tasks import lines
from tasks.connect import connect
from tasks.plan.config import PlanConfig


def sample_mask(mask_f: NDArray[np.float32], pts: NDArray) -> NDArray[np.float32]:
    """Bilinear samples of a float raster at (N, 2) pixel positions (u, v); 0 outside."""
    if len(pts) == 0:
        return np.zeros(0, np.float32)
    # as a (rows, 1) map, in pieces: OpenCV's remap takes fewer than 32767 rows
    mx = pts[:, 0].astype(np.float32).reshape(-1, 1)
    my = pts[:, 1].astype(np.float32).reshape(-1, 1)
    step = 32000
    return np.concatenate(
        [
            cv2.remap(
                mask_f,
                mx[k : k + step],
                my[k : k + step],
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0,
            )[:, 0]
            for k in range(0, len(mx), step)
        ]
    )


def _thickness_px(
    seg: NDArray,
    mask_f: NDArray[np.float32],
    max_px: float,
    lines_f: NDArray[np.float32] | None = None,
    bounded_runs: bool = False,
) -> tuple[float, float]:
    """(median width, median offset of the run's centre along the left normal) of the ink run across
    the centreline, sampled along the middle of the wall: the distance across the wall raster, and a
    sub-pixel correction of the skeleton's position (thinning is biased by up to a pixel).

    With `lines_f` (the drawn lines before outline walls were filled), a run that holds paper between
    two lines is an outline-drawn wall: its width is the distance between the centres of its first and
    last line (CAD draws a wall's faces as lines centred on the faces), not the outer width of the ink.

    With `bounded_runs`, the stations whose run reaches the end of the window (+-max_px) are left out
    while any other is found: a wall crossing there runs on along the normal."""
    a, b = seg[:2], seg[2:]
    d = b - a
    L = float(np.hypot(*d))
    if L <= 0:
        return 0.0, 0.0
    u = d / L
    nrm = np.array([-u[1], u[0]])
    ts = np.linspace(0.15, 0.85, max(3, min(40, int(L / 2))))
    step = 0.25
    offs = np.arange(-max_px, max_px + step, step)
    pts = ((a + ts[:, None, None] * d) + offs[None, :, None] * nrm).reshape(-1, 2)
    vals = sample_mask(mask_f, pts).reshape(len(ts), len(offs))
    drawn = None if lines_f is None else sample_mask(lines_f, pts).reshape(len(ts), len(offs))
    c = len(offs) // 2
    widths, centres, bounded = [], [], []
    for r, row in enumerate(vals):
        inside = row > 0.01  # down to the bilinear tails, so the run's mass is the full width
        if not inside[c - 4 : c + 5].any():
            continue
        j = c - 4 + int(np.argmax(row[c - 4 : c + 5]))
        lo = j
        while lo > 0 and inside[lo - 1]:
            lo -= 1
        hi = j
        while hi < len(row) - 1 and inside[hi + 1]:
            hi += 1
        mass = row[lo : hi + 1]
        width = float(mass.sum()) * step
        if drawn is not None:
            faces = _line_centres(drawn[r, lo : hi + 1], offs[lo : hi + 1])
            if len(faces) >= 2:
                width = faces[-1] - faces[0]
        widths.append(width)
        centres.append(float((mass * offs[lo : hi + 1]).sum() / max(float(mass.sum()), 1e-9)))
        bounded.append(lo > 0 and hi < len(row) - 1)
    if not widths:
        return 0.0, 0.0
    # a run that reaches the end of the window is no wall's width: a wall crossing there runs on along
    # the normal. A short wall between two doors with a crossing wall over half its stations measured
    # as thick as that wall is long (drawing 323's photo: its line sealed a room's corner off), and a
    # door's jamb that Hough kept only the inner half of, over the wall it stems from (320's scan), was
    # dropped as a spur shorter than half its thickness. Taken in heavy-pen drawings only: on MLSTRUCT
    # floor 302 (CAD) it added a wall (completeness 0.9518 -> 0.9506, correctness 0.9782 -> 0.9759)
    ok = np.asarray(bounded) if bounded_runs and any(bounded) else np.ones(len(widths), bool)
    return float(np.median(np.asarray(widths)[ok])), float(np.median(np.asarray(centres)[ok]))


def _line_centres(profile: NDArray, offs: NDArray) -> list[float]:
    """Centres (mass-weighted offsets) of the ink runs of a profile across a wall, separated by paper."""
    out = []
    for k, e in lines.true_runs(profile > 0.5):
        w = profile[k:e]
        out.append(float((w * offs[k:e]).sum() / max(float(w.sum()), 1e-9)))
    return out


def _centre_and_measure(
    segs: NDArray, mask_f: NDArray[np.float32], max_px: float, bounded_runs: bool = False
) -> tuple[NDArray, NDArray]:
    """Segments moved onto the middle of their ink band, and their thickness (px)."""
    out = segs.copy()
    thick = np.zeros(len(segs))
    for i, sg in enumerate(segs):
        thick[i], off = _thickness_px(sg, mask_f, max_px, bounded_runs=bounded_runs)
        d = sg[2:] - sg[:2]
        nrm = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        # thinning is biased by up to a pixel; a larger offset is another wall's ink met at a junction
        out[i] += np.tile(float(np.clip(off, -1.5, 1.5)) * nrm, 2)
    return out, thick


def free_ends(segs: NDArray, tol: float, thick: NDArray | None = None) -> list[tuple[int, int]]:
    """(segment, end) pairs of the ends farther than tol from every other segment (with `thick`, also
    outside its ink: farther than half its thickness)."""
    if len(segs) == 0:
        return []
    ends = np.concatenate([segs[:, :2], segs[:, 2:]])
    owner = np.concatenate([np.arange(len(segs))] * 2)
    dist = lines.point_segment_distances(ends, segs)
    if thick is not None:
        dist -= np.maximum(np.asarray(thick)[None, :] / 2 - tol, 0.0)
    dist[np.arange(len(ends)), owner] = np.inf
    free = dist.min(axis=1) > tol if len(segs) > 1 else np.ones(len(ends), bool)
    return [(int(owner[k]), int(k >= len(segs))) for k in np.flatnonzero(free)]


def _spur_free(segs: NDArray, keep: NDArray[np.bool_], short_px: NDArray) -> NDArray[np.bool_]:
    """False for the short segments (length below short_px), off the plan's main axes, that are not on the
    line of another kept segment (both ends within 1.5 px of it, directions within 2 degrees): a jamb beside a door or window
    continues its wall, a skeleton spur at a corner turns away from both walls."""
    out = np.ones(len(segs), bool)
    if len(segs) == 0:
        return out
    ang = lines.angles(segs)
    main = ang[int(np.argmax(lines.lengths(segs)))]
    # along or across the longest wall: the plan's main axes, where spurs (diagonal at corners) are not
    on_axes = np.abs(np.sin(2 * (ang - main))) < math.sin(math.radians(4.0))
    for i in np.flatnonzero((lines.lengths(segs) < short_px) & ~on_axes):
        others = np.flatnonzero(keep & (np.arange(len(segs)) != i))
        turn = np.abs(np.sin(np.asarray(lines.angle_difference(ang[others], ang[i]))))
        same = others[turn < math.sin(math.radians(2.0))]
        a = segs[same, :2]
        u = segs[same, 2:] - a
        u /= np.maximum(np.hypot(u[:, 0], u[:, 1]), 1e-9)[:, None]
        off = [np.abs(u[:, 0] * (e[1] - a[:, 1]) - u[:, 1] * (e[0] - a[:, 0])) for e in segs[i].reshape(2, 2)]
        out[i] = bool(len(same) and (np.maximum(*off) <= 1.5).any())
    return out


def merge_within_directions(segs: NDArray, lcfg: lines.LinesConfig) -> NDArray[np.float64]:
    """`lines.merge_segments`, each merged wall's direction kept within its pieces' directions: the
    total-least-squares fit over the pieces of one wall whose skeleton steps by a pixel or two (where a
    partition's lines meet its face) tilts it past every piece (two pieces on the axis, 0.5 m long and
    3 px apart: 4.6 degrees, MLSTRUCT floor 302), and a few such walls form an orientation cluster of
    their own that regularization keeps. Such a wall is turned, about its pieces' centroid, to the
    nearest of its pieces' directions and cropped to their ends. A wall drawn a few degrees off the
    axes, skeletonized into pixel steps, has pieces on both sides of its direction and keeps the fit."""
    merged = lines.merge_segments(segs, lcfg)
    out = merged.segments.copy()
    if not len(out):
        return out
    L = lines.lengths(segs)
    th = lines.angles(segs)
    fit = lines.angles(out)
    for j in range(len(out)):
        m = np.flatnonzero(merged.labels == j)
        if len(m) < 2 or L[m].sum() <= 0:
            continue
        rel = np.asarray(lines.angle_difference(th[m], fit[j]), dtype=np.float64)
        if rel.min() <= 0.0 <= rel.max():
            continue
        phi = fit[j] + float(rel[np.argmin(np.abs(rel))])
        u = np.array([math.cos(phi), math.sin(phi)])
        if float(u @ (out[j, 2:] - out[j, :2])) < 0:
            u = -u
        w = L[m]
        c = (w[:, None] * lines.midpoints(segs[m])).sum(0) / w.sum()
        t = np.concatenate([segs[m, :2], segs[m, 2:]]) @ u - c @ u
        out[j] = np.concatenate([c + t.min() * u, c + t.max() * u])
    return out


def _regularize(segs: NDArray, band_px: NDArray, lcfg: lines.LinesConfig) -> NDArray[np.float64]:
    """`lines.regularize`, except that walls its orientation clusters would turn by more than the angle
    tolerance and more than their own angle is uncertain keep out of those clusters: a wing of the
    building drawn a few degrees off the main axes would otherwise be snapped to them, and would pull the
    main axes off by a fraction of a degree (0.3 degrees is 0.3 m over 60 m). The two sets are
    regularized apart. A skeleton piece can tilt across its ink band (band_px (N,) wide) by up to
    atan(band / length) and still lie in it: that is how uncertain its angle is."""
    out, rot = lines.regularize(segs, lcfg)
    uncertain = np.arctan2(np.maximum(band_px, 2.0), np.maximum(lines.lengths(segs), 1e-9))
    off = np.abs(rot) > np.maximum(math.radians(lcfg.angle_tol_deg), uncertain)
    if off.any() and not off.all():
        out[~off] = lines.regularize(segs[~off], lcfg)[0]
        out[off] = lines.regularize(segs[off], lcfg)[0]
    return out


def follow_ink_to_ends(
    segs: NDArray, thick: NDArray, mask_f: NDArray[np.float32], max_px: float
) -> NDArray[np.float64]:
    """Free wall ends (M, 4) (thickness (M,) px) moved along their wall's line to where its ink ends (the wall's face) or to
    the first other wall's centreline the ink runs into (a junction), at most max_px; never shortened.

    A skeleton stops about half a thickness short of a wall's free end, and the Hough transform can
    leave only the middle of a short wall (a jamb between a corner and a door) when its skeleton steps
    by a pixel (a photo's residual perspective): the wall's own ink says where it ends."""
    out = segs.copy()
    step = 0.5
    ts = np.arange(step, max_px + step, step)
    ang = lines.angles(segs) if len(segs) else np.zeros(0)
    for i, e in free_ends(segs, 1.0):
        a, b = segs[i, :2], segs[i, 2:]
        p, q = (b, a) if e else (a, b)
        u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
        pts = p + ts[:, None] * u
        off_ink = sample_mask(mask_f, pts) <= 0.5
        stop = off_ink.copy()
        if len(segs) > 1:
            others = np.delete(np.arange(len(segs)), i)
            turn = np.abs(np.sin(np.asarray(lines.angle_difference(ang[others], ang[i]))))
            parallel = turn < math.sin(math.radians(10.0))
            # into a crossing wall up to its centreline, lengthened by both half thicknesses (a corner
            # whose other wall's skeleton also stops short); a parallel wall's ink (the same wall's
            # other piece, or the wall whose face a stray piece lies on) is not this wall's to follow
            o = segs[others]
            d = o[:, 2:] - o[:, :2]
            d /= np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]
            ext = np.where(parallel, 0.0, (thick[others] + thick[i]) / 2)[:, None]
            o = np.hstack([o[:, :2] - ext * d, o[:, 2:] + ext * d])
            dist = lines.point_segment_distances(pts, o)  # (T, M - 1)
            reach = np.where(parallel, thick[others] / 2 + 1.0, 1.0)
            stop |= (dist <= reach[None, :]).any(axis=1)
        if not stop.any():
            out[i, 2 * e : 2 * e + 2] = p + ts[-1] * u
            continue
        k = int(np.argmax(stop))
        # the ink's end lies between the last sample on ink and the first off it
        out[i, 2 * e : 2 * e + 2] = p + (ts[k] - (step / 2 if off_ink[k] else 0.0)) * u
    return out


def jambs_past_corners(
    segs: NDArray, thick: NDArray, mask_f: NDArray[np.float32], max_px: float
) -> NDArray[np.float64]:
    """Wall ends (M, 4) at a corner whose own ink runs straight on past the other wall's far face by at
    least half the wall's thickness (a jamb beside a door or window on the far side of a junction that
    the skeleton turned at, or that the line connection trimmed back to it: the junction is a T, not an
    L) prolonged to where that ink ends, at most max_px. At a true corner the ink stops at the other
    wall's outer face."""
    out = segs.copy()
    if len(segs) < 2:
        return out
    step = 0.5
    ts = np.arange(step, max_px + step, step)
    ang = lines.angles(segs)
    free = set(free_ends(segs, 1.0))
    for i in range(len(segs)):
        for e in (0, 1):
            if (i, e) in free:
                continue
            a, b = segs[i, :2], segs[i, 2:]
            p, q = (b, a) if e else (a, b)
            u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
            others = np.delete(np.arange(len(segs)), i)
            at_p = lines.point_segment_distances(p[None], segs[others])[0] <= 1.0
            turn = np.abs(np.sin(np.asarray(lines.angle_difference(ang[others], ang[i]))))
            # only a corner: the walls met there all cross this one, and one of them ends there
            if not at_p.any() or (turn[at_p] < math.sin(math.radians(60.0))).any():
                continue
            met = others[at_p]
            if min(min(np.hypot(*(segs[j, :2] - p)), np.hypot(*(segs[j, 2:] - p))) for j in met) > 1.0:
                continue
            pts = p + ts[:, None] * u
            on_ink = sample_mask(mask_f, pts) > 0.5
            # and no other wall on the way (its ink is not this wall's)
            rest = others[~at_p]
            if len(rest):
                on_ink &= ~(lines.point_segment_distances(pts, segs[rest]) <= 1.0).any(axis=1)
            n = len(ts) if on_ink.all() else int(np.argmin(on_ink))
            reach = n * step - step / 2 if n < len(ts) else ts[-1]
            if n == 0 or reach < float(thick[met].max() + thick[i]) / 2:
                continue
            out[i, 2 * e : 2 * e + 2] = p + reach * u
    return out


def _join_hidden_junctions(
    segs: NDArray, thick: NDArray, support: NDArray[np.float32], door_min_px: float
) -> NDArray[np.float64]:
    """Free wall ends whose prolongation meets another wall after a gap narrower than door_min_px and
    drawn (ink or a removed symbol over all of it): the junction is hidden under a symbol, and the
    wall is prolonged to the other wall's centreline. A gap of paper stays open."""
    out = segs.copy()
    for i, e in free_ends(segs, 1.0, thick):
        a, b = segs[i, :2], segs[i, 2:]
        p, q = (b, a) if e else (a, b)
        u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
        r = first_wall_hit(p, u, segs, thick, i)
        if not r < door_min_px:
            continue
        pts = p + np.linspace(0, r, max(2, int(r) + 1))[:, None] * u
        if float((sample_mask(support, pts) > 0.5).mean()) >= 0.99:
            out[i, 2 * e : 2 * e + 2] = p + r * u
    return _close_hidden_corners(out, thick, support, door_min_px)


def _close_hidden_corners(
    segs: NDArray, thick: NDArray, support: NDArray[np.float32], door_min_px: float
) -> NDArray[np.float64]:
    """Two free ends of crossing walls whose lines meet beyond both ends, each within the smallest door,
    with ink or a removed symbol over both prolongations: a corner hidden under a symbol (a fire
    extinguisher drawn on it), which neither wall's prolongation alone meets (the other wall stops short
    of it too). Both walls are prolonged to the corner. A gap of paper stays open."""
    out = segs.copy()
    ends = free_ends(segs, 1.0, thick)
    used: set[tuple[int, int]] = set()
    for n, (i, e) in enumerate(ends):
        for k, f in ends[n + 1 :]:
            if k == i or (i, e) in used or (k, f) in used:
                continue
            turn = abs(
                math.sin(
                    float(lines.angle_difference(lines.angles(segs[[i]])[0], lines.angles(segs[[k]])[0]))
                )
            )
            hit = lines.line_intersection(segs[i], segs[k])
            if hit is None or turn < math.sin(math.radians(10.0)):  # a corner, not a wall's two pieces
                continue
            x = np.asarray(hit[0], dtype=np.float64)
            ok = True
            for j, g in ((i, e), (k, f)):
                p, q = (segs[j, 2:], segs[j, :2]) if g else (segs[j, :2], segs[j, 2:])
                u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
                r = float(np.dot(x - p, u))
                # beyond the end (or inside its own ink), short of a door, and on the line
                if not (-thick[j] / 2 <= r < door_min_px):
                    ok = False
                    break
                pts = p + np.linspace(0, max(r, 0.0), max(2, int(r) + 1))[:, None] * u
                ok = float((sample_mask(support, pts) > 0.5).mean()) >= 0.99
                if not ok:
                    break
            if ok:
                out[i, 2 * e : 2 * e + 2] = x
                out[k, 2 * f : 2 * f + 2] = x
                used |= {(i, e), (k, f)}
    return out


def first_wall_hit(
    p: NDArray, u: NDArray, segs: NDArray, thick: NDArray, i: int, skip: int | None = None
) -> float:
    """Distance (px) from the end p of wall i along the unit direction u to the first other wall the
    prolongation meets (inf when none). A wall is met when the ray crosses its centreline within its
    length, lengthened by half the thickness of wall i plus a pixel (a wall ending beside the ray still
    blocks the gap's ink band). Walls crossing within their half thickness of p are the junction p sits
    at (a jamb at a corner), not an obstacle; nor is wall `skip`."""
    best = math.inf
    for k in range(len(segs)):
        if k == i or k == skip:
            continue
        t = segs[k]
        hit = lines.line_intersection(np.concatenate([p, p + u]), t)
        if hit is None:
            continue
        _x, s_ray, s_seg = hit
        slack = (thick[i] / 2 + 1.0) / max(float(np.hypot(*(t[2:] - t[:2]))), 1e-9)
        if s_ray > thick[k] / 2 + 1.0 and -slack <= s_seg <= 1 + slack:
            best = min(best, s_ray)
    return best


def hough_lines(
    walls_r: NDArray[np.bool_], px: float, cfg: PlanConfig, second_pass: bool = True
) -> NDArray[np.float64]:
    """Probabilistic Hough segments (K, 4) in working pixels of the wall raster's (h, w) skeleton; with
    `second_pass`, also those of the skeleton that no segment of the first pass covers."""
    skel = skeletonize(walls_r).astype(np.uint8) * 255
    min_len = max(3, round(cfg.hough_min_length_m * px))

    def hough(img: NDArray[np.uint8]) -> NDArray[np.float64]:
        found = cv2.HoughLinesP(
            img,
            1,
            np.pi / 720,
            max(3, min_len // 2),
            minLineLength=min_len,
            maxLineGap=max(1, round(cfg.hough_max_gap_m * px)),
        )
        return found.reshape(-1, 4).astype(np.float64) if found is not None else np.zeros((0, 4))

    raw = hough(skel)
    # The probabilistic transform walks a line at the angle of the accumulator cell that first reached
    # its threshold, which depends on the order pixels were drawn in, i.e. on the whole image: a walk a
    # fraction of a degree off leaves the skeleton and stops, and the pixels beyond it have already voted,
    # so they never form a line (a wall's stub past a T-junction lost that way left a door gap too wide
    # for its swing). The skeleton no segment passed over gets a second pass of its own.
    if not second_pass:
        return raw
    covered = np.zeros_like(skel)
    for sg in np.round(raw).astype(int):
        cv2.line(covered, (int(sg[0]), int(sg[1])), (int(sg[2]), int(sg[3])), 255, 3)
    rest = cv2.bitwise_and(skel, cv2.bitwise_not(covered))
    if rest.any():
        raw = np.vstack([raw, hough(rest)])
    return raw


def vector_walls(
    raw: NDArray[np.float64],
    walls_r: NDArray[np.bool_],
    lines_f: NDArray[np.float32],
    sym_any: NDArray[np.bool_],
    px: float,
    cfg: PlanConfig,
    heavy_pen: bool = False,
    outline_layers: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Straight walls from the Hough segments `raw` (K, 4): merged, regularized, centred on their ink,
    connected (extensions backed by walls or symbols), spurs dropped, free ends prolonged to the wall
    face and hidden junctions joined. Returns the walls (M, 4), their raster thickness (M,) and their
    thickness between drawn faces (M,), in working pixels.

    A junction hidden under a symbol is joined across less than the smallest door: an evacuation plan
    draws its signs in doorways. In a drawing in a heavy pen (`heavy_pen`) the drawing itself is black
    and a coloured stroke over it is someone's pen mark, and a door shows as paper with its swing: there
    a wall's prolongation hidden all the way to another wall is joined up to the largest door.

    In a CAD drawing whose walls are filled between faces drawn in coloured layers (`outline_layers`;
    a partition's lines meeting a face step the skeleton there) a merged wall keeps within its pieces'
    directions (`merge_within_directions`). Elsewhere it did not pay: on the survey generator's evacuation plans
    it moved walls by up to a centimetre (generator seeds 0-20: mean completeness 0.9903 -> 0.9894 at
    0.05 m; the fusion downstream was checked on them as they were), and in the heavy-pen drawings
    (0-5, 300-310) it left the means as they were but opened a room of drawing 310's scan (7 -> 4
    rooms found)."""
    lcfg = cfg.lines.scaled(px)
    mask_f = walls_r.astype(np.float32)
    support = (walls_r | sym_any).astype(np.float32)
    segs = np.zeros((0, 4))
    if len(raw):
        merge = (
            merge_within_directions if outline_layers else (lambda s, c: lines.merge_segments(s, c).segments)
        )
        segs = merge(raw, lcfg)
        band = np.array(
            [
                _thickness_px(sg, mask_f, cfg.max_outline_width_m * px, bounded_runs=heavy_pen)[0]
                for sg in segs
            ]
        )
        segs = _regularize(segs, band, lcfg)
        segs = merge(segs, lcfg)
        segs, _ = _centre_and_measure(segs, mask_f, cfg.max_outline_width_m * px, heavy_pen)

        def support_fn(pieces: NDArray, parent: NDArray) -> NDArray:
            out = np.zeros(len(pieces))
            for n, p in enumerate(pieces):
                L = float(np.hypot(p[2] - p[0], p[3] - p[1]))
                ts = np.linspace(0, 1, max(2, int(L) + 1))
                pts = p[:2] + ts[:, None] * (p[2:] - p[:2])
                out[n] = float((sample_mask(support, pts) > 0.5).mean())
            return out

        segs, _ = connect(segs, lcfg, support_fn)
    max_t = cfg.max_outline_width_m * px
    thick = np.array([_thickness_px(sg, mask_f, max_t, bounded_runs=heavy_pen)[0] for sg in segs])
    # reported thickness: between the face lines of outline-drawn walls (the raster width elsewhere)
    thick_faces = np.array([_thickness_px(sg, mask_f, max_t, lines_f, heavy_pen)[0] for sg in segs])
    keep = (
        (lines.lengths(segs) >= cfg.min_wall_length_ratio * thick) & (thick > 0)
        if len(segs)
        else np.zeros(0, bool)
    )
    keep &= _spur_free(segs, keep, cfg.short_wall_length_ratio * thick)
    segs, thick, thick_faces = segs[keep], thick[keep], thick_faces[keep]
    segs = follow_ink_to_ends(segs, thick, mask_f, cfg.end_follow_max_m * px)
    if heavy_pen:
        # a door's jamb past a T-junction decides whether its gap fits the swing; on the survey
        # generator's evacuation plans (no swings) this moved wall ends the fusion was not checked on
        segs = jambs_past_corners(segs, thick, mask_f, cfg.end_follow_max_m * px)
    hidden_max = (cfg.door_max_m if heavy_pen else cfg.door_min_m) * px
    segs = _join_hidden_junctions(segs, thick, support, hidden_max)
    return segs, thick, thick_faces
