"""Plans as people have them: an architect's drawing of the generator's AS-PLANNED floor (furniture and
sanitary symbols, stairs, door swings, hatched / filled / double-line walls, dimension lines, level marks,
text at any angle, a legend panel, a title block and a scale bar on the sheet), rendered as a paper scan
(paper tone, noise, pen marks, blur, slight rotation, JPEG blocks), as a phone photo of the posted sheet
(perspective, glare, background around the sheet) or as a close-up phone photo whose view ends inside the
sheet (a pinhole camera's perspective, no sheet border to rectify from).

The truth stays known: `Drawing.to_image` maps plan pixels (u, v) = (x / s, -y / s) of the plan frame
(s = `Drawing.m_per_px`) to pixels of the delivered image, so the as-planned walls and rooms of
`tasks.synth.survey.planned_truth` can be carried into any frame the parser works in. The generator's
evacuation plans (`tasks.synth.plan_raster`) are not changed by this module.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
import shapely.affinity
from numpy.typing import NDArray
from shapely.geometry import Polygon

from tasks.synth.building import Building
from tasks.synth.plan_raster import _opening_gap as opening_gap
from tasks.synth.plan_raster import _wall_polygon as wall_outline

SHEET_ASPECT = math.sqrt(2.0)
"""ISO 216 sheets (A4, A3, ...): long side / short side."""

_INK = (20, 20, 20)
_SHIFT = 4
_ONE = 1 << _SHIFT


@dataclass(frozen=True)
class DrawingConfig:
    """How the architect's drawing is styled and how it is degraded."""

    m_per_px: float = 0.02
    """Scale of the clean drawing (metres per pixel)."""
    wall_style: str = "hatched"
    """"filled" (solid black), "hatched" (outline and 45 degree hatching), "double" (two face lines with
    an empty core)."""
    degrade: str = "scan"
    """"none", "scan", "photo" (the whole sheet on a wall) or "closeup" (a phone held closer: the view
    ends inside the sheet, so neither its edge nor its drawn border shows)."""
    max_rotation_deg: float = 1.5
    """Largest skew of a scan."""
    max_corner_shift: float = 0.06
    """Largest shift of a photographed sheet corner, as a share of the sheet's short side."""
    jpeg_quality: int = 55
    """JPEG quality of the delivered image (blocks)."""
    scale_bar_m: float = 5.0
    """Length of the printed scale bar; 0 prints none (the dimension lines carry the scale)."""
    max_tilt_deg: float = 12.0
    """Largest tilt of a close-up's camera about either of the sheet's axes (a pinhole camera, principal
    point in the middle, square pixels)."""
    closeup_margin_px: int = 14
    """A close-up's view ends this far inside the paper's edges."""
    closeup_paper_px: int = 80
    """A close-up shows a print without the drawing's frame, whose paper reaches this much farther round
    the drawing (so the view can hold the plan and its scale bar without showing an edge)."""


@dataclass(frozen=True)
class Drawing:
    """A degraded architect's drawing and how it maps to the plan frame."""

    image: NDArray[np.uint8]
    """(H, W, 3) RGB."""
    m_per_px: float
    """Metres per plan pixel: plan pixel (u, v) is the plan frame point (u * s, -v * s)."""
    to_image: NDArray[np.float64]
    """(3, 3) homography from plan pixels to image pixels."""
    scale_bar_px: tuple[float, float, float, float]
    """The printed scale bar's two ends in image pixels (x0, y0, x1, y1)."""
    scale_bar_m: float
    """Its length in metres."""
    sheet_px: NDArray[np.float64]
    """(4, 2) the sheet's corners in image pixels, clockwise from top-left."""

    @property
    def image_m_per_px(self) -> float:
        """Mean metres per image pixel (exact for a scan, whose mapping is a rotation)."""
        return self.m_per_px / math.sqrt(abs(np.linalg.det(self.to_image[:2, :2])))


def _pts(xy: NDArray, s: float, off: NDArray) -> NDArray[np.int32]:
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return np.rint((np.column_stack([p[:, 0] / s, -p[:, 1] / s]) + off) * _ONE).astype(np.int32)


def _poly(img: NDArray, poly, s: float, off: NDArray, colour, thickness: int = -1) -> None:
    for g in getattr(poly, "geoms", [poly]):
        if g.is_empty or not isinstance(g, Polygon):
            continue
        rings = [_pts(np.asarray(g.exterior.coords)[:-1], s, off)]
        rings += [_pts(np.asarray(i.coords)[:-1], s, off) for i in g.interiors]
        if thickness < 0:
            cv2.fillPoly(img, rings, colour, cv2.LINE_AA, _SHIFT)
        else:
            cv2.polylines(img, rings, True, colour, thickness, cv2.LINE_AA, _SHIFT)


