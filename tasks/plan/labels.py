"""The label printed in each room of a plan raster ("101", "WC"), read by Tesseract (pytesseract; Debian's
tesseract-ocr, installed by .ci/setup). The plan stage stores it as the `label` of each room in
rooms.geojson; the fuse stage matches survey.yaml's `plan_room` against it (thesis 7.1.1: the room
correspondence).

Only dark ink in small connected components counts (letters; walls, green arrows and red symbols do
not; a letter's strokes over a green arrow are near black and count), inside the room's outline shrunk by 0.1 m; the crop around them is enlarged three
times and read as sparse text of letters and digits. The line read with the highest confidence is the
room's label; a room with no readable text has none (its correspondence falls back to the track or its
shape).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Polygon

log = logging.getLogger("indoor_survey")

WHITELIST = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"


def text_ink(image: NDArray[np.uint8], max_char_px: float) -> NDArray[np.bool_]:
    """(H, W) pixels of ink in connected components no taller or wider than max_char_px: dark and
    unsaturated, or near black whatever its hue (a letter printed over a green arrow blends into dark
    green: 'WC' over the exit arrow read as 'W')."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    value = image.max(axis=2)
    ink = (((value < 110) & (hsv[..., 1] < 80)) | (value < 60)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(ink, connectivity=8)
    keep = np.zeros(n, dtype=bool)
    keep[1:] = (stats[1:, 2] <= max_char_px) & (stats[1:, 3] <= max_char_px) & (stats[1:, 4] >= 3)
    return keep[lab]


def read_room_labels(
    image: NDArray[np.uint8], rooms: list[Polygon], m_per_px: float, inset_m: float = 0.1
) -> list[str | None]:
    """The label printed inside each room (plan-frame polygons, metres; pixel (u, v) is the plan point
    (u m_per_px, -v m_per_px)), None where nothing is readable or Tesseract is missing."""
    try:
        import pytesseract
    except ImportError:  # pragma: no cover - a dependency of the package
        log.warning("pytesseract is not installed: plan room labels are not read")
        return [None] * len(rooms)
    letters = text_ink(image, 0.5 / m_per_px)
    out: list[str | None] = []
    for poly in rooms:
        inner = poly.buffer(-inset_m)
        if inner.is_empty or inner.geom_type != "Polygon":
            out.append(None)
            continue
        xy = np.asarray(inner.exterior.coords)
        px = np.rint(np.column_stack([xy[:, 0], -xy[:, 1]]) / m_per_px).astype(np.int32)
        mask = np.zeros(letters.shape, np.uint8)
        cv2.fillPoly(mask, [px], 1)
        ys, xs = np.nonzero(letters & mask.astype(bool))
        if len(xs) == 0:
            out.append(None)
            continue
        y0, y1 = max(ys.min() - 8, 0), ys.max() + 9
        x0, x1 = max(xs.min() - 8, 0), xs.max() + 9
        crop = np.where(letters[y0:y1, x0:x1] & mask[y0:y1, x0:x1].astype(bool), 0, 255).astype(np.uint8)
        crop = cv2.resize(crop, None, fx=3, fy=3, interpolation=cv2.INTER_CUBIC)
        try:
            data = pytesseract.image_to_data(
                crop,
                config=f"--psm 11 -c tessedit_char_whitelist={WHITELIST}",
                output_type=pytesseract.Output.DICT,
            )
        except pytesseract.TesseractNotFoundError:
            log.warning(
                "tesseract is not installed (apt-get install tesseract-ocr): plan room labels are not read"
            )
            return [None] * len(rooms)
        out.append(_label(data))
    return out


def _label(data: dict) -> str | None:
    """The line of text read with the highest confidence, its tokens joined left to right (sparse-text
    mode may split 'WC' into 'W' and 'C')."""
    tokens = [
        (float(c), t.strip(), int(x), int(y), int(h))
        for t, c, x, y, h in zip(
            data["text"], data["conf"], data["left"], data["top"], data["height"], strict=True
        )
        if t.strip()
    ]
    if not tokens:
        return None
    best = max(tokens)
    line = [t for t in tokens if abs((t[3] + t[4] / 2) - (best[3] + best[4] / 2)) <= best[4] / 2]
    return "".join(t[1] for t in sorted(line, key=lambda t: t[2]))
