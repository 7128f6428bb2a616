"""The plan's scale from its dimension lines, for a drawing without a scale bar: a dimension line is a long
thin line crossed by extension lines (ticked where they cross), with each stretch's length printed beside
it. The crossings are found in the ink, each stretch's number is read by Tesseract in a crop beside it,
and a number divided by the distance between its two crossings is the scale. Lines across the image (a
horizontal dimension) and along it (the image turned a quarter) are both read."""

from __future__ import annotations

import itertools
import logging
import os
import re
import tempfile

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
    """Metres per pixel from the dimension lines of an (h, w) grey image, and how many stretches agree
    on it. Every stretch read (a number like "5.38" beside the stretch between two crossings) gives a few
    candidate scales, number over length, one per reading Tesseract made of its number under different
    enlargements (a photo's 9 px digits come out "5.38", "5.36" or "3.38"); the scale is the one on which
    the most stretches have a candidate within `tol` (ties: the most readings), the median of those
    stretches' nearest candidates, when at least `min_agree` stretches agree. None when fewer do (no
    dimension lines, or Tesseract missing). Horizontal and vertical stretches are pooled."""
    try:
        import pytesseract
    except ImportError:  # pragma: no cover - the project depends on it
        log.warning("pytesseract is not installed: no dimension line is read")
        return None
    stretches: list[dict[float, int]] = []
    try:
        for k in (0, 1):  # horizontal lines, then the vertical ones turned to horizontal
            g = grey if k == 0 else np.ascontiguousarray(np.rot90(grey, -1))
            stretches += _read_lines(g, pytesseract)
    except pytesseract.TesseractNotFoundError:
        log.warning("tesseract is not installed: no dimension line is read")
        return None
    return agreed_scale(stretches, min_agree, tol)


def agreed_scale(
    stretches: list[dict[float, int]], min_agree: int = 2, tol: float = 0.01
) -> tuple[float, int] | None:
    """The scale most stretches agree on (see `read_dimension_scale`): `stretches` holds per stretch its
    candidate scales and how many readings gave each. (scale, number of stretches agreeing) or None."""
    best: tuple[int, int, float] = (0, 0, 0.0)  # (stretches, readings, scale)
    for cand in stretches:
        for v in cand:
            n, votes, near = 0, 0, []
            for other in stretches:
                close = [(abs(c / v - 1.0), c, k) for c, k in other.items() if abs(c / v - 1.0) <= tol]
                if close:
                    n += 1
                    votes += sum(k for _e, _c, k in close)
                    near.append(min(close)[1])
            if (n, votes) > best[:2]:
                best = (n, votes, float(np.median(near)))
    if best[0] < min_agree:
        return None
    return best[2], best[0]