def _line(img: NDArray, a, b, s: float, off: NDArray, colour=_INK, t: int = 1) -> None:
    p = _pts(np.array([a, b]), s, off)
    cv2.line(img, tuple(p[0]), tuple(p[1]), colour, t, cv2.LINE_AA, _SHIFT)


def _text(img: NDArray, text: str, centre_px, angle_deg: float, size: float, colour=_INK) -> None:
    """Text centred on `centre_px` (sheet pixels), turned by angle_deg (counter-clockwise)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    (w, h), base = cv2.getTextSize(text, font, size, 1)
    pad = 4
    patch = np.zeros((h + base + 2 * pad, w + 2 * pad), np.uint8)
    cv2.putText(patch, text, (pad, pad + h), font, size, 255, 1, cv2.LINE_AA)
    side = int(math.hypot(*patch.shape)) + 2
    big = np.zeros((side, side), np.uint8)
    y0, x0 = (side - patch.shape[0]) // 2, (side - patch.shape[1]) // 2
    big[y0 : y0 + patch.shape[0], x0 : x0 + patch.shape[1]] = patch
    rot = cv2.getRotationMatrix2D((side / 2, side / 2), angle_deg, 1.0)
    big = cv2.warpAffine(big, rot, (side, side), flags=cv2.INTER_LINEAR)
    cx, cy = round(centre_px[0] - side / 2), round(centre_px[1] - side / 2)
    H, W = img.shape[:2]
    ya, xa = max(0, cy), max(0, cx)
    yb, xb = min(H, cy + side), min(W, cx + side)
    if ya >= yb or xa >= xb:
        return
    a = big[ya - cy : yb - cy, xa - cx : xb - cx].astype(np.float32)[..., None] / 255.0
    region = img[ya:yb, xa:xb].astype(np.float32)
    img[ya:yb, xa:xb] = (region * (1 - a) + np.asarray(colour, np.float32) * a).astype(np.uint8)


def _walls(img: NDArray, building: Building, s: float, off: NDArray, style: str) -> None:
    """The walls of the plan in their style, windows as three thin lines across a gap."""
    doors = [op for op in building.planned_openings if op.kind == "door"]
    windows = [op for op in building.planned_openings if op.kind == "window"]
    solid = shapely.union_all([wall_outline(w) for w in building.planned_walls])
    gaps = shapely.union_all([opening_gap(op) for op in doors + windows])
    drawn = solid.difference(gaps)
    if style == "filled":
        _poly(img, drawn, s, off, _INK)
    elif style == "double":  # the cut walls' faces in the heavy pen (0.5 mm at 1:100)
        _poly(img, drawn, s, off, _INK, 3)
    elif style == "hatched":
        mask = np.zeros(img.shape[:2], np.uint8)
        _poly(mask, drawn, s, off, 255)
        hatch = np.zeros_like(mask)
        step = max(4, round(0.07 / s))
        H, W = mask.shape
        for c in range(-H, W, step):
            cv2.line(hatch, (c, 0), (c + H, H), 255, 1, cv2.LINE_AA)
        # exterior walls hatched, interior walls filled grey: both kinds of a real drawing
        inner = shapely.union_all([wall_outline(w) for w in building.planned_walls if not w.exterior])
        inner_mask = np.zeros_like(mask)
        _poly(inner_mask, inner.difference(gaps), s, off, 255)
        a = (np.minimum(mask, hatch).astype(np.float32) / 255.0)[..., None]
        img[:] = (img * (1 - a) + np.asarray(_INK, np.float32) * a).astype(np.uint8)
        img[inner_mask > 127] = (90, 90, 90)
        _poly(img, drawn, s, off, _INK, 3)
    else:
        raise ValueError(f"unknown wall style {style!r}")
    for op in windows:
        a, b = np.array([op.x0, op.y0]), np.array([op.x1, op.y1])
        u = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
        n = np.array([-u[1], u[0]])
        for k in (-0.5, 0.0, 0.5):
            d = n * k * op.thickness_m
            _line(img, a + d, b + d, s, off, _INK, 1)


def _door_swings(img: NDArray, building: Building, s: float, off: NDArray) -> None:
    """A door leaf and its quarter-circle swing in every door gap."""
    for op in building.planned_openings:
        if op.kind != "door":
            continue
        a, b = np.array([op.x0, op.y0]), np.array([op.x1, op.y1])
        w = float(np.hypot(*(b - a)))
        u = (b - a) / max(w, 1e-9)
        n = np.array([-u[1], u[0]]) * (1 if round(op.x0 * 10 + op.y0 * 10) % 2 else -1)
        hinge = a + n * op.thickness_m / 2
        leaf = hinge + n * w
        _line(img, hinge, leaf, s, off, _INK, 1)
        ts = np.linspace(0, math.pi / 2, 24)
        arc = hinge + np.outer(np.cos(ts), u * w) + np.outer(np.sin(ts), n * w)
        cv2.polylines(img, [_pts(arc, s, off)], False, _INK, 1, cv2.LINE_AA, _SHIFT)


def _furniture(img: NDArray, building: Building, s: float, off: NDArray, rng: np.random.Generator) -> None:
    """Furniture outlines with their details, in thin lines."""
    for f in building.furniture:
        if f.kind in ("lamp", "poster", "extinguisher"):
            continue
        fp = f.footprint
        if f.kind == "plant":
            c = fp.centroid
            r = math.sqrt(fp.area / math.pi)
            for k in (1.0, 0.5):
                ring = c.buffer(r * k, quad_segs=8)
                _poly(img, ring, s, off, _INK, 1)
            continue
        _poly(img, fp, s, off, _INK, 1)
        if f.kind in ("shelf", "cabinet"):
            x0, y0, x1, y1 = fp.bounds
            _line(img, (x0, y0), (x1, y1), s, off, _INK, 1)
            _line(img, (x0, y1), (x1, y0), s, off, _INK, 1)
        elif f.kind == "table":
            _poly(img, fp.buffer(-0.05, join_style="mitre"), s, off, _INK, 1)


def _wall_side(room, width: float, depth: float, rng: np.random.Generator) -> Polygon | None:
    """A box (width along a wall, depth into the room) standing against the longest side of the room."""
    poly = room.polygon
    coords = np.asarray(poly.exterior.coords)
    sides = sorted(range(len(coords) - 1), key=lambda i: -np.hypot(*(coords[i + 1] - coords[i])))
    for i in sides:
        a, b = coords[i], coords[i + 1]
        L = float(np.hypot(*(b - a)))
        if L < width + 0.4:
            continue
        u = (b - a) / L
        n = np.array([-u[1], u[0]])
        if not poly.contains(shapely.Point(*(0.5 * (a + b) + n * 0.05))):
            n = -n
        t = 0.2 + rng.uniform(0, L - width - 0.4)
        p0 = a + u * t + n * 0.02
        box = Polygon([p0, p0 + u * width, p0 + u * width + n * depth, p0 + n * depth])
        if poly.buffer(1e-6).contains(box):
            return box
    return None


def _fixtures(img: NDArray, building: Building, s: float, off: NDArray, rng: np.random.Generator) -> None:
    """Sanitary fixtures (WC, washbasin), a kitchen counter, a straight and a spiral stair."""
    rooms = [r for r in building.rooms if r.capture != "hallway"]
    for r in rooms:
        if r.label == "WC" or r.shape == "storage":
            wc = _wall_side(r, 0.4, 0.65, rng)
            if wc is not None:
                _poly(img, wc.buffer(-0.02), s, off, _INK, 1)
                c = wc.centroid
                _poly(img, shapely.affinity.scale(c.buffer(0.17, quad_segs=8), 1.0, 1.3), s, off, _INK, 1)
            basin = _wall_side(r, 0.5, 0.4, rng)
            if basin is not None:
                _poly(img, basin, s, off, _INK, 1)
                _poly(img, basin.centroid.buffer(0.13, quad_segs=8), s, off, _INK, 1)
    big = sorted(rooms, key=lambda r: -r.polygon.area)
    if big:
        counter = _wall_side(big[0], 2.4, 0.6, rng)
        if counter is not None:
            _poly(img, counter, s, off, _INK, 1)
            sink = counter.centroid.buffer(0.2, cap_style="square")
            _poly(img, sink, s, off, _INK, 1)
            for hob in range(2):
                c = counter.representative_point()
                _poly(img, shapely.Point(c.x + (hob - 0.5) * 0.5 + 0.7, c.y).buffer(0.1), s, off, _INK, 1)
    if len(big) > 1:  # a straight stair: run of treads with the walking line
        r = big[1]
        c = r.polygon.centroid
        w, L = 1.0, 2.5
        x0, y0 = c.x - w / 2, c.y - L / 2
        if r.polygon.contains(shapely.box(x0, y0, x0 + w, y0 + L)):
            _poly(img, shapely.box(x0, y0, x0 + w, y0 + L), s, off, _INK, 1)
            for k in np.arange(0.28, L, 0.28):
                _line(img, (x0, y0 + k), (x0 + w, y0 + k), s, off, _INK, 1)
            _line(img, (c.x, y0 + 0.1), (c.x, y0 + L - 0.2), s, off, _INK, 1)
            _line(img, (c.x, y0 + L - 0.1), (c.x - 0.12, y0 + L - 0.3), s, off, _INK, 1)
            _line(img, (c.x, y0 + L - 0.1), (c.x + 0.12, y0 + L - 0.3), s, off, _INK, 1)
    if len(big) > 2:  # a spiral stair: outer and newel circles and radial treads
        c = big[2].polygon.centroid
        R = 0.8
        if big[2].polygon.contains(c.buffer(R)):
            _poly(img, c.buffer(R, quad_segs=16), s, off, _INK, 1)
            _poly(img, c.buffer(0.12, quad_segs=8), s, off, _INK, 1)
            for ang in np.arange(0, 2 * math.pi, 2 * math.pi / 14):
                d = np.array([math.cos(ang), math.sin(ang)])
                _line(img, np.array([c.x, c.y]) + 0.12 * d, np.array([c.x, c.y]) + R * d, s, off, _INK, 1)


def _dimensions(img: NDArray, building: Building, s: float, off: NDArray) -> None:
    """Dimension lines 0.8 m outside the footprint's bounding box with ticks and their lengths, and a
    level mark."""
    x0, y0, x1, y1 = building.footprint.bounds
    d = 0.8
    xs = sorted({round(v, 2) for w in building.planned_walls if w.exterior for v in (w.x0, w.x1)})
    ys = sorted({round(v, 2) for w in building.planned_walls if w.exterior for v in (w.y0, w.y1)})
    _line(img, (x0, y0 - d), (x1, y0 - d), s, off)
    for x in xs:
        _line(img, (x - 0.1, y0 - d - 0.1), (x + 0.1, y0 - d + 0.1), s, off, _INK, 2)
        _line(img, (x, y0 - d - 0.2), (x, y0 - 0.15), s, off)
    for a, b in itertools.pairwise(xs):
        if b - a > 1.0:
            p = _pts(np.array([[(a + b) / 2, y0 - d - 0.25]]), s, off)[0] / _ONE
            _text(img, f"{b - a:.2f}", p, 0.0, 0.4)
    _line(img, (x1 + d, y0), (x1 + d, y1), s, off)
    for y in ys:
        _line(img, (x1 + d - 0.1, y - 0.1), (x1 + d + 0.1, y + 0.1), s, off, _INK, 2)
        _line(img, (x1 + 0.15, y), (x1 + d + 0.2, y), s, off)
    for a, b in itertools.pairwise(ys):
        if b - a > 1.0:
            p = _pts(np.array([[x1 + d + 0.3, (a + b) / 2]]), s, off)[0] / _ONE
            _text(img, f"{b - a:.2f}", p, 90.0, 0.4)
    hall = building.room("hall").polygon.representative_point()
    tri = Polygon([(hall.x - 0.15, hall.y + 0.6), (hall.x + 0.15, hall.y + 0.6), (hall.x, hall.y + 0.4)])
    _poly(img, tri, s, off, _INK, 1)
    p = _pts(np.array([[hall.x + 0.7, hall.y + 0.55]]), s, off)[0] / _ONE
    _text(img, "+0.00", p, 0.0, 0.4)


def _room_texts(img: NDArray, building: Building, s: float, off: NDArray, rng: np.random.Generator) -> None:
    """Room names, numbers and areas, some of them turned."""
    names = ["Office", "Lab", "Store", "Meeting", "Kitchen", "Bath"]
    for k, r in enumerate(building.rooms):
        p = r.polygon.representative_point()
        c = _pts(np.array([[p.x, p.y]]), s, off)[0] / _ONE
        ang = float(rng.choice([0.0, 0.0, 90.0, float(rng.uniform(-40, 40))]))
        if r.capture == "hallway":
            ang = 0.0
            c = c + np.array([0.0, -25.0])
        name = "Corridor" if r.capture == "hallway" else names[k % len(names)]
        t = np.array([-math.sin(math.radians(ang)), -math.cos(math.radians(ang))]) * 12
        _text(img, f"{name} {r.label}", c + t, ang, 0.45)
        _text(img, f"{r.polygon.area:.1f} m2", c - t, ang, 0.38)


def _sheet_extras(img: NDArray, plan_box: tuple[int, int, int, int], s: float, bar_m: float) -> tuple:
    """Legend panel with pictograms left of the plan, title block and scale bar under it; returns the
    scale bar's ends (sheet pixels)."""
    H, W = img.shape[:2]
    u0, v0, _u1, _v1 = plan_box
    # legend panel
    lx0, lx1 = 30, u0 - 60
    cv2.rectangle(img, (lx0, v0), (lx1, v0 + 420), _INK, 2)
    _text(img, "LEGEND", ((lx0 + lx1) / 2, v0 + 25), 0, 0.6)
    y = v0 + 60
    for k, what in enumerate(["Fire extinguisher", "Exit", "First aid", "Assembly", "Stair", "Lift"]):
        col = [(200, 30, 30), (20, 140, 60), (20, 140, 60), (20, 140, 60), (40, 40, 40), (30, 60, 180)][k]
        cv2.rectangle(img, (lx0 + 15, y), (lx0 + 45, y + 30), col, -1)
        cv2.circle(img, (lx0 + 30, y + 15), 8, (255, 255, 255), -1, cv2.LINE_AA)
        cv2.line(img, (lx0 + 22, y + 15), (lx0 + 38, y + 15), col, 2)
        _text(img, what, (lx0 + 55 + 70, y + 15), 0, 0.42)
        y += 55
    # title block along the bottom right
    tx0, ty0, tx1, ty1 = W - 420, H - 150, W - 30, H - 30
    cv2.rectangle(img, (tx0, ty0), (tx1, ty1), _INK, 2)
    for yy in (ty0 + 40, ty0 + 80):
        cv2.line(img, (tx0, yy), (tx1, yy), _INK, 1)
    cv2.line(img, (tx0 + 200, ty0 + 40), (tx0 + 200, ty1), _INK, 1)
    _text(img, "GROUND FLOOR PLAN", ((tx0 + tx1) / 2, ty0 + 20), 0, 0.6)
    _text(img, "Scale 1:100", (tx0 + 100, ty0 + 60), 0, 0.45)
    _text(img, "Drawn: AB", (tx0 + 300, ty0 + 60), 0, 0.45)
    _text(img, "Sheet A-101", (tx0 + 100, ty0 + 100), 0, 0.45)
    _text(img, "Rev. C", (tx0 + 300, ty0 + 100), 0, 0.45)
    # scale bar: alternating 1 m blocks, ends labelled
    n = round(bar_m / s)
    bx0, by = u0, H - 70
    if bar_m > 0:  # 0: a sheet without a scale bar (its scale is in the dimension lines)
        cv2.rectangle(img, (bx0, by - 8), (bx0 + n, by), _INK, 1)
        for k in range(round(bar_m)):
            if k % 2 == 0:
                a = bx0 + round(k / s)
                cv2.rectangle(img, (a, by - 8), (a + round(1 / s), by), _INK, -1)
        _text(img, "0", (bx0, by + 16), 0, 0.45)
        _text(img, f"{bar_m:g} m", (bx0 + n + 5, by + 16), 0, 0.45)
    return (float(bx0), float(by - 4), float(bx0 + n), float(by - 4))


