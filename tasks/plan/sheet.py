"""The sheet a plan is printed on: its border in a photo (for perspective rectification) and the printed
scale bar (for the scale when none is given)."""

from __future__ import annotations

import logging
import math
import re

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.plan.dimensions import read_lines_batch

log = logging.getLogger(__name__)


def find_sheet(
    image: NDArray[np.uint8], min_area_share: float, min_contrast: float = 25.0
) -> NDArray[np.float64] | None:
    """The four corners (4, 2) of the paper sheet in a photo (clockwise from top-left), when its edges
    show: the outermost long straight edges, two roughly horizontal and two roughly vertical, enclosing
    at least min_area_share of the image, with the outside darker by min_contrast grey levels on average.
    None otherwise (a scan, a drawing on a white page, a photo cropped inside the sheet)."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), (0, 0), 2)
    edges = cv2.Canny(grey, 8, 24)
    quad = _sheet_quad(grey, edges, min_area_share, min_contrast)
    if quad is None:
        # the sheet's edge beside the drawing's frame a few pixels in gives parallel edges that the
        # probabilistic Hough can walk across in pieces too short to count: once more, each band of
        # parallel edges merged into one
        quad = _sheet_quad(grey, cv2.dilate(edges, np.ones((5, 5), np.uint8)), min_area_share, min_contrast)
    return quad


def _sheet_quad(
    grey: NDArray[np.uint8], edges: NDArray[np.uint8], min_area_share: float, min_contrast: float
) -> NDArray[np.float64] | None:
    """`find_sheet` on the (h, w) edge image of the blurred grey photo."""
    h, w = grey.shape
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


def direction_homography(
    image: NDArray[np.uint8], min_shift_px: float = 1.5, max_tilt_deg: float = 35.0
) -> tuple[NDArray[np.float64], tuple[int, int]] | None:
    """Perspective rectification of a photo from the plan's two dominant orthogonal directions (thesis
    4.2.3), for a photo whose sheet border does not show: the long straight edges of the ink (walls,
    frames, furniture) fall into two families, each family's vanishing point is the least-squares meet of
    its lines, and a pinhole camera (principal point in the middle, square pixels) whose two vanishing
    directions are orthogonal gives the focal length and the camera's rotation; the image is turned back
    to face the plane, at the photo's mean scale. When the two vanishing points leave the focal length
    unknown (one or both at infinity, weak perspective) the image's diagonal stands for it. Returns the
    (3, 3) homography from image to rectified pixels and the rectified (width, height), or None when the
    rectification moves no corner of the image more than min_shift_px from a similarity (a scan, a
    plan rendered square on) or when fewer than two families of lines are found."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), (0, 0), 1.5)
    h, w = grey.shape
    diag = math.hypot(w, h)
    min_len = max(20.0, 0.04 * min(h, w))
    found = cv2.createLineSegmentDetector().detect(grey)[0]  # sub-pixel line segments
    if found is None:
        return None
    segs = found.reshape(-1, 4).astype(np.float64)
    d = segs[:, 2:] - segs[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    segs, d, length = segs[length >= min_len], d[length >= min_len], length[length >= min_len]
    if len(segs) < 8:
        return None
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0
    # the dominant direction (length-weighted, 1 degree bins, smoothed) and the one about 90 degrees off
    hist = np.bincount(np.round(ang).astype(int) % 180, weights=length, minlength=180)
    smooth = np.convolve(np.concatenate([hist[-2:], hist, hist[:2]]), np.ones(5), "valid")
    a1 = float(np.argmax(smooth))
    near = (np.arange(180) - a1 - 90.0 + 90.0) % 180.0 - 90.0  # signed distance from a1 + 90
    a2 = float(np.argmax(np.where(np.abs(near) <= max_tilt_deg, smooth, -1.0)))
    c = np.array([w / 2, h / 2])
    vps = _family_points(
        segs, length, c, diag, [np.abs((ang - a + 90.0) % 180.0 - 90.0) <= 12.0 for a in (a1, a2)]
    )
    if vps is None:
        return None
    v1, v2 = vps  # homogeneous, in coordinates centred on the image's middle and divided by its diagonal
    # which is the horizontal family: the one whose direction is nearer the image's u axis
    if abs(math.cos(math.radians(a1))) < abs(math.cos(math.radians(a2))):
        v1, v2 = v2, v1
    f2 = -(v1[0] * v2[0] + v1[1] * v2[1]) / (v1[2] * v2[2]) if abs(v1[2] * v2[2]) > 1e-12 else -1.0
    f = math.sqrt(f2) if 0.25 <= f2 <= 16.0 else 1.0  # in diagonals
    K_inv = np.diag([1.0, 1.0, f])  # K^-1 up to scale in the normalised coordinates
    d1, d2 = K_inv @ v1, K_inv @ v2
    d1 *= np.sign(d1[0]) or 1.0  # the first axis points right, the second down
    d2 *= np.sign(d2[1]) or 1.0
    # the nearest rotation whose first two columns are d1, d2 (polar factor of the 3 x 2 pair)
    U, _S, Vt = np.linalg.svd(
        np.column_stack([d1 / np.linalg.norm(d1), d2 / np.linalg.norm(d2)]), full_matrices=False
    )
    r12 = U @ Vt
    R = np.column_stack([r12, np.cross(r12[:, 0], r12[:, 1])])
    N = np.array([[1 / diag, 0, -c[0] / diag], [0, 1 / diag, -c[1] / diag], [0, 0, 1.0]])
    H = R.T @ K_inv @ N
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], np.float64)
    q = corners @ H.T
    if (q[:, 2] <= 0).any():
        return None
    q = q[:, :2] / q[:, 2:]
    # at the photo's mean scale, upright, from the origin
    k = math.sqrt(w * h / max(abs(cv2.contourArea(q.astype(np.float32))), 1e-12))
    q *= k
    lo = q.min(axis=0)
    S = np.array([[k, 0, -lo[0]], [0, k, -lo[1]], [0, 0, 1.0]])
    H = S @ H
    H /= H[2, 2]
    q -= lo
    # how far it is from a similarity: corners against their best similarity fit
    A = np.zeros((8, 4))
    A[0::2] = np.column_stack([corners[:, 0], -corners[:, 1], np.ones(4), np.zeros(4)])
    A[1::2] = np.column_stack([corners[:, 1], corners[:, 0], np.zeros(4), np.ones(4)])
    sol, *_ = np.linalg.lstsq(A, q.reshape(-1), rcond=None)
    if float(np.abs(A @ sol - q.reshape(-1)).max()) <= min_shift_px:
        return None
    size = (math.ceil(q[:, 0].max()), math.ceil(q[:, 1].max()))
    if max(size) > 2 * max(w, h):
        return None
    return H, size


