"""Doors in a parsed plan: gaps in a wall between a free wall end and the wall's continuation or a
crossing wall, a door's width apart; gaps spanned by a thin line are windows and become walls. In an
architect's drawing (walls in a heavy pen, thin line work beside them) a door also shows its swing: a
quarter circle of the gap's width about one jamb, drawn thin. A gap without one is no door there: a
furniture piece or a stair touching a wall, or a wall's stub pointing across a corridor, leaves wall ends
a door's width from another wall, and such a gap must neither close a room off nor split one."""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks import lines
from tasks.plan.config import PlanConfig
from tasks.plan.raster import InkMasks, faint_ink
from tasks.plan.vectorize import first_wall_hit, free_ends, sample_mask


def _jamb(p: NDArray, u: NDArray, segs: NDArray, thick: NDArray, i: int, mask_f: NDArray[np.float32]) -> bool:
    """Whether wall ink runs on from the junction p along u past the face of the wall crossing there."""
    d = lines.point_segment_distances(p[None], segs)[0]
    d[i] = np.inf
    reach = thick[int(np.argmin(d))] / 2 + 2.0
    return bool(sample_mask(mask_f, (p + reach * u)[None])[0] > 0.5)


def _on_other_wall(p: NDArray, q: NDArray, segs: NDArray, i: int, jamb: tuple[int, int] | None) -> bool:
    """Whether the middle of the gap p -> q (a quarter, half and three quarters along) lies on a wall
    other than i and the jamb's wall (within a pixel): the wall runs on there, the gap is no opening."""
    skip = [i] if jamb is None else [i, jamb[0]]
    others = np.delete(segs, skip, axis=0)
    probe = p + np.outer([0.25, 0.5, 0.75], q - p)
    return bool(len(others) and lines.point_segment_distances(probe, others).min() <= 1.0)


def swing_share(
    p: NDArray,
    q: NDArray,
    half_thick: float,
    thin_f: NDArray[np.float32],
    n_angles: int = 24,
    hidden_f: NDArray[np.float32] | None = None,
) -> float:
    """How much of a door swing the thin ink `thin_f` (h, w) draws over the gap p -> q (pixels): the
    best, over the two jambs as hinge, the two sides of the wall, the hinge's place along the gap (a
    quarter of it inwards to a tenth outwards, two pixels apart: a jamb's end may be found short or long)
    and the radius (0.7 to 1.2 times the hinge's distance to the far jamb: the leaf spans the opening;
    and 0.55 to 1.1 times the gap; a pixel apart), of the share of angles (0.2 rad to the quarter
    turn less 0.1 rad) at which ink lies on the arc of that radius about the hinge (on the wall's face,
    `half_thick` off the centreline), within a pixel and a half. A swing is one continuous stroke: the
    share is that of the longest run of angles with ink (a single angle without it bridged, where glare
    pales the arc), so the edges of a table and its chairs that the arc happens to cross in pieces do not
    add up to a swing. With `hidden_f` (h, w), the removed symbols: a stretch of arc under one (a pen
    mark drawn across the swing) does not break the run, but only the angles with ink count; and a jamb
    whose end lies under one (the wall's ink stops where the mark begins) may end anywhere along the
    hidden stretch that runs on from it into the gap, so the hinge is also sought that far out. Where a
    mark hides the arc and the leaf is drawn (`_leaf_drawn`: the straight line from the hinge out to the
    radius, square to the wall), the hidden angles count as arc: a mark across most of a swing left a
    third of its arc (drawing 320's scan), and the leaf says the rest of it is there."""
    w = float(np.hypot(*(q - p)))
    if w <= 0:
        return 0.0
    u = (q - p) / w
    n = np.array([-u[1], u[0]])
    ts = np.linspace(0.2, math.pi / 2 - 0.1, n_angles)
    band = np.array([-1.5, -0.75, 0.0, 0.75, 1.5])
    best = 0.0
    for hinge, along in ((p, u), (q, -u)):
        # the jamb's end found short or long, or hidden under a removed symbol up to half the gap
        out = max(0.1 * w, _hidden_run(hinge, along, 0.5 * w, hidden_f))
        shifts = np.arange(-0.25 * w, out + 1.0, 2.0)
        for side in (n, -n):
            dirs = np.outer(np.cos(ts), along) + np.outer(np.sin(ts), side)  # (A, 2)
            for sh in shifts:
                radii = np.arange(max(0.55 * w, 0.7 * (w - sh)), min(1.1 * w, 1.2 * (w - sh)) + 1.0, 1.0)
                r = radii[:, None] + band[None, :]  # (R, B)
                c = hinge + side * half_thick + along * sh
                pts = c + r[:, :, None, None] * dirs[None, None, :, :]  # (R, B, A, 2)
                flat = pts.reshape(-1, 2)
                ink = sample_mask(thin_f, flat).reshape(len(radii), len(band), len(ts)) > 0.5
                hidden = None
                hit = ink.any(axis=1)
                if hidden_f is not None:
                    hidden = (sample_mask(hidden_f, flat).reshape(ink.shape) > 0.5).any(axis=1)
                    if hidden.any():
                        # the leaf drawn from the hinge out to the radius: under the mark the arc went on
                        hit = hit | (hidden & _leaf_drawn(c, side, along, radii, thin_f, hidden_f)[:, None])
                best = max(best, _longest_run(hit, hidden) / len(ts))
    return best