def draw_sheet(
    building: Building, cfg: DrawingConfig, rng: np.random.Generator
) -> tuple[NDArray[np.uint8], NDArray[np.float64], tuple[float, float, float, float]]:
    """The clean architect's sheet: (H, W, 3) RGB, the plan-pixel -> sheet-pixel offset (2,), the scale
    bar's ends in sheet pixels. The sheet has the ISO aspect ratio."""
    s = cfg.m_per_px
    _xmin, ymin, xmax, _ymax = building.extent
    pw, ph = math.ceil(xmax / s), math.ceil(-ymin / s)
    left, top = 380, 60
    W = left + pw + 80
    H = max(top + ph + 200, round(W / SHEET_ASPECT))
    W = max(W, round(H * SHEET_ASPECT))
    img = np.full((H, W, 3), 255, np.uint8)
    off = np.array([left + (W - left - 80 - pw) / 2, top], np.float64)
    _walls(img, building, s, off, cfg.wall_style)
    _door_swings(img, building, s, off)
    _furniture(img, building, s, off, rng)
    _fixtures(img, building, s, off, rng)
    _dimensions(img, building, s, off)
    _room_texts(img, building, s, off, rng)
    box = (round(off[0]), round(off[1]), round(off[0] + pw), round(off[1] + ph))
    bar = _sheet_extras(img, box, s, cfg.scale_bar_m)
    cv2.rectangle(img, (8, 8), (W - 9, H - 9), _INK, 2)  # the drawing's border
    return img, off, bar


