"""The report's inline SVG: the fused floor (rooms, walls at their thickness, doors, changes) and a room's
height histogram. Plain strings, no scripts; hovering a wall shows its <title>."""

from __future__ import annotations

import math
from html import escape
from typing import Any

import numpy as np
from numpy.typing import NDArray

CHANGE_COLOURS = {"added": "#17a02a", "removed": "#dc1e1e", "unknown": "#9a9a9a"}
ROOM_FILLS = ("#e8f0fb", "#fbf1e3", "#e9f6ea", "#f6e8f3", "#fdf9dc", "#e6f5f6", "#f1ece4")
SUPPORT_SAMPLE_M = 0.05
SUPPORT_TOL_M = 0.10
SUPPORT_ANGLE_DEG = 10.0


def _num(value: float) -> str:
    return f"{value:.3f}".rstrip("0").rstrip(".") if math.isfinite(value) else "0"


def _pt(x: float, y: float) -> str:
    return f"{_num(x)},{_num(-y)}"  # SVG y points down; the plan's y up


def wall_outline(seg: NDArray, thickness_m: float) -> NDArray:
    """(4, 2) corners of a wall centreline's rectangle at its thickness."""
    a, b = np.asarray(seg[:2], float), np.asarray(seg[2:], float)
    d = b - a
    n = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-12) * thickness_m / 2
    return np.array([a + n, b + n, b - n, a - n])


def face_support(seg: NDArray, thickness_m: float, faces: NDArray) -> float:
    """Share of a wall centreline (sampled every 5 cm) that has a modelled room face beside it: parallel
    within 10 degrees, within half the thickness plus 10 cm, and not beyond the face's ends. 0 when no room
    saw it."""
    a, b = np.asarray(seg[:2], float), np.asarray(seg[2:], float)
    length = float(np.hypot(*(b - a)))
    if length == 0 or len(faces) == 0:
        return 0.0
    t = np.arange(max(2, math.ceil(length / SUPPORT_SAMPLE_M) + 1)) / max(
        1, math.ceil(length / SUPPORT_SAMPLE_M)
    )
    samples = a + np.outer(np.clip(t, 0, 1), b - a)
    f = np.asarray(faces, float).reshape(-1, 4)
    fd = f[:, 2:] - f[:, :2]
    flen = np.hypot(fd[:, 0], fd[:, 1])
    u = (b - a) / length
    cos = np.abs(fd @ u) / np.maximum(flen, 1e-12)
    keep = (flen > 0) & (cos >= math.cos(math.radians(SUPPORT_ANGLE_DEG)))
    if not keep.any():
        return 0.0
    f, fd, flen = f[keep], fd[keep], flen[keep]
    rel = samples[:, None, :] - f[None, :, :2]  # (S, F, 2)
    s = (rel * fd[None]).sum(axis=2) / flen[None] ** 2  # where along each face a sample falls
    dist = np.abs(rel[..., 0] * fd[None, :, 1] - rel[..., 1] * fd[None, :, 0]) / flen[None]
    dist = np.where((s >= 0) & (s <= 1), dist, np.inf)  # beside the face, not beyond its ends
    return float((dist.min(axis=1) <= thickness_m / 2 + SUPPORT_TOL_M).mean())


def _lines(features: list[dict[str, Any]], kind: str) -> list[tuple[NDArray, dict[str, Any]]]:
    out = []
    for feat in features:
        props = feat.get("properties") or {}
        geom = feat.get("geometry") or {}
        if props.get("kind") == kind and geom.get("type") == "LineString":
            coords = np.asarray(geom.get("coordinates"), float)
            if coords.ndim == 2 and len(coords) >= 2:
                out.append((np.concatenate([coords[0, :2], coords[-1, :2]]), props))
    return out