def residual_perspective(
    image: NDArray[np.uint8], min_shift_px: float = 0.5, max_shift_share: float = 0.03
) -> NDArray[np.float64] | None:
    """The perspective a rectification left in an (h, w, 3) image that should face the plan square on (a
    photographed sheet rectified from its border: a corner found a pixel or two off tilts the plane, and
    the scale then drifts across the plan by a few tenths of a percent). The plan's two families of long
    straight edges (near the image's axes) must meet at infinity: the line through their two vanishing
    points is sent to infinity by a (3, 3) homography that keeps the image's middle and the scale and
    directions there (an affine rectification, thesis 4.2.3: the sheet's side ratio stays). Returns the
    homography, or None when it moves no image corner more than min_shift_px (nothing left to take out),
    or more than max_shift_share of the image's diagonal (not trusted), or fewer than two families show."""
    grey = cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), (0, 0), 1.0)
    h, w = grey.shape
    diag = math.hypot(w, h)
    found = cv2.createLineSegmentDetector().detect(grey)[0]
    if found is None:
        return None
    segs = found.reshape(-1, 4).astype(np.float64)
    d = segs[:, 2:] - segs[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180.0
    c = np.array([w / 2, h / 2])
    long = length >= max(20.0, 0.04 * min(h, w))
    vps = _family_points(
        segs, length, c, diag, [long & (np.abs((ang - a + 90.0) % 180.0 - 90.0) <= 5.0) for a in (0.0, 90.0)]
    )
    if vps is None:
        return None
    line = np.cross(vps[0], vps[1])
    if abs(line[2]) < 1e-12:
        return None
    line = line / line[2]
    N = np.array([[1 / diag, 0, -c[0] / diag], [0, 1 / diag, -c[1] / diag], [0, 0, 1.0]])
    Hn = np.array([[1.0, 0, 0], [0, 1.0, 0], [line[0], line[1], 1.0]])
    H = np.linalg.inv(N) @ Hn @ N
    H /= H[2, 2]
    corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], np.float64)
    q = corners @ H.T
    if (q[:, 2] <= 0).any():
        return None
    shift = float(np.abs(q[:, :2] / q[:, 2:] - corners[:, :2]).max())
    if shift <= min_shift_px or shift > max_shift_share * diag:
        return None
    return H