def _jpeg(img: NDArray[np.uint8], quality: int) -> NDArray[np.uint8]:
    _ok, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()


def _pen_marks(img: NDArray[np.uint8], rng: np.random.Generator, n: int) -> None:
    """Ballpoint scribbles: smooth curves in blue or red."""
    H, W = img.shape[:2]
    for _ in range(n):
        c = rng.uniform([0.1 * W, 0.1 * H], [0.9 * W, 0.9 * H])
        t = np.linspace(0, 1, 40)[:, None]
        a, b = rng.uniform(-60, 60, 2), rng.uniform(-60, 60, 2)
        pts = c + t * a * 2 + np.sin(t * math.pi * rng.uniform(1, 3)) * b
        col = [(30, 50, 170), (190, 30, 40)][int(rng.integers(2))]
        cv2.polylines(img, [np.rint(pts * _ONE).astype(np.int32)], False, col, 2, cv2.LINE_AA, _SHIFT)


def _scan(sheet: NDArray[np.uint8], cfg: DrawingConfig, rng: np.random.Generator) -> tuple:
    H, W = sheet.shape[:2]
    img = sheet.astype(np.float32)
    tone = np.array([250, 238, 210], np.float32) * rng.uniform(0.9, 1.0)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    fade = 1.0 - 0.08 * ((xx / W - rng.uniform()) ** 2 + (yy / H - rng.uniform()) ** 2)
    img = img / 255.0 * tone * fade[..., None]
    img += rng.normal(0, 6.0, img.shape).astype(np.float32)
    img = np.clip(img, 0, 255).astype(np.uint8)
    _pen_marks(img, rng, 3)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    ang = float(rng.uniform(-cfg.max_rotation_deg, cfg.max_rotation_deg))
    M = cv2.getRotationMatrix2D((W / 2, H / 2), ang, 1.0)
    paper = tuple(int(v) for v in tone)
    img = cv2.warpAffine(img, M, (W, H), flags=cv2.INTER_LINEAR, borderValue=paper)
    return _jpeg(img, cfg.jpeg_quality), np.vstack([M, [0, 0, 1]])


