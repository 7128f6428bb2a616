"""The plan's scale from its dimension lines, for a drawing without a scale bar: a dimension line is a long
thin line crossed by extension lines (ticked where they cross), with each stretch's length printed beside
it. The crossings are found in the ink, each stretch's number is read by Tesseract in a crop beside it,
and a number divided by the distance between its two crossings is the scale. Lines across the image (a
horizontal dimension) and along it (the image turned a quarter) are both read."""

from __future__ import annotations

import itertools
import logging
import re

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.lines import true_runs

log = logging.getLogger(__name__)

_LENGTH = re.compile(r"^(\d{1,3})[.,]?(\d{2})$")
"""A length in metres to the centimetre, as dimension lines print it ("5.38"); a point too small to
survive the photo ("538") is read as the same number."""


def read_dimension_scale(
    grey: NDArray[np.uint8], min_agree: int = 2, tol: float = 0.01
) -> tuple[float, int] | None:
    """Metres per pixel from the dimension lines of an (h, w) grey image: the median
    over the stretches read (a number like "5.38" beside the stretch between two crossings) of number
    over length, when at least `min_agree` stretches agree with it within `tol`; with the count that
    agree. None when fewer are read (no dimension lines, or Tesseract missing)."""
    try:
        import pytesseract
    except ImportError:  # pragma: no cover - the project depends on it
        log.warning("pytesseract is not installed: no dimension line is read")
        return None
    scales: list[float] = []
    try:
        for k in (0, 1):  # horizontal lines, then the vertical ones turned to horizontal
            g = grey if k == 0 else np.ascontiguousarray(np.rot90(grey, -1))
            scales += _read_lines(g, pytesseract)
    except pytesseract.TesseractNotFoundError:
        log.warning("tesseract is not installed: no dimension line is read")
        return None
    if not scales:
        return None
    s = np.asarray(scales)
    best, best_n = 0.0, 0
    for v in s:  # the value most others agree with
        n = int((np.abs(s / v - 1.0) <= tol).sum())
        if n > best_n:
            best, best_n = float(np.median(s[np.abs(s / v - 1.0) <= tol])), n
    if best_n < min_agree:
        return None
    return best, best_n