def _family_points(
    segs: NDArray[np.float64], length: NDArray[np.float64], c: NDArray, diag: float, families: list[NDArray]
) -> list[NDArray[np.float64]] | None:
    """The vanishing point (`_vanishing_point`) of each family of segments (a mask over `segs`), or None
    when a family has fewer than 4 segments or no point."""
    vps = []
    for sel in families:
        v = _vanishing_point(segs[sel], length[sel], c, diag) if sel.sum() >= 4 else None
        if v is None:
            return None
        vps.append(v)
    return vps


def _vanishing_point(
    segs: NDArray[np.float64], length: NDArray[np.float64], c: NDArray, diag: float
) -> NDArray[np.float64] | None:
    """The vanishing point (3,) of a family of segments (K, 4) pixels, homogeneous in coordinates centred
    on c and divided by diag: the unit vector nearest to lying on every segment's line (length-weighted
    least squares), again with the lines that miss it by more than 3, 1.5, 0.75 and 0.5 degrees left out."""
    p = np.column_stack([(segs[:, :2] - c) / diag, np.ones(len(segs))])
    q = np.column_stack([(segs[:, 2:] - c) / diag, np.ones(len(segs))])
    lines_h = np.cross(p, q)
    lines_h /= np.maximum(np.linalg.norm(lines_h[:, :2], axis=1), 1e-12)[:, None]
    keep = np.ones(len(segs), bool)
    v = None
    for tol_deg in (3.0, 1.5, 0.75, 0.5, 0.5):
        if keep.sum() < 3:
            return v
        L = lines_h[keep] * np.sqrt(length[keep])[:, None]
        _u, _s, vt = np.linalg.svd(L, full_matrices=False)
        v = vt[-1]
        # angle between each segment and the direction from its middle to the vanishing point
        mid = (p + q) / 2
        seg_d = q[:, :2] - p[:, :2]
        to_v = v[:2][None, :] - mid[:, :2] * v[2]
        cos = np.abs((seg_d * to_v).sum(axis=1)) / np.maximum(
            np.linalg.norm(seg_d, axis=1) * np.linalg.norm(to_v, axis=1), 1e-12
        )
        keep = cos >= math.cos(math.radians(tol_deg))
    return v


_NUMBER = re.compile(r"^(\d+(?:[.,]\d+)?)(m)?$")


def read_scale_bar(image: NDArray[np.uint8], dark: NDArray[np.bool_]) -> tuple[float, tuple] | None:
    """Metres per pixel from a printed scale bar: a label "<n> m" (Tesseract) with a long thin dark bar
    ending just left of it, `dark` (h, w) being the image's ink. The bars are found first and the label
    is read in a small crop beside and under each bar's far end, enlarged four times, binarized and read
    as one line of digits and "m" (a phone photo's small "5 m" is a few pixels high); failing that, the
    whole image is read for labels. Returns (m_per_px, (x0, y0, x1, y1) the bar's ends) or None when no
    labelled bar is read."""
    try:
        import pytesseract
    except ImportError:  # pragma: no cover - the project depends on it
        log.warning("pytesseract is not installed: no scale bar is read")
        return None
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    try:
        found = _bar_first(grey, dark, pytesseract)
    except pytesseract.TesseractNotFoundError:
        log.warning("tesseract is not installed: no scale bar is read")
        return None
    if found is not None:
        return found
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
        found = _scale_bar(words, dark, grey)
        if found is not None:
            return found
    return None


