"""Pictures for people: a north-up drawing in metres framed with a title, axes in metres, a 1 m scale bar,
a legend for every colour drawn and a north arrow (plan up).

A stage draws its data as it likes into an RGB array whose pixels map to metres by a `View`; `frame_picture`
puts the frame around it. Drawn with OpenCV only, so the same drawing gives the same bytes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

Colour = tuple[int, int, int]
"""RGB, 0-255."""

BLACK: Colour = (0, 0, 0)
WHITE: Colour = (255, 255, 255)
AXIS_GREY: Colour = (90, 90, 90)
FONT = cv2.FONT_HERSHEY_SIMPLEX

TITLE_PX = 36
"""Height of the title band at the top of every framed picture."""
LEFT_PX = 70
BOTTOM_PX = 48
PANEL_MIN_PX = 190
TICK_STEPS_M = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
MIN_TICK_GAP_PX = 70


@dataclass(frozen=True)
class View:
    """How the pixels of a north-up drawing map to metres: the left edge of pixel column c lies at
    x = x0_m + c * m_per_px, the top edge of pixel row r at y = y_top_m - r * m_per_px (y up)."""

    x0_m: float
    y_top_m: float
    m_per_px: float

    def __post_init__(self) -> None:
        if not (self.m_per_px > 0 and math.isfinite(self.m_per_px)):
            raise ValueError(f"a view's scale must be positive metres per pixel, got {self.m_per_px}")


@dataclass(frozen=True)
class Key:
    """One legend entry: what a colour means and how it is drawn (a line, a dashed line, a filled box or a
    dot)."""

    label: str
    colour: Colour
    mark: Literal["line", "dash", "box", "dot"] = "line"


def tick_step(m_per_px: float, min_gap_px: float = MIN_TICK_GAP_PX) -> float:
    """The smallest of 0.1, 0.2, 0.5, 1, 2, 5... metres whose ticks lie at least `min_gap_px` apart."""
    for step in TICK_STEPS_M:
        if step / m_per_px >= min_gap_px:
            return step
    return TICK_STEPS_M[-1]


def _label(value: float) -> str:
    text = f"{value:.1f}" if abs(value - round(value)) > 1e-9 else f"{round(value)}"
    return "0" if text in ("-0", "-0.0") else text


def ui_scale(height_px: int, width_px: int) -> float:
    """How much larger than at 1x the frame's text and marks are drawn, so that a large drawing shown
    shrunk on a page stays readable: 1, 1.5 or 2."""
    side = max(height_px, width_px)
    return 1.0 if side < 1100 else 1.5 if side < 1900 else 2.0


def _text(img: NDArray, text: str, org: tuple[int, int], scale: float = 0.45, thick: int = 1) -> None:
    cv2.putText(img, text, org, FONT, scale, BLACK, thick, cv2.LINE_AA)


def _text_width(text: str, scale: float = 0.45, thick: int = 1) -> int:
    return cv2.getTextSize(text, FONT, scale, thick)[0][0]


def _ticks(lo: float, hi: float, step: float) -> list[float]:
    first = math.ceil(lo / step - 1e-9)
    last = math.floor(hi / step + 1e-9)
    return [k * step for k in range(first, last + 1)]


def _draw_key(img: NDArray, key: Key, x: int, y: int, k: float) -> None:
    """The key's mark in a 28k x 12k px box with its left end at (x, y - 6k), its label to the right."""
    colour = tuple(int(c) for c in key.colour)
    r, length, t = round(6 * k), round(28 * k), max(1, round(k))
    if key.mark == "box":
        cv2.rectangle(img, (x, y - r), (x + length, y + r), colour, -1)
        cv2.rectangle(img, (x, y - r), (x + length, y + r), AXIS_GREY, 1)
    elif key.mark == "dot":
        cv2.circle(img, (x + length // 2, y), r, colour, -1, cv2.LINE_AA)
    elif key.mark == "dash":
        dash = length // 5
        for x0 in range(x, x + length, 2 * dash):
            cv2.line(img, (x0, y), (min(x0 + dash, x + length), y), colour, 3 * t, cv2.LINE_AA)
    else:
        cv2.line(img, (x, y), (x + length, y), colour, 4 * t, cv2.LINE_AA)
    _text(img, key.label, (x + length + round(8 * k), y + round(5 * k)), 0.45 * k, t)


def _north_arrow(img: NDArray, cx: int, top: int, k: float) -> int:
    """A north arrow (plan up) with the N at (cx, top); returns the y below it."""
    t = max(1, round(k))
    tip, base, half = (cx, top + round(18 * k)), top + round(58 * k), round(10 * k)
    notch = (cx, base - half)
    cv2.fillPoly(img, [np.array([tip, (cx - half, base), notch], np.int32)], BLACK, cv2.LINE_AA)
    cv2.polylines(img, [np.array([tip, (cx + half, base), notch], np.int32)], True, BLACK, t, cv2.LINE_AA)
    _text(img, "N", (cx - round(6 * k), top + round(12 * k)), 0.5 * k, 2 * t)
    note = "(plan up)"
    _text(img, note, (cx - _text_width(note, 0.4 * k, t) // 2, base + round(16 * k)), 0.4 * k, t)
    return base + round(24 * k)


def frame_picture(
    img: NDArray[np.uint8],
    view: View,
    title: str,
    legend: Sequence[Key],
    axes_note: str = "metres",
) -> NDArray[np.uint8]:
    """`img` (H, W, 3) RGB, north up, framed: a title band on top, axes in metres (ticks every 0.5, 1, 2, 5...
    m, labelled, x below and y on the left), and a panel on the right with the legend, a north arrow and a
    1 m scale bar. Text and marks grow with the picture (`ui_scale`). Returns a new (H', W', 3) RGB uint8
    array with the drawing copied unchanged."""
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"a picture to frame must be (H, W, 3) uint8 RGB, got {img.shape} {img.dtype}")
    h, w = img.shape[:2]
    k = ui_scale(h, w)
    t = max(1, round(k))
    small, normal = 0.42 * k, 0.45 * k
    bar_px = max(1, round(1.0 / view.m_per_px))
    label_w = max((_text_width(key.label, normal, t) for key in legend), default=0)
    panel = max(round(PANEL_MIN_PX * k), bar_px + round(40 * k), label_w + round(60 * k))
    panel_h = round((28 + 20 * len(legend) + 140) * k)
    top, left, bottom = round(TITLE_PX * k), round(LEFT_PX * k), round(BOTTOM_PX * k)
    canvas = np.full((top + max(h, panel_h) + bottom, left + w + panel, 3), 255, np.uint8)
    canvas[top : top + h, left : left + w] = img
    cv2.rectangle(canvas, (left - 1, top - 1), (left + w, top + h), AXIS_GREY, 1)

    # axes: x along the bottom edge, y along the left edge, in metres
    x_lo, x_hi = view.x0_m, view.x0_m + w * view.m_per_px
    y_hi, y_lo = view.y_top_m, view.y_top_m - h * view.m_per_px
    step = tick_step(view.m_per_px, MIN_TICK_GAP_PX * k)
    tick = round(6 * k)
    for x in _ticks(x_lo, x_hi, step):
        col = left + round((x - x_lo) / view.m_per_px)
        cv2.line(canvas, (col, top + h), (col, top + h + tick), AXIS_GREY, t)
        text = _label(x)
        _text(canvas, text, (col - _text_width(text, small, t) // 2, top + h + round(20 * k)), small, t)
    for y in _ticks(y_lo, y_hi, step):
        row = top + round((y_hi - y) / view.m_per_px)
        cv2.line(canvas, (left - tick, row), (left - 1, row), AXIS_GREY, t)
        text = _label(y)
        baseline = min(max(row + round(5 * k), top + round(10 * k)), top + h)
        _text(canvas, text, (left - tick - round(4 * k) - _text_width(text, small, t), baseline), small, t)
    _text(canvas, f"x, y in {axes_note}", (left, top + h + round(40 * k)), small, t)

    _text(canvas, title, (round(10 * k), round(25 * k)), 0.65 * k, 2 * t)

    # the panel: legend, north arrow, scale bar
    px = left + w + round(16 * k)
    y = top + round(14 * k)
    _text(canvas, "legend", (px, y), normal, t)
    y += round(22 * k)
    for key in legend:
        _draw_key(canvas, key, px, y, k)
        y += round(20 * k)
    y = _north_arrow(canvas, px + round(20 * k), y + round(6 * k), k) + round(14 * k)
    cv2.rectangle(canvas, (px, y), (px + bar_px, y + round(6 * k)), BLACK, -1)
    for end in (px, px + bar_px):
        cv2.line(canvas, (end, y - round(3 * k)), (end, y + round(9 * k)), BLACK, t)
    _text(canvas, "1 m", (px, y + round(26 * k)), normal, t)
    return canvas


def retitle(framed: NDArray[np.uint8], title: str) -> NDArray[np.uint8]:
    """A picture `frame_picture` made, with its title replaced (the band above the drawing's border)."""
    out = np.array(framed, dtype=np.uint8, copy=True)
    grey = np.all(out == AXIS_GREY, axis=2).sum(axis=1) >= 0.3 * out.shape[1]
    if not grey.any():
        raise ValueError("retitle: not a picture framed by tasks.preview.frame_picture (no border found)")
    band = int(np.argmax(grey)) + 1  # the border row lies just above the drawing
    k = band / TITLE_PX
    out[: band - 1] = 255
    _text(out, title, (round(10 * k), round(25 * k)), 0.65 * k, 2 * max(1, round(k)))
    return out