def _leaf_drawn(
    c: NDArray,
    side: NDArray,
    along: NDArray,
    radii: NDArray,
    thin_f: NDArray[np.float32],
    hidden_f: NDArray[np.float32],
) -> NDArray[np.bool_]:
    """(R,) whether a door leaf of each radius is drawn from the hinge point c (pixels) along the unit
    direction `side` (the swing's side of the wall): thin ink within a pixel and a half of the line from
    a fifth of the radius to nine tenths of it (off the wall's face and the arc's end) at all its samples
    but a tenth, at least half of them ink rather than under a removed symbol."""
    fr = np.linspace(0.2, 0.9, 15)
    band = np.array([-1.5, -0.75, 0.0, 0.75, 1.5])
    pts = c + (radii[:, None, None] * fr[None, :, None])[..., None] * side + band[None, None, :, None] * along
    flat = pts.reshape(-1, 2)
    ink = (sample_mask(thin_f, flat).reshape(pts.shape[:3]) > 0.5).any(axis=2)
    hid = (sample_mask(hidden_f, flat).reshape(pts.shape[:3]) > 0.5).any(axis=2)
    return ((ink | hid).mean(axis=1) >= 0.9) & (ink.mean(axis=1) >= 0.5)


def _hidden_run(p: NDArray, u: NDArray, max_px: float, hidden_f: NDArray[np.float32] | None) -> float:
    """How far (pixels) from the wall end p along the unit direction u the removed symbols `hidden_f`
    (h, w) cover the line without a break (starting within 2 px of p), at most max_px; 0 without any."""
    if hidden_f is None or max_px < 1.0:
        return 0.0
    ts = np.arange(1.0, max_px + 1.0, 1.0)
    on = sample_mask(hidden_f, p + ts[:, None] * u) > 0.5
    if not on[:2].any():
        return 0.0
    start = int(np.argmax(on))
    rest = ~on[start:]
    return float(ts[start + int(np.argmax(rest))] - 1.0) if rest.any() else float(ts[-1])


def _longest_run(hit: NDArray[np.bool_], hidden: NDArray[np.bool_] | None = None) -> int:
    """The longest run of True along the last axis of (R, A) `hit`, over its rows, a single False between
    two True counted as True. With `hidden` (R, A), those angles do not break a run but add nothing to
    it (an arc passing under a removed symbol)."""
    hit = hit.copy()
    hit[:, 1:-1] |= hit[:, :-2] & hit[:, 2:]
    go_on = hit if hidden is None else hit | hidden
    run = np.zeros(hit.shape[0], np.int64)
    longest = 0
    for a in range(hit.shape[1]):
        run = (run + hit[:, a]) * go_on[:, a]
        longest = max(longest, int(run.max()))
    return longest


def _ink_cover(gap: NDArray, ink_f: NDArray[np.float32], half_width: float = 0.0) -> float:
    """Share of the gap x0 y0 x1 y1 (pixels) that the ink raster (h, w) covers (a pixel a sample): a
    sample is covered when ink lies on the gap's line or beside it within half_width (a window drawn as
    its wall's two faces running on across the opening leaves the centreline bare)."""
    L = float(np.hypot(*(gap[2:] - gap[:2])))
    pts = gap[:2] + np.linspace(0, 1, max(2, int(L) + 1))[:, None] * (gap[2:] - gap[:2])
    n = np.array([gap[1] - gap[3], gap[2] - gap[0]]) / max(L, 1e-9)
    offs = np.arange(-math.floor(half_width), math.floor(half_width) + 1, dtype=np.float64)
    across = pts[:, None, :] + offs[None, :, None] * n  # (S, O, 2)
    on = sample_mask(ink_f, across.reshape(-1, 2)).reshape(len(pts), len(offs)) > 0.5
    return float(on.any(axis=1).mean())


