"""An evacuation-plan-like raster of the AS-PLANNED building, and the survey overview picture.

Pixel (u, v) of the plan maps to the plan frame point (u * s, -v * s) metres (s = m_per_px), the same
frame as the building, so a parser that reads this image at its stated scale lands on the truth.
The drawing follows the photographed plans of thesis section 4.2.3: generalized black walls at their
thickness with door gaps, windows as thin lines, green escape-route arrows, red fire-equipment symbols,
room labels, a legend and a "you are here" mark.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from shapely.geometry import LineString, Polygon

from tasks.synth.building import Building, Opening, WallSegment

_SHIFT = 4
_ONE = 1 << _SHIFT


@dataclass(frozen=True)
class PlanRasterConfig:
    """Scale and styling of the plan raster."""

    m_per_px: float = 0.02
    """Plan scale (metres per pixel)."""
    legend_height_px: int = 170
    """Height of the legend band under the building."""
    window_line_px: int = 2
    """Width of the thin line that stands for a window."""
    symbol_size_px: int = 24
    """Side of a fire-equipment symbol."""
    arrow_spacing_m: float = 3.0
    """Spacing of the escape-route arrows along the corridor."""
    white: tuple[int, int, int] = (255, 255, 255)
    """Paper colour."""


@dataclass(frozen=True)
class PlanRaster:
    """The rendered plan."""

    image: NDArray[np.uint8]
    """(H, W, 3) RGB."""
    m_per_px: float
    """Scale: pixel (u, v) -> plan frame (u * m_per_px, -v * m_per_px) metres."""
    you_are_here_px: tuple[float, float]
    """Pixel position of the "you are here" mark."""


def to_px(xy, m_per_px: float) -> NDArray[np.float64]:
    """Plan frame points (..., 2) metres -> pixel coordinates (u, v)."""
    p = np.asarray(xy, dtype=np.float64)
    return np.stack([p[..., 0] / m_per_px, -p[..., 1] / m_per_px], axis=-1)


def _poly_px(poly: Polygon, s: float) -> NDArray[np.int32]:
    return np.rint(to_px(np.asarray(poly.exterior.coords)[:-1], s) * _ONE).astype(np.int32)


def _fill(img, poly: Polygon, s: float, colour) -> None:
    polys = getattr(poly, "geoms", [poly])
    for p in polys:
        if p.is_empty:
            continue
        cv2.fillPoly(img, [_poly_px(p, s)], colour, cv2.LINE_AA, _SHIFT)


def _wall_polygon(w: WallSegment) -> Polygon:
    # square caps close the outer corners of walls meeting at an angle; the partition stubs keep a flat end
    cap = "flat" if w.kind == "partition" else "square"
    return w.line.buffer(w.thickness_m / 2, cap_style=cap, join_style="mitre")


def _opening_gap(op: Opening) -> Polygon:
    return LineString([(op.x0, op.y0), (op.x1, op.y1)]).buffer(op.thickness_m / 2 + 0.02, cap_style="flat")


def _arrow(img, tail, head, colour, width_px: int) -> None:
    tail, head = np.asarray(tail, float), np.asarray(head, float)
    d = head - tail
    n = np.linalg.norm(d)
    if n < 1:
        return
    d /= n
    perp = np.array([-d[1], d[0]])
    hl = min(0.45 * n, 2.2 * width_px)
    body = [tail + perp * width_px / 2, head - d * hl + perp * width_px / 2]
    body += [head - d * hl + perp * width_px * 1.2, head, head - d * hl - perp * width_px * 1.2]
    body += [head - d * hl - perp * width_px / 2, tail - perp * width_px / 2]
    cv2.fillPoly(img, [np.rint(np.array(body) * _ONE).astype(np.int32)], colour, cv2.LINE_AA, _SHIFT)


def _fire_symbol(img, centre, size: int) -> None:
    c = np.asarray(centre, float)
    h = size / 2
    p0, p1 = np.rint(c - h).astype(int), np.rint(c + h).astype(int)
    cv2.rectangle(img, tuple(p0), tuple(p1), (220, 30, 30), -1)
    # an extinguisher silhouette in white
    body = (int(c[0]), int(c[1] + size * 0.08))
    cv2.ellipse(
        img, body, (max(2, size // 7), max(3, size // 3)), 0, 0, 360, (255, 255, 255), -1, cv2.LINE_AA
    )
    cv2.line(
        img,
        (int(c[0]), int(c[1] - size * 0.3)),
        (int(c[0] + size * 0.25), int(c[1] - size * 0.38)),
        (255, 255, 255),
        2,
    )


def _you_are_here(img, centre, size: int) -> None:
    c = tuple(round(v) for v in centre)
    cv2.circle(img, c, size, (20, 60, 200), -1, cv2.LINE_AA)
    cv2.circle(img, c, size // 2, (255, 255, 255), -1, cv2.LINE_AA)
    cv2.circle(img, c, max(2, size // 4), (20, 60, 200), -1, cv2.LINE_AA)


def _text(img, text: str, org, scale: float, colour=(0, 0, 0), thickness: int = 1) -> None:
    cv2.putText(
        img,
        text,
        tuple(round(v) for v in org),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        colour,
        thickness,
        cv2.LINE_AA,
    )


def _centred_text(img, text: str, centre, scale: float, colour=(0, 0, 0), thickness: int = 1) -> None:
    (w, h), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    _text(img, text, (centre[0] - w / 2, centre[1] + h / 2), scale, colour, thickness)


def image_size(building: Building, cfg: PlanRasterConfig) -> tuple[int, int]:
    """(width, height) in pixels of the plan of ``building``."""
    _xmin, ymin, xmax, _ymax = building.extent
    return math.ceil(xmax / cfg.m_per_px), math.ceil(-ymin / cfg.m_per_px) + cfg.legend_height_px


def render_plan(building: Building, cfg: PlanRasterConfig | None = None) -> PlanRaster:
    """Draw the as-planned floor of ``building`` as an evacuation plan (pure; no file I/O)."""
    cfg = cfg or PlanRasterConfig()
    s = cfg.m_per_px
    w, h = image_size(building, cfg)
    img = np.full((h, w, 3), cfg.white, dtype=np.uint8)
    # rooms first (pale fill, as printed plans tint rooms), then walls on top
    for room in building.rooms:
        if room.capture == "hallway":
            _fill(img, room.cell, s, (232, 245, 232))
    for wall in building.planned_walls:
        _fill(img, _wall_polygon(wall), s, (0, 0, 0))
    for op in building.planned_openings:
        _fill(img, _opening_gap(op), s, cfg.white)
        if op.kind == "window":
            a, b = to_px([(op.x0, op.y0), (op.x1, op.y1)], s)
            cv2.line(
                img,
                tuple(np.rint(a * _ONE).astype(int)),
                tuple(np.rint(b * _ONE).astype(int)),
                (0, 0, 0),
                cfg.window_line_px,
                cv2.LINE_AA,
                _SHIFT,
            )
    hall = building.room("hall")
    # escape-route arrows along the corridor towards the exit, and out of each room door
    minx, miny, maxx, maxy = hall.polygon.bounds
    ymid = 0.5 * (miny + maxy)
    xs = np.arange(maxx - 1.0, minx + 0.5, -cfg.arrow_spacing_m)
    for x in xs:
        tail, head = to_px([(x, ymid), (max(x - 1.2, minx + 0.3), ymid)], s)
        _arrow(img, tail, head, (0, 150, 60), 10)
    for room in building.rooms:
        if room.door is None or room.capture == "hallway":
            continue
        c = np.asarray(room.door.centre)
        into_hall = np.sign(ymid - c[1])
        tail, head = to_px([c - np.array([0.0, into_hall * 0.9]), c + np.array([0.0, into_hall * 0.35])], s)
        _arrow(img, tail, head, (0, 150, 60), 8)
    exit_px = to_px(building.exit_xy, s)
    cv2.rectangle(
        img,
        tuple((exit_px + np.array([-14, -30])).astype(int)),
        tuple((exit_px + np.array([34, -12])).astype(int)),
        (0, 150, 60),
        -1,
    )
    _text(img, "EXIT", exit_px + np.array([-11, -15]), 0.4, (255, 255, 255), 1)
    for xy in building.extinguishers:
        _fire_symbol(img, to_px(xy, s), cfg.symbol_size_px)
    for room in building.rooms:
        p = room.cell.representative_point() if room.shape in ("l_shaped", "storage") else room.cell.centroid
        if room.capture == "hallway":
            p = hall.polygon.centroid
            c = to_px((p.x + 1.5, p.y - 0.45), s)
            _centred_text(img, room.label, c, 0.5, (0, 0, 0), 1)
            continue
        _centred_text(
            img, room.label, to_px((p.x, p.y), s), 0.6 if room.capture != "none" else 0.4, (0, 0, 0), 1
        )
    yah = to_px(building.you_are_here, s)
    _you_are_here(img, yah, 11)
    _legend(img, building, cfg)
    return PlanRaster(image=img, m_per_px=s, you_are_here_px=(float(yah[0]), float(yah[1])))


def _legend(img, building: Building, cfg: PlanRasterConfig) -> None:
    h, w = img.shape[:2]
    top = h - cfg.legend_height_px + 20
    cv2.rectangle(img, (10, top), (w - 10, h - 10), (0, 0, 0), 1)
    _text(img, "Evacuation plan - floor 1", (24, top + 28), 0.7, (0, 0, 0), 2)
    y = top + 70
    _arrow(img, (30, y), (80, y), (0, 150, 60), 10)
    _text(img, "Escape route", (95, y + 6), 0.5)
    _fire_symbol(img, (270, y), cfg.symbol_size_px)
    _text(img, "Fire extinguisher", (292, y + 6), 0.5)
    _you_are_here(img, (480, y), 11)
    _text(img, "You are here", (500, y + 6), 0.5)
    # scale bar: 5 m
    y2 = top + 118
    n = round(5.0 / cfg.m_per_px)
    cv2.rectangle(img, (30, y2 - 6), (30 + n, y2), (0, 0, 0), -1)
    for k in range(6):
        x = 30 + round(k / cfg.m_per_px)
        cv2.line(img, (x, y2 - 12), (x, y2), (0, 0, 0), 1)
    _text(img, "5 m", (40 + n, y2 + 2), 0.5)
    _text(img, f"1 px = {cfg.m_per_px * 1000:.0f} mm", (110 + n, y2 + 2), 0.45)


def render_overview(
    building: Building,
    plan: PlanRaster,
    trajectories: dict[str, NDArray[np.float64]],
    scanners: dict[str, NDArray[np.float64]],
    track_xy: NDArray[np.float64] | None = None,
    track_true_xy: NDArray[np.float64] | None = None,
) -> NDArray[np.uint8]:
    """The plan raster beside the true (as-built) floor with the capture trajectories drawn.

    trajectories: room id -> (N, 2 or 3) camera positions (plan frame, m); scanners: room id -> (S, 2 or 3)
    TLS positions; track_xy / track_true_xy: (M, 2) IMU track with drift / without. Returns (H, 2W, 3) RGB."""
    s = plan.m_per_px
    h, w = plan.image.shape[:2]
    img = np.full((h, w, 3), 255, dtype=np.uint8)
    # trajectory colours; orange is kept for the IMU track
    colours = [
        (31, 119, 180),
        (214, 39, 40),
        (44, 160, 44),
        (148, 103, 189),
        (23, 190, 207),
        (140, 86, 75),
        (188, 189, 34),
    ]
    for room in building.rooms:
        _fill(img, room.polygon, s, (245, 245, 240) if room.capture != "none" else (225, 225, 225))
    solid = building.footprint.difference(_union([r.polygon for r in building.rooms]))
    for g in getattr(solid, "geoms", [solid]):
        ext = _poly_px(g, s)
        holes = [np.rint(to_px(np.asarray(i.coords)[:-1], s) * _ONE).astype(np.int32) for i in g.interiors]
        cv2.fillPoly(img, [ext, *holes], (90, 90, 90), cv2.LINE_AA, _SHIFT)
    for op in building.built_openings:
        if op.kind == "window":
            _fill(img, _opening_gap(op).intersection(solid), s, (150, 200, 240))
        else:
            _fill(img, _opening_gap(op).intersection(solid), s, (245, 245, 240))
    for f in building.furniture:
        if f.kind in ("lamp", "poster"):
            continue
        pts = np.rint(to_px(np.asarray(f.footprint.exterior.coords)[:-1], s) * _ONE).astype(np.int32)
        cv2.polylines(img, [pts], True, (170, 140, 110), 1, cv2.LINE_AA, _SHIFT)
    for ch in building.changes:
        col = (230, 0, 0) if ch.kind == "added" else (0, 90, 255)
        a, b = to_px([(ch.x0, ch.y0), (ch.x1, ch.y1)], s)
        cv2.line(
            img,
            tuple(np.rint(a * _ONE).astype(int)),
            tuple(np.rint(b * _ONE).astype(int)),
            col,
            4,
            cv2.LINE_AA,
            _SHIFT,
        )
    if track_true_xy is not None and len(track_true_xy) > 1:
        pts = np.rint(to_px(np.asarray(track_true_xy)[:, :2], s) * _ONE).astype(np.int32)
        cv2.polylines(img, [pts], False, (160, 160, 160), 1, cv2.LINE_AA, _SHIFT)
    if track_xy is not None and len(track_xy) > 1:
        pts = to_px(np.asarray(track_xy)[:, :2], s)
        for i in range(0, len(pts) - 1, 2):
            a, b = pts[i], pts[i + 1]
            cv2.line(
                img,
                tuple(np.rint(a * _ONE).astype(int)),
                tuple(np.rint(b * _ONE).astype(int)),
                (255, 140, 0),
                2,
                cv2.LINE_AA,
                _SHIFT,
            )
    for k, (rid, traj) in enumerate(sorted(trajectories.items())):
        col = colours[k % len(colours)]
        pts = to_px(np.asarray(traj)[:, :2], s)
        cv2.polylines(img, [np.rint(pts * _ONE).astype(np.int32)], False, col, 2, cv2.LINE_AA, _SHIFT)
        for p in pts:
            cv2.circle(img, tuple(round(v) for v in p), 3, col, -1, cv2.LINE_AA)
        _text(img, rid, pts[0] + (5, -5), 0.45, col, 1)
    for rid, pos in sorted(scanners.items()):
        for p in to_px(np.asarray(pos)[:, :2], s):
            c = tuple(round(v) for v in p)
            cv2.drawMarker(img, c, (200, 0, 120), cv2.MARKER_TILTED_CROSS, 16, 3, cv2.LINE_AA)
        _text(
            img, f"{rid} (TLS)", to_px(np.asarray(pos)[0, :2], s) + np.array([10, 15]), 0.45, (200, 0, 120), 1
        )
    for room in building.rooms:
        p = room.polygon.representative_point()
        _centred_text(img, room.label, to_px((p.x, p.y), s), 0.45, (60, 60, 60), 1)
    _you_are_here(img, to_px(building.you_are_here, s), 9)
    top = h - 150
    cv2.rectangle(img, (10, top), (w - 10, h - 10), (0, 0, 0), 1)
    _text(img, "As built (truth) with captures", (24, top + 28), 0.7, (0, 0, 0), 2)
    _text(
        img,
        "dots: depth camera positions per room; x: TLS stations; orange: IMU track (drift), grey: true",
        (24, top + 60),
        0.45,
    )
    _text(
        img, "red: added in the building; blue: in the plan only (removed / moved door)", (24, top + 85), 0.45
    )
    sep = np.full((h, 6, 3), 0, dtype=np.uint8)
    return np.concatenate([plan.image, sep, img], axis=1)


def _union(polys):
    import shapely

    return shapely.union_all(polys)