def _light_and_glare(img: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.uint8]:
    """A photo's light on an (h, w, 3) float image: it falls off across the sheet, and glare is a bright
    blob that washes the ink out; then sensor noise and a slight blur."""
    out_h, out_w = img.shape[:2]
    yy, xx = np.mgrid[0:out_h, 0:out_w].astype(np.float32)
    gx, gy = rng.uniform(0.3, 0.7) * out_w, rng.uniform(0.3, 0.7) * out_h
    r = 0.25 * max(out_w, out_h)
    glare = np.exp(-((xx - gx) ** 2 + (yy - gy) ** 2) / (2 * r * r))
    shade = 0.8 + 0.2 * (xx / out_w)
    img = img * shade[..., None] * 0.92 + 110.0 * glare[..., None]
    img += rng.normal(0, 4.0, img.shape).astype(np.float32)
    return cv2.GaussianBlur(np.clip(img, 0, 255).astype(np.uint8), (0, 0), 0.8)


def _photo(sheet: NDArray[np.uint8], cfg: DrawingConfig, rng: np.random.Generator) -> tuple:
    H, W = sheet.shape[:2]
    pad = 0.12 * max(W, H)
    out_w, out_h = round(W + 2 * pad), round(H + 2 * pad)
    src = np.float32([[0, 0], [W, 0], [W, H], [0, H]])
    shift = rng.uniform(-1, 1, (4, 2)) * cfg.max_corner_shift * min(W, H)
    dst = (src + pad + shift).astype(np.float32)
    Hm = cv2.getPerspectiveTransform(src, dst)
    # the wall behind the sheet: grey-beige with a texture
    yy, xx = np.mgrid[0:out_h, 0:out_w].astype(np.float32)
    wall = (
        np.array([150, 140, 125], np.float32) * (0.9 + 0.1 * np.sin(xx / 37.0) * np.cos(yy / 53.0))[..., None]
    )
    bg = np.clip(wall + rng.normal(0, 5, (out_h, out_w, 3)), 0, 255).astype(np.uint8)
    warped = cv2.warpPerspective(sheet, Hm, (out_w, out_h), flags=cv2.INTER_LINEAR, borderValue=0)
    inside = cv2.warpPerspective(np.full((H, W), 255, np.uint8), Hm, (out_w, out_h), flags=cv2.INTER_LINEAR)
    a = (inside.astype(np.float32) / 255.0)[..., None]
    img = bg * (1 - a) + warped.astype(np.float32) * a
    return _jpeg(_light_and_glare(img, rng), cfg.jpeg_quality), Hm