def _find_doors(
    segs: NDArray,
    thick: NDArray,
    cfg_px: dict[str, float],
    mask_f: NDArray[np.float32] | None = None,
    swing: tuple | None = None,
) -> NDArray[np.float64]:
    """Door gaps: a free wall end whose prolongation meets another wall (its collinear continuation or a
    crossing wall) after a gap between door_min and door_max. With `swing` (the thin ink (h, w) off the
    walls and the share of a swing's arc it must draw; the thin ink (h, w) and the share of a gap it
    covers in a window; the removed symbols (h, w) that may hide part of a swing), a gap is taken only
    where its swing is drawn, or a window spans it."""

    def swung(p: NDArray, q: NDArray, i: int) -> bool:
        hidden = swing[4] if swing is not None and len(swing) > 4 else None
        if swing is None or swing_share(p, q, thick[i] / 2, swing[0], hidden_f=hidden) >= swing[1]:
            return True
        return len(swing) > 2 and _ink_cover(np.concatenate([p, q]), swing[2], thick[i] / 2 - 1) >= swing[3]

    doors: list[NDArray] = []
    used: set[tuple[int, int]] = set()
    ang = lines.angles(segs) if len(segs) else np.zeros(0)
    sin_tol = math.sin(math.radians(2.0))
    # an end inside another wall's ink is a junction the skeleton stopped short of, not a door jamb
    free = free_ends(segs, 1.0, thick)
    for i, e in free:
        if (i, e) in used:
            continue
        s = segs[i]
        p = s[2:] if e else s[:2]
        q = s[:2] if e else s[2:]
        u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
        # a door is a gap in one wall: the prolongation stops at the first wall it meets, and a wall end
        # beyond that (the same line on the far side of a corridor) is not the other jamb
        reach = first_wall_hit(p, u, segs, thick, i)
        best = None
        for j in range(len(segs)):
            if j == i:
                continue
            t = segs[j]
            # the other jamb is the end of a wall on the same line: parallel (a crossing wall's end that
            # lies on the line is a corner, met by the ray below) and within half a thickness of the line
            parallel = abs(math.sin(float(lines.angle_difference(ang[i], ang[j])))) <= sin_tol
            for ej, pt in ((0, t[:2]), (1, t[2:])) if parallel else ():
                # collinear continuation: a facing end, free or at a corner (a door beside a T-junction)
                if (j, ej) in used or float((t[2:] if ej == 0 else t[:2]) @ u - pt @ u) <= 0:
                    continue
                v = pt - p
                along = float(v @ u)
                lateral = abs(float(v[0] * u[1] - v[1] * u[0]))
                if along > reach + thick[j] / 2 + 1.0:
                    continue
                if cfg_px["door_min"] <= along <= cfg_px["door_max"] and lateral < max(thick[i], 2.0) / 2:
                    if (best is None or along < best[0]) and swung(p, pt, i):
                        best = (along, pt.copy(), (j, ej))
            # a crossing wall's face: a parallel wall's line meets the ray only by its slight tilt (drawing
            # 310's scan: the far jamb's wall, 0.2 degrees off, put the door's end 8 px short of it)
            hit = None if parallel else lines.line_intersection(np.concatenate([p, p + u]), t)
            if hit is not None:
                x, s_ray, s_seg = hit
                # the wall's end may stop at the face of the wall the ray runs along (a door at a corner)
                slack = (thick[i] / 2 + 1.0) / max(float(np.hypot(*(t[2:] - t[:2]))), 1e-9)
                if (
                    -slack <= s_seg <= 1 + slack
                    and cfg_px["door_min"] <= s_ray <= cfg_px["door_max"]
                    and s_ray <= reach + 1e-6
                ):
                    foot = x - u * thick[j] / 2  # stop at the face of the crossing wall
                    if (best is None or s_ray < best[0]) and swung(p, foot, i):
                        best = (s_ray, foot, None)
        if best is not None and _on_other_wall(p, best[1], segs, i, best[2]):
            best = None  # the gap runs along another wall: the wall goes on, no opening
        if best is not None:
            doors.append(np.concatenate([p, best[1]]))
            used.add((i, e))
            if best[2] is not None:
                used.add(best[2])
    # a door beside two junctions (both jambs trimmed to a crossing wall) has no free end: collinear
    # walls whose facing ends are a door width apart with nothing crossing the gap
    for i, j in itertools.combinations(range(len(segs)), 2):
        if abs(math.sin(float(lines.angle_difference(ang[i], ang[j])))) > sin_tol:
            continue
        for ei, ej in itertools.product((0, 1), (0, 1)):
            if (i, ei) in used or (j, ej) in used:
                continue
            p, q = segs[i].reshape(2, 2)[ei], segs[j].reshape(2, 2)[ej]
            u = segs[i].reshape(2, 2)[ei] - segs[i].reshape(2, 2)[1 - ei]
            u /= max(float(np.hypot(*u)), 1e-9)
            v = q - p
            along, lateral = float(v @ u), abs(float(v[0] * u[1] - v[1] * u[0]))
            facing = float((segs[j].reshape(2, 2)[1 - ej] - q) @ u) > 0
            if not (facing and cfg_px["door_min"] <= along <= cfg_px["door_max"]):
                continue
            if lateral >= max(thick[i], 2.0) / 2:
                continue
            if _on_other_wall(p, q, segs, i, (j, ej)):
                continue
            if along > first_wall_hit(p, u, segs, thick, i, j) + thick[j] / 2 + 1.0:
                continue  # another wall crosses the gap: the two ends face each other across a room
            if mask_f is not None and not (
                _jamb(p, u, segs, thick, i, mask_f) and _jamb(q, -u, segs, thick, j, mask_f)
            ):
                continue  # the walls turn at both ends (an alcove's mouth), no wall runs on into the gap
            if not swung(p, q, i):
                continue
            doors.append(np.concatenate([p, q]))
            used.update({(i, ei), (j, ej)})
    return np.array(doors, dtype=np.float64).reshape(-1, 4)


