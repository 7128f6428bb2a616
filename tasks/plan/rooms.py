"""Rooms and scale of a parsed plan: the plan's metres per pixel (given, from a known distance, from the
outline's perimeter, or from a rectified outline of known size), working pixels to plan metres, the rooms
as the free space the walls and doors enclose, and the preview picture."""

from __future__ import annotations

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import Polygon

from tasks.plan.config import PlanConfig
from tasks.plan.raster import closing, enhance


def to_metres(seg_px: NDArray, f: int, s: float) -> NDArray[np.float64]:
    """Working pixels (after min-pooling by f) -> plan metres (u s, -v s) of the input pixel grid."""
    out = (np.asarray(seg_px, dtype=np.float64) * f + (f - 1) / 2.0) * s
    out[..., 1::2] *= -1
    return out


def rectify(
    image: NDArray[np.uint8], corners: NDArray, size_m: tuple[float, float] | None
) -> tuple[NDArray[np.uint8], float | None, NDArray[np.float64]]:
    """Perspective rectification: the corners go to an axis-parallel rectangle with a 5 % margin. Its
    sides are the photo's mean side lengths, or, with `size_m`, the true aspect ratio at the photo's
    mean resolution (then also returns that scale, metres per pixel); and the (3, 3) homography."""
    c = np.asarray(corners, dtype=np.float32)
    w = 0.5 * (np.hypot(*(c[1] - c[0])) + np.hypot(*(c[2] - c[3])))
    h = 0.5 * (np.hypot(*(c[3] - c[0])) + np.hypot(*(c[2] - c[1])))
    s = None
    if size_m is not None:
        s = 0.5 * (size_m[0] / w + size_m[1] / h)
        w, h = size_m[0] / s, size_m[1] / s
    margin = 0.05 * max(w, h)
    dst = np.float32([[margin, margin], [margin + w, margin], [margin + w, margin + h], [margin, margin + h]])
    H = cv2.getPerspectiveTransform(c, dst)
    size = (round(w + 2 * margin), round(h + 2 * margin))
    out = cv2.warpPerspective(image, H, size, flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255))
    return out, s, H.astype(np.float64)


