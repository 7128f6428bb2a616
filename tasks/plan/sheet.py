"""The sheet a plan is printed on: its border in a photo (for perspective rectification) and the printed
scale bar (for the scale when none is given)."""

from __future__ import annotations

import logging
import re

import cv2
import numpy as np
from numpy.typing import NDArray

log = logging.getLogger(__name__)


def find_sheet(
    image: NDArray[np.uint8], min_area_share: float, min_contrast: float = 25.0
) -> NDArray[np.float64] | None:
    """The four corners (4, 2) of the paper sheet in a photo (clockwise from top-left), when its edges
    show: the outermost long straight edges, two roughly horizontal and two roughly vertical, enclosing
    at least min_area_share of the image, with the outside darker by min_contrast grey levels on average.
    None otherwise (a scan, a drawing on a white page, a photo cropped inside the sheet)."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), (0, 0), 2)
    h, w = grey.shape
    edges = cv2.Canny(grey, 8, 24)
    min_len = 0.3 * min(h, w)
    found = cv2.HoughLinesP(
        edges, 1, np.pi / 720, int(min_len / 2), minLineLength=min_len, maxLineGap=round(0.02 * max(h, w))
    )
    if found is None:
        return None
    segs = found.reshape(-1, 4).astype(np.float64)
    d = segs[:, 2:] - segs[:, :2]
    horizontal = np.abs(d[:, 0]) >= np.abs(d[:, 1])
    margin = 0.01 * max(h, w)
    sides = []
    for sel, axis, centre in ((horizontal, 1, w / 2), (~horizontal, 0, h / 2)):
        s = segs[sel]
        if len(s) < 2:
            return None
        # the line's position across (v for a horizontal line) at the image's middle
        a, b = s[:, :2], s[:, 2:]
        t = (centre - a[:, 1 - axis]) / np.where(
            b[:, 1 - axis] == a[:, 1 - axis], 1e-9, b[:, 1 - axis] - a[:, 1 - axis]
        )
        pos = a[:, axis] + t * (b[:, axis] - a[:, axis])
        size = h if axis == 1 else w
        inner = (pos > margin) & (pos < size - 1 - margin)
        if inner.sum() < 2:
            return None
        s, pos = s[inner], pos[inner]
        sides += [s[int(np.argmin(pos))], s[int(np.argmax(pos))]]
    top, bottom, left, right = sides
    quad = [_meet(top, left), _meet(top, right), _meet(bottom, right), _meet(bottom, left)]
    if any(q is None for q in quad):
        return None
    quad_a = np.array(quad, np.float64)
    if cv2.contourArea(quad_a.astype(np.float32)) < min_area_share * h * w:
        return None
    quad_a = _clockwise(quad_a)
    # paper is brighter than what is around it; a building outline on a white page is not a sheet
    inside = np.zeros((h, w), np.uint8)
    cv2.fillPoly(inside, [np.round(quad_a).astype(np.int32)], 1)
    if inside.all() or float(grey[inside == 0].mean()) > float(grey[inside > 0].mean()) - min_contrast:
        return None
    return quad_a


def _meet(p: NDArray, q: NDArray) -> NDArray[np.float64] | None:
    """Intersection of the lines through segments p and q (x0, y0, x1, y1)."""
    a, b, c, d = p[:2], p[2:], q[:2], q[2:]
    r, s = b - a, d - c
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-9:
        return None
    t = ((c[0] - a[0]) * s[1] - (c[1] - a[1]) * s[0]) / den
    return a + t * r


def _clockwise(quad: NDArray[np.float64]) -> NDArray[np.float64]:
    """Corners ordered clockwise (image v down) from the top-left one."""
    c = quad.mean(axis=0)
    ang = np.arctan2(quad[:, 1] - c[1], quad[:, 0] - c[0])
    q = quad[np.argsort(ang)]
    start = int(np.argmin(q.sum(axis=1)))
    return np.roll(q, -start, axis=0)


def sheet_homography(
    corners: NDArray[np.float64], aspect: float
) -> tuple[NDArray[np.float64], tuple[int, int]]:
    """Homography (3, 3) taking the photographed sheet corners to an upright rectangle with the sheet's
    side ratio `aspect` (long / short) and the photo's mean area, and that rectangle's (width, height)."""
    c = np.asarray(corners, np.float64)
    w = 0.5 * (np.hypot(*(c[1] - c[0])) + np.hypot(*(c[2] - c[3])))
    h = 0.5 * (np.hypot(*(c[3] - c[0])) + np.hypot(*(c[2] - c[1])))
    area = w * h
    if w >= h:
        w, h = np.sqrt(area * aspect), np.sqrt(area / aspect)
    else:
        w, h = np.sqrt(area / aspect), np.sqrt(area * aspect)
    dst = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    H = cv2.getPerspectiveTransform(c.astype(np.float32), dst).astype(np.float64)
    return H, (round(w), round(h))


_NUMBER = re.compile(r"^(\d+(?:[.,]\d+)?)(m)?$")


def read_scale_bar(image: NDArray[np.uint8], dark: NDArray[np.bool_]) -> tuple[float, tuple] | None:
    """Metres per pixel from a printed scale bar: a label "<n> m" (Tesseract) with a long thin dark bar
    ending just left of it, `dark` (h, w) being the image's ink. Returns (m_per_px, (x0, y0, x1, y1) the
    bar's ends) or None when no labelled bar is read."""
    try:
        import pytesseract
    except ImportError:  # pragma: no cover - the project depends on it
        log.warning("pytesseract is not installed: no scale bar is read")
        return None
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    words: list[tuple[str, int, int, int, int]] = []
    for zoom in (1, 2):  # printed labels are small: read again at twice the size when none was found
        g = grey if zoom == 1 else cv2.resize(grey, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
        try:
            data = pytesseract.image_to_data(
                g,
                config="--psm 11 -c tessedit_char_whitelist=0123456789.,m",
                output_type=pytesseract.Output.DICT,
            )
        except pytesseract.TesseractNotFoundError:
            log.warning("tesseract is not installed: no scale bar is read")
            return None
        words = [
            (str(t).strip(), int(x) // zoom, int(y) // zoom, int(w) // zoom, int(h) // zoom)
            for t, x, y, w, h in zip(
                data["text"], data["left"], data["top"], data["width"], data["height"], strict=True
            )
            if str(t).strip()
        ]
        found = _scale_bar(words, dark)
        if found is not None:
            return found
    return None


def _scale_bar(
    words: list[tuple[str, int, int, int, int]], dark: NDArray[np.bool_]
) -> tuple[float, tuple] | None:
    """The scale bar labelled by one of the words read (text, x, y, w, h), as `read_scale_bar` returns it."""
    labels = []
    for k, (t, x, y, w, h) in enumerate(words):
        m = _NUMBER.match(t.lower().replace(" ", ""))
        if not m:
            continue
        unit_here = m.group(2) is not None
        nxt = words[k + 1] if k + 1 < len(words) else None
        unit_next = (
            nxt is not None and nxt[0].lower() == "m" and abs(nxt[2] - y) < h and nxt[1] - (x + w) < 3 * h
        )
        if (unit_here or unit_next) and float(m.group(1).replace(",", ".")) > 0:
            labels.append((float(m.group(1).replace(",", ".")), x, y, w, h))
    if not labels:
        return None
    # a bar's outline broken by glare or noise is closed along the bar
    bars = cv2.morphologyEx(dark.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 9), np.uint8))
    n, lab, stats, _c = cv2.connectedComponentsWithStats(bars, connectivity=8)
    best = None
    for value, x, y, lw, h in labels:
        for k in range(1, n):
            bx, by, bw, bh, _a = (int(v) for v in stats[k])
            if bw < 8 * max(bh, 1) or bw < 20:
                continue
            # the label stands at the bar's far end: beside it or under it
            end_u, end_v = bx + bw, by + bh / 2
            du = max(x - end_u, end_u - (x + lw), 0)
            dv = max(y - end_v, end_v - (y + h), 0)
            if du > 3 * h or dv > 3 * h:
                continue
            if best is None or du + dv < best[0]:
                # the ends are the middles of the end strokes: the outer extent less one stroke width
                # (the thinnest run of ink down from the bar's top edge)
                comp = (lab[by : by + bh, bx : bx + bw] == k) & dark[by : by + bh, bx : bx + bw]
                runs = []
                for col in comp.T:
                    if col.any():
                        first = int(np.argmax(col))
                        rest = np.append(col[first:], False)
                        runs.append(int(np.argmin(rest)))
                stroke = float(np.percentile(runs, 20)) if runs else 1.0
                length = bw - stroke
                best = (du + dv, value / length, (bx + stroke / 2, end_v, end_u - stroke / 2, end_v))
    if best is None:
        return None
    return best[1], best[2]