def line_work(grey: NDArray[np.uint8]) -> NDArray[np.bool_]:
    """Thin, faint line work (h, w): darker than the paper around it (a local threshold: a dimension
    line is a pale hairline that a global ink threshold loses in a photo)."""
    block = max(15, (min(grey.shape) // 60) | 1)
    return cv2.adaptiveThreshold(grey, 1, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, 10) > 0


def dimension_lines(ink: NDArray[np.bool_]) -> list[tuple[float, float, int, int]]:
    """Thin, nearly horizontal lines (a, b, u0, u1: row v = a + b u from u0 to u1) at least a tenth of the
    image's width long and at most 4 px thick: candidates for dimension lines (walls are thicker, text is
    shorter). A line tilted by a degree or two (a scan's skew) is found in pieces that are joined, and so
    is a line cut where a photo's blur made it as thick as a wall for a few pixels: collinear pieces
    (each at least 15 px) a short gap apart are one line."""
    w = ink.shape[1]
    d8 = ink.astype(np.uint8)
    L = max(30, w // 10)
    horiz = cv2.morphologyEx(d8, cv2.MORPH_OPEN, np.ones((1, max(15, L // 4)), np.uint8))
    thick = cv2.morphologyEx(d8, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    thin = horiz & (1 - cv2.dilate(thick, np.ones((3, 3), np.uint8)))
    # pieces of one tilted line overlap once thickened a little across
    joined = cv2.dilate(thin, np.ones((3, 25), np.uint8))
    n, lab, stats, _c = cv2.connectedComponentsWithStats(joined, connectivity=8)
    pieces = []  # (u0, u1, us, vs) of every thin, straight piece
    for k in range(1, n):
        x, y, bw, bh, _a = stats[k]
        if bw < 15 or bh > 4 + bw * 0.05:
            continue
        vs, us = np.nonzero((lab[y : y + bh, x : x + bw] == k) & (thin[y : y + bh, x : x + bw] > 0))
        if len(us) < 0.5 * bw:
            continue
        pieces.append((int(x), int(x + bw), us + x, vs + y))
    pieces.sort(key=lambda p: p[0])
    gap = max(12, L // 4)
    lines: list[list] = []  # [u0, u1, us, vs, a, b]
    for u0, u1, us, vs in pieces:
        for ln in lines:
            # a piece starting a short gap after a line's end, on that line's prolongation
            if 0 <= u0 - ln[1] <= gap and abs(ln[4] + ln[5] * (u0 + u1) / 2 - np.median(vs)) <= 2.0:
                ln[1], ln[2], ln[3] = u1, np.concatenate([ln[2], us]), np.concatenate([ln[3], vs])
                ln[5], ln[4] = np.polyfit(ln[2], ln[3], 1) if np.ptp(ln[2]) > 0 else (0.0, ln[4])
                break
        else:
            b, a = np.polyfit(us, vs, 1) if np.ptp(us) > 0 else (0.0, float(np.median(vs)))
            lines.append([u0, u1, us, vs, a, b])
    out = []
    for u0, u1, us, vs, a, b in lines:
        if u1 - u0 < L or len(us) < 0.5 * (u1 - u0):
            continue
        resid = np.abs(vs - (a + b * us))
        if np.percentile(resid, 90) <= 2.0:
            out.append((float(a), float(b), int(u0), int(u1)))
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


def _read_lines(grey: NDArray[np.uint8], tess) -> list[dict[float, int]]:
    """Every stretch read on the image's nearly horizontal dimension lines: its candidate metres per
    pixel (each reading of its number over the stretch's length) and how many readings gave each."""
    H = grey.shape[0]
    ink = line_work(grey)
    out: list[dict[float, int]] = []
    for a, b, u0, u1 in dimension_lines(ink):
        cs, reach = crossings(ink, a, b, u0 - 3, u1 + 3)
        if len(cs) < 2 or reach < 4:
            continue
        for ca, cb in itertools.pairwise(cs):
            if cb - ca < 2 * reach:
                continue  # too short a stretch to carry its number
            v = a + b * (ca + cb) / 2
            length = float(np.hypot(cb - ca, b * (cb - ca)))
            for side in (1, -1):  # the number under the line, else over it
                lo, hi = (0.3, 2.6) if side > 0 else (-2.6, -0.3)
                va, vb = max(0, round(v + lo * reach)), min(H, round(v + hi * reach))
                ua, ub = round(ca + 0.1 * (cb - ca)), round(cb - 0.1 * (cb - ca))
                if vb - va < 6 or ub - ua < 8:
                    continue
                values = _read_number(grey[va:vb, ua:ub], tess)
                cand = {value / length: k for value, k in values.items() if 0.3 <= value <= 200.0}
                if cand:
                    out.append(cand)
                    break
    return out


def _read_number(crop: NDArray[np.uint8], tess) -> dict[float, int]:
    """The readings of a length like "5.38" in a small grey crop, and how many of the tries gave each:
    its ink (half-way between paper and the darkest ink) boxed, contrast stretched, enlarged 3 to 6 times
    (at least to about 40 px high) and read as one line, in grey and binarized. Empty when nothing reads
    as a length."""
    lo, hi = int(crop.min()), int(crop.max())
    if hi - lo < 30:
        return {}
    ink = crop < (lo + hi) // 2
    vs, us = np.nonzero(ink)
    if len(vs) < 6:
        return {}
    v0, v1, u0, u1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
    box = crop[max(0, v0 - 2) : v1 + 2, max(0, u0 - 2) : u1 + 2]
    # contrast stretched and enlarged, in grey and binarized (binarizing a small "5" can make a "9" of it)
    stretched = ((box.astype(np.float32) - lo) * (255.0 / (hi - lo))).clip(0, 255).astype(np.uint8)
    z0 = max(3, round(40 / max(v1 - v0, 1)))
    tries = []
    for binarize, zoom in itertools.product((False, True), (z0, z0 + 1, z0 + 2, z0 + 3)):
        big = cv2.resize(stretched, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
        if binarize:
            big = np.where(big < 128, 0, 255).astype(np.uint8)
        tries.append(cv2.copyMakeBorder(big, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255))
    found: dict[float, int] = {}
    for text in read_lines_batch(tries, tess, "--psm 7 -c tessedit_char_whitelist=0123456789.,"):
        m = _LENGTH.match(text.strip().replace(" ", ""))
        if m is not None:
            value = float(f"{m.group(1)}.{m.group(2)}")
            found[value] = found.get(value, 0) + 1
    return found


def read_lines_batch(images: list[NDArray[np.uint8]], tess, config: str) -> list[str]:
    """Tesseract's text of each (h, w) grey image, read in one run: the images are the pages of a list
    file, each recognized on its own as if read alone (the same engine settings; the text is the same),
    but the engine and its model are loaded once, not once per image (about 0.2 CPU s each time, most of
    what reading a small crop costs)."""
    from PIL import Image

    if not images:
        return []
    with tempfile.TemporaryDirectory(prefix="plan_ocr_") as tmp:
        paths = []
        for k, img in enumerate(images):
            paths.append(os.path.join(tmp, f"{k}.png"))
            Image.fromarray(img).save(paths[-1], format="PNG")
        listing = os.path.join(tmp, "pages.txt")
        with open(listing, "w") as fh:
            fh.write("\n".join(paths) + "\n")
        pages = tess.image_to_string(listing, config=config).split("\f")
    if len(pages) < len(images):
        raise RuntimeError(f"tesseract read {len(pages)} pages of {len(images)}")
    return pages[: len(images)]