def line_work(grey: NDArray[np.uint8]) -> NDArray[np.bool_]:
    """Thin, faint line work (h, w): darker than the paper around it (a local threshold: a dimension
    line is a pale hairline that a global ink threshold loses in a photo)."""
    block = max(15, (min(grey.shape) // 60) | 1)
    return cv2.adaptiveThreshold(grey, 1, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, 10) > 0


def dimension_lines(ink: NDArray[np.bool_]) -> list[tuple[float, float, int, int]]:
    """Thin, nearly horizontal lines (a, b, u0, u1: row v = a + b u from u0 to u1) at least a tenth of the
    image's width long and at most 4 px thick: candidates for dimension lines (walls are thicker, text is
    shorter). A line tilted by a degree or two (a scan's skew) is found in pieces that are joined."""
    w = ink.shape[1]
    d8 = ink.astype(np.uint8)
    L = max(30, w // 10)
    horiz = cv2.morphologyEx(d8, cv2.MORPH_OPEN, np.ones((1, max(15, L // 4)), np.uint8))
    thick = cv2.morphologyEx(d8, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    thin = horiz & (1 - cv2.dilate(thick, np.ones((3, 3), np.uint8)))
    # pieces of one tilted line overlap once thickened a little across
    joined = cv2.dilate(thin, np.ones((3, 25), np.uint8))
    n, lab, stats, _c = cv2.connectedComponentsWithStats(joined, connectivity=8)
    out = []
    for k in range(1, n):
        x, y, bw, bh, _a = stats[k]
        if bw < L or bh > 4 + bw * 0.05:
            continue
        vs, us = np.nonzero((lab[y : y + bh, x : x + bw] == k) & (thin[y : y + bh, x : x + bw] > 0))
        if len(us) < 0.5 * bw:
            continue
        b, a = np.polyfit(us + x, vs + y, 1)
        resid = np.abs(vs + y - (a + b * (us + x)))
        if np.percentile(resid, 90) <= 2.0:
            out.append((float(a), float(b), int(x), int(x + bw)))
    return out


def crossings(ink: NDArray[np.bool_], a: float, b: float, u0: int, u1: int) -> tuple[list[float], float]:
    """Where ink crosses the line v = a + b u between u0 and u1 (extension lines and their ticks): columns
    with ink both a little above and a little below the line, grouped, their centres (sub-pixel); and
    the median reach of that ink below the line (px; an extension line's overshoot, the unit for where
    the numbers stand)."""
    h, w = ink.shape
    us = np.arange(max(0, u0), min(w, u1))
    if len(us) == 0:
        return [], 0.0
    rows = np.round(a + b * us).astype(int)
    offs = np.arange(3, 8)
    va = np.clip(rows[None, :] - offs[:, None], 0, h - 1)
    vb = np.clip(rows[None, :] + offs[:, None], 0, h - 1)
    above = ink[va, us[None, :]].mean(axis=0)
    below = ink[vb, us[None, :]].mean(axis=0)
    hit = (above >= 0.2) & (below >= 0.2)
    out, reach = [], []
    for k, e in true_runs(hit):
        wts = (above[k:e] + below[k:e]).astype(np.float64)
        c = float((us[k:e] * wts).sum() / wts.sum())
        out.append(c)
        col = ink[round(a + b * c) :, round(c)]
        reach.append(float(np.argmin(np.append(col, False))))
    return out, float(np.median(reach)) if reach else 0.0


def _read_lines(grey: NDArray[np.uint8], tess) -> list[float]:
    """Metres per pixel from every stretch read on the image's nearly horizontal dimension lines."""
    H = grey.shape[0]
    ink = line_work(grey)
    out: list[float] = []
    for a, b, u0, u1 in dimension_lines(ink):
        cs, reach = crossings(ink, a, b, u0 - 3, u1 + 3)
        if len(cs) < 2 or reach < 4:
            continue
        for ca, cb in itertools.pairwise(cs):
            if cb - ca < 2 * reach:
                continue  # too short a stretch to carry its number
            v = a + b * (ca + cb) / 2
            for side in (1, -1):  # the number under the line, else over it
                lo, hi = (0.3, 2.6) if side > 0 else (-2.6, -0.3)
                va, vb = max(0, round(v + lo * reach)), min(H, round(v + hi * reach))
                ua, ub = round(ca + 0.1 * (cb - ca)), round(cb - 0.1 * (cb - ca))
                if vb - va < 6 or ub - ua < 8:
                    continue
                value = _read_number(grey[va:vb, ua:ub], tess)
                if value is not None and 0.3 <= value <= 200.0:
                    out.append(value / float(np.hypot(cb - ca, b * (cb - ca))))
                    break
    return out


def _read_number(crop: NDArray[np.uint8], tess) -> float | None:
    """A length like "5.38" read in a small grey crop: its ink (half-way between paper and the darkest
    ink) boxed, contrast stretched, enlarged to about 40 px high and read as one line (in grey, then
    binarized)."""
    lo, hi = int(crop.min()), int(crop.max())
    if hi - lo < 30:
        return None
    ink = crop < (lo + hi) // 2
    vs, us = np.nonzero(ink)
    if len(vs) < 6:
        return None
    v0, v1, u0, u1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
    box = crop[max(0, v0 - 2) : v1 + 2, max(0, u0 - 2) : u1 + 2]
    # contrast stretched and enlarged, in grey first (binarizing a small "5" can make a "9" of it)
    stretched = ((box.astype(np.float32) - lo) * (255.0 / (hi - lo))).clip(0, 255).astype(np.uint8)
    for binarize, zoom in itertools.product((False, True), sorted({max(3, round(40 / max(v1 - v0, 1))), 4})):
        big = cv2.resize(stretched, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
        if binarize:
            big = np.where(big < 128, 0, 255).astype(np.uint8)
        big = cv2.copyMakeBorder(big, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255)
        text = tess.image_to_string(big, config="--psm 7 -c tessedit_char_whitelist=0123456789.,").strip()
        m = _LENGTH.match(text.replace(" ", ""))
        if m is not None:
            return float(f"{m.group(1)}.{m.group(2)}")
    return None