def doors_and_windows(
    segs: NDArray[np.float64],
    thick: NDArray[np.float64],
    thick_faces: NDArray[np.float64],
    mask_f: NDArray[np.float32],
    found: InkMasks,
    px: float,
    cfg: PlanConfig,
    heavy_pen: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], int]:
    """The door gaps (D, 4) between the walls (M, 4), and the gaps spanned by a thin line turned into walls
    (windows). In a drawing whose walls are in a heavy pen (`heavy_pen`), a gap is a door only where its
    swing is drawn (`door_swing_share`). Returns the walls, their two thicknesses and the doors (all in
    working pixels), and the number of windows."""
    dark, sym_any = found.dark, found.symbols_any
    thin = cv2.dilate((dark & ~sym_any).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    swing = None
    if heavy_pen and cfg.door_swing_share > 0:
        # a swing is thin ink off the walls, read against the paper around it (a photo's glare pales it
        # below the whole sheet's ink threshold)
        faint = cv2.dilate(faint_ink(found, px).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(
            np.float32
        )
        off_walls = np.where(mask_f > 0.5, 0.0, np.maximum(thin, faint)).astype(np.float32)
        # a window's thin lines are read against the paper around them too (glare pales them as well)
        thin = np.maximum(thin, faint).astype(np.float32)
        # a pen mark or pictogram drawn across a swing hides that stretch of it
        hidden = sym_any.astype(np.float32)
        swing = (off_walls, cfg.door_swing_share, thin, cfg.window_ink_share, hidden)
    doors = _find_doors(
        segs, thick, {"door_min": cfg.door_min_m * px, "door_max": cfg.door_max_m * px}, mask_f, swing
    )
    n_windows = 0
    if len(doors) and cfg.window_ink_share <= 1.0:
        # a gap spanned by a thin line is a window drawn in its wall: the wall goes on through it
        window = np.zeros(len(doors), bool)
        jamb = lines.point_segment_distances(doors[:, :2], segs).argmin(axis=1)  # the wall it opens
        for n, dr in enumerate(doors):
            window[n] = _ink_cover(dr, thin, thick[jamb[n]] / 2 - 1) >= cfg.window_ink_share
            if window[n] and swing is not None:
                # a gap whose swing is drawn is a door, whatever runs along it (a counter by the wall)
                window[n] = (
                    swing_share(dr[:2], dr[2:], thick[jamb[n]] / 2, swing[0], hidden_f=swing[4])
                    < cfg.door_swing_share
                )
        if window.any():
            near = lines.point_segment_distances(doors[window][:, :2], segs).argmin(axis=1)
            segs = np.concatenate([segs, doors[window]])
            thick = np.concatenate([thick, thick[near]])
            thick_faces = np.concatenate([thick_faces, thick_faces[near]])
            doors, n_windows = doors[~window], int(window.sum())
    return segs, thick, thick_faces, doors, n_windows


def wall_gaps(
    segs: NDArray[np.float64],
    thick: NDArray[np.float64],
    mask_f: NDArray[np.float32],
    px: float,
    cfg: PlanConfig,
) -> NDArray[np.float64]:
    """Every gap (G, 4) between wall ends (M, 4) (working pixels) that a door could fill (door_min_m to
    door_max_m at `px` pixels per metre), its swing drawn or not: what closes an outer wall's openings
    when the outside is sought."""
    return _find_doors(
        segs, thick, {"door_min": cfg.door_min_m * px, "door_max": cfg.door_max_m * px}, mask_f
    )
