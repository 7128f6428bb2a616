"""The overlay picture of the floor's changes: the plan in grey, added walls in green, removed walls in
red, unknown ones in dashed orange, room-level changes outlined in blue; framed with a title, axes in
metres of the plan frame, a legend of the colours drawn, a north arrow and a 1 m bar (tasks.preview)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.changes.detect import ADDED, REMOVED, Change, RoomChange
from tasks.lines import as_segments
from tasks.preview import Key, View, frame_picture

GREY, GREEN, RED, ORANGE, BLUE = (150, 150, 150), (20, 160, 40), (220, 30, 30), (240, 150, 20), (40, 90, 220)
ROOM_FILL = (235, 235, 235)


def overlay_png(
    centrelines: NDArray,
    thickness: NDArray,
    plan_rooms: dict,
    changes: list[Change],
    room_changes: list[RoomChange],
    px_per_m: float = 40.0,
    margin_m: float = 1.0,
) -> NDArray[np.uint8]:
    """(H, W, 3) RGB: plan walls at their thickness in grey, changes on top (y up in the plan is up),
    framed by tasks.preview.frame_picture."""
    segs = as_segments(centrelines)
    pts = [segs.reshape(-1, 2)] + [np.array([[c.x0, c.y0], [c.x1, c.y1]]) for c in changes]
    xy = np.concatenate(pts) if len(segs) or changes else np.zeros((1, 2))
    lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    w, h = (np.ceil((hi - lo) * px_per_m)).astype(int) + 1
    img = np.full((h, w, 3), 255, np.uint8)

    def px(p: NDArray) -> tuple[int, int]:
        return round(float(p[0] - lo[0]) * px_per_m), round(float(hi[1] - p[1]) * px_per_m)

    for poly in plan_rooms.values():
        ring = np.array([px(p) for p in np.asarray(poly.exterior.coords)], np.int32)
        cv2.fillPoly(img, [ring], ROOM_FILL)
    for s, t in zip(segs, thickness, strict=True):
        cv2.line(img, px(s[:2]), px(s[2:]), GREY, max(1, round(t * px_per_m)), cv2.LINE_AA)
    for r in room_changes:
        for part in getattr(r.polygon, "geoms", [r.polygon]):
            ring = np.array([px(p) for p in np.asarray(part.exterior.coords)], np.int32)
            cv2.polylines(img, [ring], True, BLUE, 2, cv2.LINE_AA)
    for c in changes:
        a, b = px(np.array([c.x0, c.y0])), px(np.array([c.x1, c.y1]))
        if c.kind in (ADDED, REMOVED):
            cv2.line(img, a, b, GREEN if c.kind == ADDED else RED, 5, cv2.LINE_AA)
        else:
            _dashed(img, np.array(a, float), np.array(b, float), ORANGE)
    kinds = {c.kind for c in changes}
    legend = [Key("plan room", ROOM_FILL, "box")] if plan_rooms else []
    legend += [Key("plan wall", GREY)] if len(segs) else []
    legend += [Key("added wall", GREEN)] if ADDED in kinds else []
    legend += [Key("removed wall", RED)] if REMOVED in kinds else []
    legend += [Key("unknown (not seen)", ORANGE, "dash")] if kinds - {ADDED, REMOVED} else []
    legend += [Key("room change", BLUE)] if room_changes else []
    half = 0.5 / px_per_m  # px() puts a point at a pixel centre
    view = View(float(lo[0]) - half, float(hi[1]) + half, 1.0 / px_per_m)
    return frame_picture(img, view, "floor: changes against the plan", legend, "metres, plan frame")


def _dashed(img: NDArray, a: NDArray, b: NDArray, colour: tuple[int, int, int], dash: float = 8.0) -> None:
    n = max(int(np.hypot(*(b - a)) / dash), 1)
    for k in range(0, n, 2):
        p, q = a + (b - a) * k / n, a + (b - a) * min(k + 1, n) / n
        cv2.line(img, tuple(int(v) for v in p), tuple(int(v) for v in q), colour, 3, cv2.LINE_AA)