def _closeup(
    sheet: NDArray[np.uint8], cfg: DrawingConfig, rng: np.random.Generator, keep: tuple[float, ...]
) -> tuple:
    """A phone photo of the sheet from closer up: a pinhole camera (focal length 0.9 to 1.3 times the
    sheet's long side, principal point in the middle of the photo, square pixels) tilted about both of
    the sheet's axes and turned a little, the view cut to what lies inside the paper's margin (a print
    without the drawing's frame: no edge, no border) and aimed so that it holds the box `keep` (u0, v0, u1, v1 sheet pixels: the plan and its
    scale bar) where it can; glare, shade, noise, blur and JPEG. Returns the image and the (3, 3)
    sheet-to-image homography."""
    # a print without the drawing's frame, on paper reaching farther round the plan
    P = cfg.closeup_paper_px
    sheet = sheet.copy()
    cv2.rectangle(sheet, (8, 8), (sheet.shape[1] - 9, sheet.shape[0] - 9), (255, 255, 255), 4)
    sheet = cv2.copyMakeBorder(sheet, P, P, P, P, cv2.BORDER_CONSTANT, value=(255, 255, 255))
    keep = (keep[0] + P, keep[1] + P, keep[2] + P, keep[3] + P)
    H, W = sheet.shape[:2]
    f = float(rng.uniform(0.9, 1.3)) * max(W, H)
    a, b = np.radians(rng.uniform(-1, 1, 2) * cfg.max_tilt_deg)
    g = math.radians(float(rng.uniform(-3, 3)))
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(g), -math.sin(g), 0], [math.sin(g), math.cos(g), 0], [0, 0, 1]])
    R = rz @ ry @ rx
    K = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
    m = cfg.closeup_margin_px
    u0, v0, u1, v1 = keep
    want = np.array([[u0, v0, 1], [u1, v0, 1], [u1, v1, 1], [u0, v1, 1]], np.float64)
    best = None
    # the aim (the sheet point on the camera's axis): the sheet's middle, else the nearest point of a
    # grid whose view holds the plan and its scale bar
    steps = np.linspace(-0.1, 0.1, 5)
    grid = sorted(((du, dv) for du in steps for dv in steps), key=lambda t: abs(t[0]) + abs(t[1]))
    for du, dv in grid:
        aim = np.array([W * (0.5 + du), H * (0.5 + dv), 0.0])
        t = np.array([0.0, 0.0, f]) - R @ aim
        Hc = K @ np.column_stack([R[:, 0], R[:, 1], t])
        inner = np.array([[m, m, 1], [W - m, m, 1], [W - m, H - m, 1], [m, H - m, 1]], np.float64) @ Hc.T
        inner = inner[:, :2] / inner[:, 2:]
        # the largest upright box inside the sheet's inner margin centred on the principal point
        half_w = min(-max(inner[0, 0], inner[3, 0]), min(inner[1, 0], inner[2, 0]))
        half_h = min(-max(inner[0, 1], inner[1, 1]), min(inner[2, 1], inner[3, 1]))
        if half_w <= 0 or half_h <= 0:
            continue
        q = want @ Hc.T
        q = q[:, :2] / q[:, 2:]
        held = bool((np.abs(q[:, 0]) < half_w).all() and (np.abs(q[:, 1]) < half_h).all())
        if best is None or held:
            best = (Hc, half_w, half_h)
        if held:
            break
    Hm, half_w, half_h = best
    out_w, out_h = 2 * math.floor(half_w), 2 * math.floor(half_h)
    Hm = np.array([[1.0, 0, out_w / 2], [0, 1.0, out_h / 2], [0, 0, 1]]) @ Hm
    Hm /= Hm[2, 2]
    img = cv2.warpPerspective(sheet, Hm, (out_w, out_h), flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255))
    Hm = Hm @ np.array([[1.0, 0, P], [0, 1.0, P], [0, 0, 1]])  # from the unpadded sheet
    img = img.astype(np.float32)
    return _jpeg(_light_and_glare(img, rng), cfg.jpeg_quality), Hm