def _bar_candidates(dark: NDArray[np.bool_]) -> list[tuple[int, int, int, int]]:
    """Boxes (x, y, w, h) shaped like a scale bar (long and thin), longest first (at most 20): components
    of the ink closed along bars (an outline broken by glare or noise), and chains of blocks in a row
    (a bar whose empty blocks' thin outline faded leaves its filled blocks apart: equal height, in
    line, at most one and a half blocks apart)."""
    bars = cv2.morphologyEx(dark.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 9), np.uint8))
    n, _lab, stats, _c = cv2.connectedComponentsWithStats(bars, connectivity=8)
    boxes = [tuple(int(v) for v in stats[k, :4]) for k in range(1, n)]
    blocks = sorted((b for b in boxes if b[2] >= 2 * b[3] and b[3] >= 3), key=lambda b: (b[0], b[1]))
    used: set[int] = set()
    for i, b0 in enumerate(blocks):
        if i in used:
            continue
        chain = [b0]
        for j in range(i + 1, len(blocks)):
            last, b1 = chain[-1], blocks[j]
            gap = b1[0] - (last[0] + last[2])
            if (
                abs(b1[1] - last[1]) <= 2
                and abs(b1[3] - last[3]) <= 2
                and -2 * max(last[3], b1[3]) <= gap <= 1.5 * max(last[2], b1[2])
            ):
                chain.append(b1)
                used.add(j)
        if len(chain) >= 2:
            x0, y0 = chain[0][0], min(c[1] for c in chain)
            x1, y1 = chain[-1][0] + chain[-1][2], max(c[1] + c[3] for c in chain)
            boxes.append((x0, y0, x1 - x0, y1 - y0))
    ok = [b for b in boxes if b[2] >= 8 * max(b[3], 1) and b[2] >= 20]
    return sorted(set(ok), key=lambda b: -b[2])[:20]


_CONFUSED = str.maketrans(
    {
        "S": "5",
        "s": "5",
        "O": "0",
        "o": "0",
        "D": "0",
        "l": "1",
        "I": "1",
        "i": "1",
        "|": "1",
        "B": "8",
        "Z": "2",
        "z": "2",
        "g": "9",
        "q": "9",
        "M": "m",
    }
)
"""Letters Tesseract reads for a label's digits (a blurred 5 is an S), and M for the unit."""