def floor_svg(floor: dict[str, Any], changes: dict[str, Any] | None, width_px: int = 1000) -> str:
    """The floor from floor.geojson (plan frame, metres) as one <svg>: rooms (each linked to its section),
    one <polygon class="wall"> per wall at its thickness with a <title> (thickness, origin, support, rooms),
    doors, and the changes from changes.geojson coloured by kind."""
    features = [f for f in floor.get("features", []) if isinstance(f, dict)]
    walls = _lines(features, "wall")
    faces = np.array([seg for seg, _ in _lines(features, "wall_face")]).reshape(-1, 4)
    doors = _lines(features, "door")
    rooms = [
        f
        for f in features
        if (f.get("properties") or {}).get("kind") == "room"
        and (f.get("geometry") or {}).get("type") == "Polygon"
    ]
    change_lines = []
    for feat in (changes or {}).get("features", []):
        geom, props = feat.get("geometry") or {}, feat.get("properties") or {}
        if geom.get("type") == "LineString" and len(geom.get("coordinates") or []) >= 2:
            c = np.asarray(geom["coordinates"], float)
            change_lines.append((np.concatenate([c[0, :2], c[-1, :2]]), props))
    pts = [seg.reshape(-1, 2) for seg, _ in walls + doors + change_lines]
    pts += [np.asarray(r["geometry"]["coordinates"][0], float)[:, :2] for r in rooms]
    if not pts:
        return '<p class="note">floor.geojson holds no rooms or walls.</p>'
    xy = np.concatenate(pts)
    lo, hi = xy.min(axis=0) - 0.6, xy.max(axis=0) + 0.6
    w, h = hi - lo
    height_px = round(width_px * h / max(w, 1e-9))
    parts = [
        f'<svg id="floor" xmlns="http://www.w3.org/2000/svg" viewBox="{_num(lo[0])} {_num(-hi[1])} {_num(w)} '
        f'{_num(h)}" width="{width_px}" height="{height_px}" role="img" aria-label="the fused floor">'
    ]
    parts.append('<g class="rooms">')
    for i, room in enumerate(rooms):
        props = room["properties"]
        rid = str(props.get("room_id") or props.get("id") or "")
        ring = np.asarray(room["geometry"]["coordinates"][0], float)[:, :2]
        area = props.get("area_m2")
        label = (
            f"{rid} (plan {props.get('plan_room', '?')}), {area:.2f} m²"
            if isinstance(area, int | float)
            else rid
        )
        centre = ring[:-1].mean(axis=0) if len(ring) > 1 else ring[0]
        parts.append(
            f'<a href="#room-{escape(rid)}"><polygon class="room" points="{" ".join(_pt(*p) for p in ring)}" '
            f'fill="{ROOM_FILLS[i % len(ROOM_FILLS)]}"><title>{escape(label)}</title></polygon>'
            f'<text x="{_num(centre[0])}" y="{_num(-centre[1])}" class="room-label">{escape(rid)}</text></a>'
        )
    parts.append('</g><g class="walls">')
    for seg, props in walls:
        t = float(props.get("thickness_m") or 0.0)
        support = props.get("support")
        if not isinstance(support, int | float):
            support = face_support(seg, t, faces)
        sides = props.get("rooms") or [props.get("room_left"), props.get("room_right")]
        sides = (
            " | ".join(str(s) if s else "outside" for s in sides) if isinstance(sides, list) else str(sides)
        )
        tip = (
            f"wall: thickness {100 * t:.1f} cm ({props.get('thickness_source', 'given')}), "
            f"origin {props.get('origin', '?')}, support {100 * float(support):.0f}% of its length, "
            f"rooms {sides}"
        )
        corners = wall_outline(seg, max(t, 0.02))
        parts.append(
            f'<polygon class="wall" data-origin="{escape(str(props.get("origin", "")))}" '
            f'points="{" ".join(_pt(*p) for p in corners)}"><title>{escape(tip)}</title></polygon>'
        )
    parts.append('</g><g class="doors">')
    for seg, props in doors:
        who = f"room {props['room_id']}" if props.get("room_id") else "the plan"
        parts.append(
            f'<line class="door door-{escape(str(props.get("source", "")))}" x1="{_num(seg[0])}" y1="{_num(-seg[1])}" '
            f'x2="{_num(seg[2])}" y2="{_num(-seg[3])}"><title>door seen by {escape(who)}, '
            f"{100 * float(np.hypot(*(seg[2:] - seg[:2]))):.0f} cm wide</title></line>"
        )
    parts.append('</g><g class="changes">')
    for seg, props in change_lines:
        kind = str(props.get("kind", "unknown"))
        colour = CHANGE_COLOURS.get(kind, CHANGE_COLOURS["unknown"])
        support = props.get("support")
        tip = f"{kind} wall" + (f" (room {props['room_id']})" if props.get("room_id") else "")
        if isinstance(support, int | float):
            tip += f", support {100 * support:.0f}%"
        parts.append(
            f'<line class="change change-{escape(kind)}" stroke="{colour}" x1="{_num(seg[0])}" y1="{_num(-seg[1])}" '
            f'x2="{_num(seg[2])}" y2="{_num(-seg[3])}"><title>{escape(tip)}</title></line>'
        )
    parts.append("</g>")
    # a 1 m scale bar and a north arrow in the lower left corner
    x0, y0 = lo[0] + 0.3, lo[1] + 0.3
    parts.append(
        f'<g class="furniture"><line x1="{_num(x0)}" y1="{_num(-y0)}" x2="{_num(x0 + 1)}" y2="{_num(-y0)}" '
        f'class="scale"/><text x="{_num(x0)}" y="{_num(-y0 - 0.12)}" class="small">1 m</text>'
        f'<polygon points="{_pt(x0 + 1.6, y0 + 0.9)} {_pt(x0 + 1.45, y0 + 0.3)} {_pt(x0 + 1.75, y0 + 0.3)}" '
        f'class="north"/><text x="{_num(x0 + 1.5)}" y="{_num(-y0 - 1.05)}" class="small">N</text></g>'
    )
    parts.append("</svg>")
    return "".join(parts)