def render_drawing(building: Building, cfg: DrawingConfig | None = None, seed: int = 0) -> Drawing:
    """The architect's drawing of ``building``'s plan, degraded as `cfg.degrade` says (pure; deterministic
    for a seed)."""
    cfg = cfg or DrawingConfig()
    rng = np.random.default_rng(seed)
    sheet, off, bar = draw_sheet(building, cfg, rng)
    T0 = np.array([[1.0, 0, off[0]], [0, 1.0, off[1]], [0, 0, 1]])
    H, W = sheet.shape[:2]
    if cfg.degrade == "none":
        img, Hd = sheet, np.eye(3)
    elif cfg.degrade == "scan":
        img, Hd = _scan(sheet, cfg, rng)
    elif cfg.degrade == "photo":
        img, Hd = _photo(sheet, cfg, rng)
    elif cfg.degrade == "closeup":
        # what the photo should hold: the plan's box and the scale bar with its labels
        _x0, y_min, x_max, _y1 = building.extent
        pw, ph = x_max / cfg.m_per_px, -y_min / cfg.m_per_px
        keep = (
            min(off[0], bar[0]) - 10,
            off[1] - 10,
            max(off[0] + pw + 10, bar[2] + 60),
            max(off[1] + ph + 10, bar[1] + 25),
        )
        img, Hd = _closeup(sheet, cfg, rng, keep)
    else:
        raise ValueError(f"unknown degradation {cfg.degrade!r}")

    def m(p: NDArray) -> NDArray:
        q = np.column_stack([p, np.ones(len(p))]) @ Hd.T
        return q[:, :2] / q[:, 2:]

    ends = m(np.array([bar[:2], bar[2:]]))
    corners = m(np.array([[0, 0], [W, 0], [W, H], [0, H]], np.float64))
    return Drawing(
        image=img,
        m_per_px=cfg.m_per_px,
        to_image=Hd @ T0,
        scale_bar_px=(float(ends[0, 0]), float(ends[0, 1]), float(ends[1, 0]), float(ends[1, 1])),
        scale_bar_m=cfg.scale_bar_m,
        sheet_px=corners,
    )