def _bar_first(grey: NDArray[np.uint8], dark: NDArray[np.bool_], tess) -> tuple[float, tuple] | None:
    """`read_scale_bar`'s first way: the label read in a crop at each bar's far end, the crop's contrast
    stretched, enlarged, binarized half-way between its paper and its ink and read as one line; a value
    is taken only when it divides into the bar's blocks at a round step (1, 2, 2.5 or 5 times a power of
    ten): a misread digit rarely does."""
    H, W = grey.shape
    for box in _bar_candidates(dark):
        bx, by, bw, bh = box
        end_u, cy = bx + bw, by + bh / 2
        blocks = _bar_blocks(box, dark)
        # beside the end, and under it (a label centred on the end)
        for u0, u1, v0, v1 in (
            (end_u + 1, end_u + 0.3 * bw, cy - 0.08 * bw, cy + 0.08 * bw),
            (end_u - 0.12 * bw, end_u + 0.25 * bw, by + bh + 1, by + bh + 0.15 * bw),
        ):
            u0, u1 = max(0, round(u0)), min(W, round(u1))
            v0, v1 = max(0, round(v0)), min(H, round(v1))
            if u1 - u0 < 8 or v1 - v0 < 6:
                continue
            g = grey[v0:v1, u0:u1]
            lo, hi = int(g.min()), int(g.max())
            if hi - lo < 30:  # paper only
                continue
            guessed: list[float] = []  # values read from letters only, at one enlargement so far
            tries = []
            for zoom in (3, 4, 2):
                big = cv2.resize(g, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_CUBIC)
                big = np.where(big < (lo + hi) // 2, 0, 255).astype(np.uint8)
                tries.append(cv2.copyMakeBorder(big, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255))
            for raw in read_lines_batch(tries, tess, "--psm 7"):  # the three enlargements in one run
                raw = raw.strip()
                m = _NUMBER.match(raw.translate(_CONFUSED).lower().replace(" ", ""))
                if m is None or m.group(2) is None:
                    continue
                value = float(m.group(1).replace(",", "."))
                if not (value > 0 and _round_step(value / blocks)):
                    continue
                # a number read without a single digit ("im" for a "5 m" the photo's edge cut) is a
                # guess: taken only when another enlargement reads the same
                if any(ch.isdigit() for ch in raw) or value in guessed:
                    return _bar_scale(box, dark, value, grey)
                guessed.append(value)
    return None


def _round_step(step: float) -> bool:
    """Whether a scale bar's block is a round length: 1, 2, 2.5 or 5 times a power of ten."""
    mant = step / 10.0 ** math.floor(math.log10(step))
    return min(abs(mant - v) for v in (1.0, 2.0, 2.5, 5.0, 10.0)) < 0.02


def _bar_blocks(box: tuple[int, int, int, int], dark: NDArray[np.bool_]) -> int:
    """How many blocks the bar in box (x, y, w, h) is divided into: the runs of ink and of paper (at least two pixels
    long) along its middle row inside its end strokes; 1 for a plain bar."""
    bx, by, bw, bh = box
    row = dark[by + bh // 2, bx : bx + bw]
    runs: list[int] = []
    start = 0
    for x in range(1, len(row) + 1):
        if x == len(row) or row[x] != row[start]:
            if x - start >= 2:
                runs.append(x - start)
            start = x
    if len(runs) >= 3 and row[0] and row[-1]:
        # an outlined bar's end strokes are short ink runs, not blocks
        inner = float(np.median(runs[1:-1]))
        runs = runs[int(runs[0] < inner / 3) : len(runs) - int(runs[-1] < inner / 3)]
    return max(1, len(runs))


def _bar_scale(
    box: tuple[int, int, int, int],
    dark: NDArray[np.bool_],
    value: float,
    grey: NDArray[np.uint8] | None = None,
) -> tuple[float, tuple]:
    """Metres per pixel of the bar in box (x, y, w, h) printed `value` metres long, and its two ends: the middles of
    the end strokes (the outer extent less one stroke width, the thinnest run of ink down from the bar's
    top edge)."""
    bx, by, bw, bh = box
    end_u, end_v = bx + bw, by + bh / 2
    comp = dark[by : by + bh, bx : bx + bw]
    runs = []
    for col in comp.T:
        if col.any():
            first = int(np.argmax(col))
            rest = np.append(col[first:], False)
            runs.append(int(np.argmin(rest)))
    stroke = float(np.percentile(runs, 20)) if runs else 1.0
    if stroke >= bh / 2:  # no outline (filled blocks only, their faint outline lost): the ends are the extent
        stroke = 1.0
    x0, x1 = float(bx), float(end_u)
    if grey is not None:  # the outer extent to a tenth of a pixel: where the ink is half-way to paper
        x0, x1 = _half_way_ends(grey, box)
        stroke = min(stroke, 1.0)
    length = x1 - x0 - stroke
    return value / length, (x0 + stroke / 2, end_v, x1 - stroke / 2, end_v)


def _half_way_ends(grey: NDArray[np.uint8], box: tuple[int, int, int, int]) -> tuple[float, float]:
    """The bar's outer ends (u, sub-pixel) along its middle rows: where the darkness crosses half-way from
    the paper beyond each end to the ink just inside it."""
    bx, by, bw, bh = box
    W = grey.shape[1]
    pad = 6
    u0, u1 = max(0, bx - pad), min(W, bx + bw + pad)
    rows = grey[by + bh // 4 : max(by + bh // 4 + 1, by + bh - bh // 4), u0:u1].astype(np.float64)
    prof = 255.0 - rows.mean(axis=0)
    out = []
    for seq, start, sign in ((prof, u0, 1), (prof[::-1], u1 - 1, -1)):
        lead = bx - u0 if sign > 0 else u1 - (bx + bw)
        paper = float(seq[: max(1, lead - 2)].mean()) if lead > 2 else float(seq[0])
        ink = float(seq[lead : lead + 4].max()) if lead + 4 <= len(seq) else float(seq.max())
        half = (paper + ink) / 2
        i = int(np.argmax(seq >= half))
        frac = 0.0 if i == 0 else (half - seq[i - 1]) / max(seq[i] - seq[i - 1], 1e-9)
        pos = i - 1 + frac + 0.5  # pixel centres -> edges: pixel i covers [i, i + 1)
        out.append(start + sign * pos if sign > 0 else start + 1 - pos)
    return out[0], out[1]


def _scale_bar(
    words: list[tuple[str, int, int, int, int]],
    dark: NDArray[np.bool_],
    grey: NDArray[np.uint8] | None = None,
) -> tuple[float, tuple] | None:
    """The scale bar labelled by one of the words read (text, x, y, w, h), as `read_scale_bar` returns it
    (its ends to a tenth of a pixel in `grey` when given, as in the first way)."""
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
    best = None
    for value, x, y, lw, h in labels:
        for box in _bar_candidates(dark):
            bx, by, bw, bh = box
            # the label stands at the bar's far end: beside it or under it
            end_u, end_v = bx + bw, by + bh / 2
            du = max(x - end_u, end_u - (x + lw), 0)
            dv = max(y - end_v, end_v - (y + h), 0)
            if du > 3 * h or dv > 3 * h:
                continue
            if best is None or du + dv < best[0]:
                best = (du + dv, *_bar_scale(box, dark, value, grey))
    if best is None:
        return None
    return best[1], best[2]