def outline_scale(image: NDArray[np.uint8], length_m: float, cfg: PlanConfig) -> float:
    """Metres per pixel from the perimeter of the largest dark outline not touching the image border
    (a photo's own frame or background does)."""
    img = enhance(image, max(image.shape[:2]) // 4, cfg)
    dark = (255 - img.min(axis=2)).astype(np.uint8)
    _, ink = cv2.threshold(dark, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    ink = closing(ink, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(ink, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    h, w = ink.shape
    inner = []
    for c in contours:
        x, y, cw, ch = cv2.boundingRect(c)
        if x > 0 and y > 0 and x + cw < w and y + ch < h:
            inner.append(c)
    if not inner:
        raise ValueError("outline_length_m given but no building outline found")
    c = max(inner, key=cv2.contourArea)
    c = cv2.approxPolyDP(c, 0.002 * cv2.arcLength(c, True), True)
    return length_m / cv2.arcLength(c, True)


def free_space_rooms(
    walls_r: NDArray[np.bool_],
    segs: NDArray[np.float64],
    thick: NDArray[np.float64],
    doors: NDArray[np.float64],
    sp: float,
    cfg: PlanConfig,
    seal_px: int = 0,
    ink: NDArray[np.bool_] | None = None,
    seal_gaps: NDArray[np.float64] | None = None,
    face_px: float = 0.0,
) -> list[Polygon]:
    """Room polygons (working pixels): the free space the walls (M, 4) and door lines (D, 4) enclose, in
    components of at least `min_room_area_m2` at `sp` metres per working pixel. With `seal_gaps` (G, 4),
    the outside is what stays joined to the image's border once those gaps (every opening between wall
    ends a door could fill, whether or not it is a door) are closed and the walls closed by a `seal_px`
    square (gaps narrower than the smallest door): a room whose outer wall has an opening no door line
    closed (a window read as a gap, a bay whose short walls were lost) keeps its free space instead of
    leaking out. Only openings between wall ends are closed, not the outside's own narrows: a square as
    wide as a door also filled the acute corner between two outer walls (a slanted wall meeting the
    next one), which then stood apart from the outside as a sliver of a room.

    The walls close the raster's gaps: each line's 3 px core everywhere, its full width across stretches
    where the raster has no wall pixel (`_raster_gaps`) and, with `ink` (the drawing's dark pixels),
    wherever that width covers ink (a strip of the wall the raster left out, a window's line along it);
    never onto blank paper beside the raster, where a line drawn thicker than its wall (one thickness for
    collinear pieces of two) would move the room's face into the wall.

    `face_px`: where the walls are drawn by their faces' lines (CAD, an architect's double or hatched
    walls), half a line's width (pixels): the face is the line's centre (as the walls' thickness between
    faces is measured), and every room reaches that much past its free space (a WC of 1.9 m2 behind
    lines 6 px wide, in drawing 323's photo, came out 1.56 m2)."""
    closed = walls_r.astype(np.uint8)
    fat = np.zeros_like(closed)
    for sg, th in zip(segs, thick, strict=True):
        width = max(1, round(th) - 2)
        ends = [tuple(int(v) for v in np.round(p)) for p in (sg[:2], sg[2:])]
        cv2.line(closed, ends[0], ends[1], 1, min(width, 3))  # its core: inside the raster wall
        cv2.line(fat, ends[0], ends[1], 1, width)
        for p, q in _raster_gaps(walls_r, sg, width):  # its full width where the raster has none
            cv2.line(closed, p, q, 1, width)
    if ink is not None:
        closed[(fat > 0) & ink] = 1
    for dr in doors:  # one 8-connected pixel line separates 4-connected free space
        cv2.line(
            closed, tuple(int(v) for v in np.round(dr[:2])), tuple(int(v) for v in np.round(dr[2:])), 1, 1
        )
    free = (1 - closed).astype(np.uint8)
    if seal_gaps is not None:
        sealed = closing(closed, np.ones((seal_px, seal_px), np.uint8)) if seal_px >= 3 else closed.copy()
        for g in seal_gaps:
            p, q = (tuple(int(v) for v in np.round(g[k : k + 2])) for k in (0, 2))
            cv2.line(sealed, p, q, 1, 3)
        _n2, lab2 = cv2.connectedComponents((1 - sealed).astype(np.uint8), connectivity=4)
        edge = np.unique(np.concatenate([lab2[0], lab2[-1], lab2[:, 0], lab2[:, -1]]))
        free[np.isin(lab2, edge[edge > 0]) & (sealed == 0)] = 0
    n, lab, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    border = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])).tolist())
    rooms_px: list[Polygon] = []
    for c in range(1, n):
        if c in border or stats[c, cv2.CC_STAT_AREA] * sp * sp < cfg.min_room_area_m2:
            continue
        comp = lab[stats[c, 1] : stats[c, 1] + stats[c, 3], stats[c, 0] : stats[c, 0] + stats[c, 2]] == c
        cs, _ = cv2.findContours(comp.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cont = max(cs, key=cv2.contourArea)
        cont = cv2.approxPolyDP(cont, 1.0, True).reshape(-1, 2).astype(np.float64)
        if len(cont) < 3:
            continue
        # pixel centres -> pixel edges: the component's outline lies half a pixel outside its centres;
        # and a wall drawn by its faces' lines has its face at the line's centre, face_px further out
        poly = Polygon(cont + np.array([stats[c, 0], stats[c, 1]])).buffer(0.5 + face_px, join_style="mitre")
        if poly.is_valid and poly.area * sp * sp >= cfg.min_room_area_m2:
            rooms_px.append(poly)
    return rooms_px


def _raster_gaps(
    walls_r: NDArray[np.bool_], seg: NDArray, width_px: int
) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The stretches of a vectorized wall (working pixels) across which the raster holds no wall pixel
    within width_px / 2 of its line (a gap the line must close), as (start, end) pixels one pixel past
    each end. Elsewhere the raster is the wall: a line drawn at its full width there would fatten a wall
    whose vectorized thickness is another piece's (collinear walls of 0.16 and 0.26 m joined into one
    line 0.28 m thick put the rooms' faces 5 cm into the thinner wall's rooms)."""
    a, b = np.asarray(seg[:2], dtype=np.float64), np.asarray(seg[2:], dtype=np.float64)
    length = float(np.hypot(*(b - a)))
    if length < 1.0:
        return []
    u = (b - a) / length
    n = np.array([-u[1], u[0]])
    s = np.arange(0.0, length + 0.5, 1.0)
    o = np.arange(-(width_px // 2), width_px // 2 + 1, dtype=np.float64)
    xy = a + s[:, None, None] * u + o[None, :, None] * n  # (S, O, 2)
    x = np.clip(np.round(xy[..., 0]).astype(np.intp), 0, walls_r.shape[1] - 1)
    y = np.clip(np.round(xy[..., 1]).astype(np.intp), 0, walls_r.shape[0] - 1)
    gap = ~walls_r[y, x].any(axis=1)
    out = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], gap.astype(np.int8), [0]])))
    for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
        p, q = a + (s[i0] - 1.0) * u, a + (s[i1 - 1] + 1.0) * u
        out.append((tuple(int(v) for v in np.round(p)), tuple(int(v) for v in np.round(q))))
    return out


def rooms_in_metres(
    rooms_px: list[Polygon], f: int, s: float, labels: dict[str, tuple[float, float]] | None
) -> list[tuple[Polygon, str | None]]:
    """The room polygons in plan metres, largest first, each with the label whose point lies inside it."""
    rooms_m: list[tuple[Polygon, str | None]] = []
    for poly in sorted(rooms_px, key=lambda p: -p.area):
        xy = to_metres(np.asarray(poly.exterior.coords), f, s)
        pm = Polygon(xy)
        label = None
        for lname, (lx, ly) in (labels or {}).items():
            if pm.contains(shapely.Point(lx, ly)):
                label = lname
                break
        rooms_m.append((pm, label))
    return rooms_m


def _thickness_colour(t_m: float) -> tuple[int, int, int]:
    """RGB of a wall thickness: blue (thin, 0.05 m) through green to red (thick, 0.45 m and more)."""
    x = float(np.clip((t_m - 0.05) / 0.4, 0.0, 1.0))
    hue = int(120 * (1.0 - x))  # OpenCV hue 0-180: 120 blue, 60 green, 0 red
    rgb = cv2.cvtColor(np.uint8([[[hue, 230, 210]]]), cv2.COLOR_HSV2RGB)[0, 0]
    return int(rgb[0]), int(rgb[1]), int(rgb[2])


def plan_preview(
    walls_r: NDArray,
    segs: NDArray,
    thick: NDArray,
    rooms_px: list[Polygon],
    doors: NDArray,
    sp: float = 0.0,
    region: tuple[int, int, int, int] | None = None,
) -> NDArray[np.uint8]:
    """A picture a person can read, at working resolution (h, w, 3) RGB: the rooms tinted and named
    (R1, R2, ... with their area), the wall raster in grey under the walls coloured by their thickness,
    doors in magenta, the plan region as a dashed box, and a legend. `sp`: metres per pixel (0: no
    areas and no thickness scale), `thick`: (M,) wall thickness in pixels."""
    out = np.full((*walls_r.shape, 3), 255, np.uint8)
    palette = np.array(
        [
            [255, 224, 178],
            [200, 230, 201],
            [187, 222, 251],
            [248, 187, 208],
            [225, 190, 231],
            [255, 249, 196],
        ],
        np.uint8,
    )
    for n, poly in enumerate(rooms_px):
        pts = np.round(np.asarray(poly.exterior.coords)).astype(np.int32)
        cv2.fillPoly(out, [pts], tuple(int(v) for v in palette[n % len(palette)]))
    out[walls_r] = (200, 200, 200)
    lw = max(1, round(min(walls_r.shape) / 800))
    for sg, th in zip(segs, thick, strict=True):
        colour = _thickness_colour(float(th) * sp) if sp > 0 else (220, 0, 0)
        cv2.line(
            out,
            tuple(int(v) for v in np.round(sg[:2])),
            tuple(int(v) for v in np.round(sg[2:])),
            colour,
            max(lw, round(float(th) * 0.6)),
        )
    for dr in doors:
        cv2.line(
            out,
            tuple(int(v) for v in np.round(dr[:2])),
            tuple(int(v) for v in np.round(dr[2:])),
            (200, 0, 200),
            lw + 2,
        )
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, max(0.35, min(walls_r.shape) / 2000)
    for n, poly in enumerate(rooms_px):
        p = poly.representative_point()
        text = f"R{n + 1}" + (f" {poly.area * sp * sp:.1f} m2" if sp > 0 else "")
        (tw, th_), _ = cv2.getTextSize(text, font, fs, 1)
        org = (round(p.x - tw / 2), round(p.y + th_ / 2))
        cv2.putText(out, text, org, font, fs, (40, 40, 40), 1, cv2.LINE_AA)
    if region is not None:
        u0, v0, u1, v1 = (int(v) for v in region)
        dash = max(6, 4 * lw)
        for a, b in (((u0, v0), (u1, v0)), ((u1, v0), (u1, v1)), ((u1, v1), (u0, v1)), ((u0, v1), (u0, v0))):
            L = max(abs(b[0] - a[0]), abs(b[1] - a[1]))
            for k in range(0, L, 2 * dash):
                e = min(k + dash, L)
                p0 = (a[0] + (b[0] - a[0]) * k // max(L, 1), a[1] + (b[1] - a[1]) * k // max(L, 1))
                p1 = (a[0] + (b[0] - a[0]) * e // max(L, 1), a[1] + (b[1] - a[1]) * e // max(L, 1))
                cv2.line(out, p0, p1, (255, 120, 0), lw)
    _legend(out, lw, fs, sp)
    return out


def _legend(out: NDArray[np.uint8], lw: int, fs: float, sp: float) -> None:
    """The preview's key in its top-left corner."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    (_w, row), _ = cv2.getTextSize("Ag", font, fs, 1)
    row = int(row * 2.2)
    items = [("plan region", (255, 120, 0)), ("door", (200, 0, 200)), ("wall raster", (200, 200, 200))]
    width, height = int(row * 9), row * (len(items) + (3 if sp > 0 else 1))
    h, w = out.shape[:2]
    if width > w or height > h:
        return
    cv2.rectangle(out, (0, 0), (width, height), (255, 255, 255), -1)
    cv2.rectangle(out, (0, 0), (width, height), (0, 0, 0), 1)
    y = row
    for text, colour in items:
        cv2.line(out, (row // 3, y - row // 4), (row * 2, y - row // 4), colour, lw + 2)
        cv2.putText(out, text, (row * 2 + row // 3, y), font, fs, (0, 0, 0), 1, cv2.LINE_AA)
        y += row
    if sp > 0:
        cv2.putText(out, "wall thickness", (row // 3, y), font, fs, (0, 0, 0), 1, cv2.LINE_AA)
        y += row // 2
        x0, x1 = row // 3, width - row // 3
        for x in range(x0, x1):
            t_m = 0.05 + 0.4 * (x - x0) / max(x1 - x0 - 1, 1)
            cv2.line(out, (x, y), (x, y + row // 3), _thickness_colour(t_m), 1)
        cv2.putText(out, "0.05 m", (x0, y + row), font, fs * 0.8, (0, 0, 0), 1, cv2.LINE_AA)
        (tw, _t), _ = cv2.getTextSize("0.45 m", font, fs * 0.8, 1)
        cv2.putText(out, "0.45 m", (x1 - tw, y + row), font, fs * 0.8, (0, 0, 0), 1, cv2.LINE_AA)