def map_walls(walls_m: NDArray, drawing: Drawing, frame: NDArray[np.float64]) -> NDArray[np.float64]:
    """Plan-frame walls (K, 4) metres carried into the frame of a parse: `frame` (3, 3) maps image pixels
    to the parser's working pixels; the result is in metres at the drawing's true scale in that frame
    (the mean scale of the plan-to-frame mapping), x right and y up."""
    s = drawing.m_per_px
    full = frame @ drawing.to_image
    k = math.sqrt(abs(np.linalg.det(full[:2, :2] / full[2, 2])))
    p = np.asarray(walls_m, np.float64).reshape(-1, 2)
    q = np.column_stack([p[:, 0] / s, -p[:, 1] / s, np.ones(len(p))]) @ full.T
    q = q[:, :2] / q[:, 2:]
    return (np.column_stack([q[:, 0], -q[:, 1]]) * s / k).reshape(-1, 4)


def map_polygon(poly: Polygon, drawing: Drawing, frame: NDArray[np.float64]) -> Polygon:
    """A plan-frame polygon carried into a parse's frame like `map_walls`."""
    ext = np.asarray(poly.exterior.coords)
    seg = np.column_stack([ext, ext]).reshape(-1, 4)
    out = map_walls(seg, drawing, frame)[:, :2]
    return Polygon(out).buffer(0) if len(out) >= 3 else Polygon()


def non_plan_images(seed: int = 0) -> dict[str, NDArray[np.uint8]]:
    """Images that hold no floor plan: a photo of a wall (brick courses and a door frame), a page of
    text, a blank sheet with paper tone and noise."""
    rng = np.random.default_rng(seed)
    H, W = 900, 1200
    wall = np.full((H, W, 3), (170, 90, 70), np.float32)
    for row, y in enumerate(range(0, H, 30)):
        wall[y : y + 3] = (200, 195, 190)
        for x in range(-60 * (row % 2), W, 120):
            wall[y : y + 30, max(0, x) : max(0, x) + 4] = (200, 195, 190)
    wall += rng.normal(0, 12, wall.shape)
    cv2.rectangle(wall, (500, 200), (760, 899), (60, 45, 35), 25)
    photo = cv2.GaussianBlur(np.clip(wall, 0, 255).astype(np.uint8), (0, 0), 1.0)
    page = np.full((H, W, 3), 250, np.uint8)
    words = "the survey of the building was made in spring and the plan shows every room".split()
    for y in range(60, H - 40, 28):
        x = 60
        while x < W - 160:
            w = words[int(rng.integers(len(words)))]
            cv2.putText(page, w, (x, y), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (20, 20, 20), 1, cv2.LINE_AA)
            x += cv2.getTextSize(w, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)[0][0] + 12
    blank = np.clip(np.full((H, W, 3), (248, 240, 220), np.float32) + rng.normal(0, 5, (H, W, 3)), 0, 255)
    return {"wall photo": photo, "text page": page, "blank sheet": blank.astype(np.uint8)}