def histogram_svg(
    z_low: NDArray,
    z_high: NDArray,
    counts: NDArray,
    marks: dict[str, float],
    band: tuple[float, float] | None,
) -> str:
    """A room's height histogram (points per height bin on a square-root scale, heights up the vertical
    axis) with its floor and ceiling marked and the furniture slice shaded, as an <svg> 420 x 300 px."""
    z_low, z_high, counts = (np.asarray(v, float) for v in (z_low, z_high, counts))
    if len(counts) == 0:
        return '<p class="note">empty height histogram</p>'
    width, height, left, bottom, top, right = 420, 300, 56, 36, 12, 110
    zmin, zmax = float(z_low.min()), float(z_high.max())
    cmax = max(float(counts.max()), 1.0)

    def y(z: float) -> float:
        return top + (zmax - z) / max(zmax - zmin, 1e-9) * (height - top - bottom)

    def x(c: float) -> float:  # square-root scale: the floor and ceiling peaks dwarf the walls linearly
        return left + math.sqrt(c / cmax) * (width - left - right)

    parts = [f'<svg class="histogram" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}">']
    if band is not None:
        parts.append(
            f'<rect x="{left}" y="{y(band[1]):.1f}" width="{width - left - right}" height="{y(band[0]) - y(band[1]):.1f}" '
            'fill="#fff1c9"><title>furniture slice (the walls stage reads it)</title></rect>'
        )
    for lo_, hi_, c in zip(z_low, z_high, counts, strict=True):
        if c > 0:
            parts.append(
                f'<rect x="{left}" y="{y(hi_):.1f}" width="{x(c) - left:.1f}" height="{max(y(lo_) - y(hi_), 0.5):.1f}" '
                f'fill="#4a6fa5"><title>{lo_:.2f}-{hi_:.2f} m: {int(c)} points</title></rect>'
            )
    for name, z in marks.items():
        if math.isfinite(z):
            parts.append(
                f'<line x1="{left}" x2="{width - right + 6}" y1="{y(z):.1f}" y2="{y(z):.1f}" stroke="#c0392b" '
                f'stroke-dasharray="4 3"/><text x="{width - right + 10}" y="{y(z) + 4:.1f}" class="hist-text">'
                f"{escape(name)} {z:.2f} m</text>"
            )
    parts.append(
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{height - bottom}" stroke="#333"/>'
        f'<line x1="{left}" y1="{height - bottom}" x2="{width - right}" y2="{height - bottom}" stroke="#333"/>'
    )
    step = 0.5 if zmax - zmin <= 4 else 1.0
    for k in range(math.ceil(zmin / step), math.floor(zmax / step) + 1):
        z = k * step
        parts.append(
            f'<text x="{left - 6}" y="{y(z) + 4:.1f}" text-anchor="end" class="hist-text">{z:.1f}</text>'
            f'<line x1="{left - 4}" x2="{left}" y1="{y(z):.1f}" y2="{y(z):.1f}" stroke="#333"/>'
        )
    parts.append(
        f'<text x="{left}" y="{height - bottom + 16}" class="hist-text">0</text>'
        f'<text x="{width - right}" y="{height - bottom + 16}" text-anchor="end" class="hist-text">{int(cmax)}</text>'
        f'<text x="{(left + width - right) / 2:.0f}" y="{height - 6}" text-anchor="middle" class="hist-text">'
        "points per bin (square-root scale)</text>"
        f'<text x="14" y="{(top + height - bottom) / 2:.0f}" class="hist-text" '
        f'transform="rotate(-90 14 {(top + height - bottom) / 2:.0f})" text-anchor="middle">height z (m)</text>'
    )
    parts.append("</svg>")
    return "".join(parts)
