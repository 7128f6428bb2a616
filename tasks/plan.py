"""Coarse floor-plan raster -> metric wall centrelines, thicknesses, rooms and doors (thesis 4.2.3).

The thesis (after Peter et al. 2010, 2013b) turns a photographed evacuation plan into a floor model:
white balance and Wallis filtering, perspective rectification from the building outline, removal of
symbols by colour segmentation, binarization, skeleton vectorization, bridging of the lines occluded by
symbols by prolonging free ends, and room polygons. The same steps serve CAD renderings (thin outline
walls are filled first). Straight walls come from the line code shared with the walls stage
(`tasks.lines`: clustering, regularization, extension/trimming), never from a copy of it.

Frames: the plan frame maps pixel (u, v) of the input image (after rectification, when four corners are
given) to metres (u * s, -v * s): x to the right, y up.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import shapely
from numpy.typing import NDArray
from scipy import ndimage
from shapely.geometry import Polygon
from skimage.morphology import skeletonize

from tasks import lines


@dataclass(frozen=True)
class PlanConfig:
    """Parameters of plan parsing. Lengths in metres are converted to pixels with the plan scale."""

    max_side_px: int = 5000
    """Images with a longer side are reduced by an integer factor with min-pooling (keeps 1 px lines)."""
    white_balance_percentile: float = 95.0
    """White-patch balance: this percentile of every channel is mapped to white (paper colour)."""
    clahe_clip: float = 2.0
    """CLAHE clip limit on the lightness channel (local contrast, the role of the Wallis filter)."""
    clahe_tile_m: float = 4.0
    """CLAHE tile size in metres of plan."""
    ink_threshold_bounds: tuple[int, int] = (60, 200)
    """Otsu threshold on darkness (255 - min(R, G, B)) is clamped to this range."""
    symbol_min_saturation: int = 90
    """HSV saturation (0-255) above which a pixel can be a coloured symbol."""
    symbol_min_value: int = 70
    """HSV value (0-255) above which a pixel can be a coloured symbol (darker is black ink)."""
    green_hue_deg: tuple[float, float] = (70.0, 170.0)
    """Hue range (degrees, 0-360) of green symbols (escape routes, exits)."""
    red_hue_deg: tuple[float, float] = (330.0, 25.0)
    """Hue range (degrees, wrapping) of red symbols (fire equipment)."""
    blue_hue_deg: tuple[float, float] = (200.0, 260.0)
    """Hue range (degrees) of blue symbols (mandatory / information signs). Cyan (180°) is not a symbol."""
    symbol_min_width_m: float = 0.06
    """Coloured ink is a symbol only where it is at least this wide (filled signs, arrows, swatches):
    thinner coloured strokes are the line work of a drawing whose layers are coloured (CAD) and stay ink."""
    layer_min_saturation: int = 40
    """HSV saturation (0-255) from which ink belongs to a coloured drawing layer (pale rims included)."""
    layer_min_share: float = 0.01
    """Share of the ink a colour layer must hold to be considered as a wall layer."""
    wall_layer_share: float = 0.8
    """Colour layers with at least this share of the best layer's wall evidence are wall layers."""
    wall_face_min_m: float = 0.5
    """Straight lines at least this long can be wall faces when colour layers are scored."""
    wall_layer_grid_m: float = 0.03
    """Cell size (metres) of the coarse grid on which colour layers are scored."""
    symbol_solid_share: float = 0.8
    """A connected piece of a symbol colour with at least this share of solid core is a symbol whole."""
    symbol_grow_m: float = 0.06
    """Symbol masks are grown by this to swallow their anti-aliased rims."""
    pen_colour_share: float = 0.5
    """A symbol colour covering more than this share of all dark pixels is the drawing's line colour
    (one-colour CAD renderings) and is kept."""
    symbol_hole_m: float = 0.12
    """White details narrower than this inside a symbol (pictograms) are part of the symbol."""
    max_outline_width_m: float = 0.5
    """Ink lines closer than this are the two faces of an outline-drawn wall and the space between them is
    filled (a closing); also the largest wall thickness measured."""
    min_wall_thickness_m: float = 0.08
    """Ink thinner than this (text strokes, hatching, furniture, dimension lines) is removed by opening."""
    text_max_size_m: float = 0.35
    """Connected components whose bounding box is smaller than this (letters, dots) are text."""
    drop_outside_shell: bool = False
    """Drop wall-like strokes outside the bounding box of the largest wall component (legend, title)."""
    legend_frame_min_m: float = 1.0
    """Thin-line rectangles at least this wide and high that do not hold the building are legend or title
    frames: the walls inside them (scale bars, legend symbols) are dropped. 0 disables."""
    legend_frame_cover: float = 0.9
    """Share of each side of a thin component's bounding box that its ink must cover to be a frame."""
    bridge_max_m: float = 2.0
    """Longest wall stretch hidden under a symbol that is bridged (only across symbol pixels)."""
    hough_min_length_m: float = 0.15
    """Minimum skeleton segment length for the probabilistic Hough transform."""
    hough_max_gap_m: float = 0.05
    """Gap closed along a skeleton line by the Hough transform."""
    lines: lines.LinesConfig = field(
        default_factory=lambda: lines.LinesConfig(
            explained_variance=0.9995,
            angle_tol_deg=2.0,
            offset_tol_m=0.06,
            max_gap_m=0.3,
            extend_m=0.2,
            min_overlap=0.5,
        )
    )
    """Shared line clustering / regularization / connection settings (metres; scaled to pixels)."""
    min_wall_length_ratio: float = 0.5
    """Walls shorter than this times their thickness are skeleton spurs at wall ends and corners."""
    short_wall_length_ratio: float = 1.2
    """Walls shorter than this times their thickness are kept only as the straight continuation of
    another wall beyond a junction (a jamb beside a door); turned ones are skeleton spurs at corners."""
    door_min_m: float = 0.5
    """Smallest wall gap taken for a door."""
    door_max_m: float = 2.2
    """Largest wall gap taken for a door."""
    window_ink_share: float = 0.9
    """A wall gap whose length is covered by thin ink at least this much is a window (a thin line in the
    wall) and becomes part of the wall; above 1 keeps every gap a door."""
    min_room_area_m2: float = 1.0
    """Free-space regions smaller than this are not rooms (shafts, wall interiors)."""
    min_extent_m: float = 2.0
    """Smallest plausible plan extent; a smaller one means the scale is wrong."""
    max_extent_m: float = 400.0
    """Largest plausible plan extent; a larger one means the scale is wrong."""
    min_walls: int = 3
    """Fewer walls than this means the image holds no floor plan."""
    min_wall_length_diagonals: float = 0.5
    """The walls must add up to at least this many image diagonals, else it is no plan."""
    min_wall_coverage: float = 0.8
    """Share of the cleaned wall raster that the vector walls must explain, else it is no plan."""
    coverage_wall_length_ratio: float = 1.2
    """Only walls at least this many times their thickness long explain the raster in that test: texture
    and noise also yield short straight pieces."""


@dataclass(frozen=True)
class PlanScale:
    """How pixels become metres: exactly one of `m_per_px`, `known_distance`, `outline_length_m`."""

    m_per_px: float | None = None
    """Metres per pixel of the (rectified) image."""
    known_distance: tuple[float, float, float, float, float] | None = None
    """x0, y0, x1, y1 (pixels) and the distance between them in metres."""
    outline_length_m: float | None = None
    """Perimeter of the building outline in metres."""
    outline_size_m: tuple[float, float] | None = None
    """Width and height (metres) of the outline rectangle whose corners are `corners_px`: fixes the
    rectified aspect ratio (four corners alone cannot) and the scale."""
    corners_px: tuple[tuple[float, float], ...] | None = None
    """Four outline corners (pixels, clockwise from top-left) for perspective rectification; the
    rectified image keeps the mean side lengths, so the other scale inputs refer to it."""

    def __post_init__(self) -> None:
        given = [
            v is not None
            for v in (self.m_per_px, self.known_distance, self.outline_length_m, self.outline_size_m)
        ]
        if sum(given) != 1:
            raise ValueError(
                "PlanScale needs exactly one of m_per_px, known_distance, outline_length_m, outline_size_m"
            )
        if self.outline_size_m is not None and (self.corners_px is None or min(self.outline_size_m) <= 0):
            raise ValueError("outline_size_m needs corners_px and two positive lengths")
        if self.m_per_px is not None and not (math.isfinite(self.m_per_px) and self.m_per_px > 0):
            raise ValueError(f"m_per_px must be a positive number, got {self.m_per_px}")
        if self.known_distance is not None:
            x0, y0, x1, y1, d = self.known_distance
            if not (d > 0 and math.hypot(x1 - x0, y1 - y0) > 0):
                raise ValueError(
                    f"known_distance needs two distinct points and a positive distance, got {self.known_distance}"
                )
        if self.outline_length_m is not None and not self.outline_length_m > 0:
            raise ValueError(f"outline_length_m must be positive, got {self.outline_length_m}")
        if self.corners_px is not None and np.asarray(self.corners_px).shape != (4, 2):
            raise ValueError("corners_px must be four (x, y) pixel pairs")


@dataclass(frozen=True)
class ParsedPlan:
    """Result of `parse_plan`, in metres in the plan frame."""

    walls: NDArray[np.float64]
    """(M, 4) wall centrelines x0 y0 x1 y1."""
    thickness_m: NDArray[np.float64]
    """(M,) wall thickness measured across the raster."""
    rooms: list[tuple[Polygon, str | None]]
    """Enclosed free-space polygons with their label (None when unlabelled), largest first."""
    doors: NDArray[np.float64]
    """(D, 4) door gaps as segments between the two wall ends (or wall end and wall); gaps spanned by a
    thin line (windows) are walls instead."""
    preview: NDArray[np.uint8]
    """(h, w, 3) RGB picture at working resolution: cleaned plan, walls, rooms, doors."""
    metrics: dict[str, Any]
    """Timings (s), counts, removed symbol pixels, scale used."""
    m_per_px: float = 0.0
    """Scale of the input (rectified) image."""


# ---------------------------------------------------------------- raster side


def _hue_mask(hue_deg: NDArray, rng: tuple[float, float]) -> NDArray[np.bool_]:
    lo, hi = rng
    return (hue_deg >= lo) & (hue_deg <= hi) if lo <= hi else (hue_deg >= lo) | (hue_deg <= hi)


def _min_pool(image: NDArray[np.uint8], f: int) -> NDArray[np.uint8]:
    """Reduce by factor f keeping the darkest value of every f x f block, so 1 px lines survive."""
    if f <= 1:
        return image
    return cv2.erode(image, np.ones((f, f), np.uint8), anchor=(0, 0))[::f, ::f][
        : image.shape[0] // f, : image.shape[1] // f
    ]


def enhance(image: NDArray[np.uint8], tile_px: int, cfg: PlanConfig) -> NDArray[np.uint8]:
    """White-patch white balance, then CLAHE on lightness (the Wallis filter's local contrast role)."""
    img = image.astype(np.float32)
    step = max(1, img.shape[0] * img.shape[1] // 1_000_000)  # a subsample is enough for a percentile
    white = np.percentile(img.reshape(-1, 3)[::step], cfg.white_balance_percentile, axis=0)
    img = np.clip(img * (255.0 / np.maximum(white, 32.0)), 0, 255).astype(np.uint8)
    if cfg.clahe_clip > 0:
        lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB)
        h, w = img.shape[:2]
        tiles = (max(1, w // max(tile_px, 8)), max(1, h // max(tile_px, 8)))
        lab[..., 0] = cv2.createCLAHE(clipLimit=cfg.clahe_clip, tileGridSize=tiles).apply(lab[..., 0])
        img = cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)
    return img


def symbol_mask(image: NDArray[np.uint8], cfg: PlanConfig) -> dict[str, NDArray[np.bool_]]:
    """Green, red and blue symbol pixels by HSV segmentation (Peter et al. 2013b colour segmentation)."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    hue = hsv[..., 0].astype(np.float32) * 2.0
    coloured = (hsv[..., 1] >= cfg.symbol_min_saturation) & (hsv[..., 2] >= cfg.symbol_min_value)
    return {
        "green": coloured & _hue_mask(hue, cfg.green_hue_deg),
        "red": coloured & _hue_mask(hue, cfg.red_hue_deg),
        "blue": coloured & _hue_mask(hue, cfg.blue_hue_deg),
    }


def _solid_symbols(
    mask: NDArray[np.bool_], hole_px: int, core_kernel: NDArray[np.uint8], solid_share: float
) -> NDArray[np.bool_]:
    """The symbols among one colour's pixels: filled signs and arrows, not the thin strokes of a drawing
    whose line work is coloured (CAD layers). The solid core survives an opening as wide as a symbol's
    narrowest part once white details narrower than hole_px (pictograms) are closed; a connected piece
    of the colour that is mostly core is a symbol whole (its thin tips and rims too), elsewhere only the
    core is."""
    m8 = mask.astype(np.uint8)
    filled = _close(m8, np.ones((hole_px, hole_px), np.uint8))
    core = cv2.morphologyEx(filled, cv2.MORPH_OPEN, core_kernel).astype(bool) & mask
    if not core.any():
        return core
    n, lab = cv2.connectedComponents(m8, connectivity=8)
    share = np.bincount(lab[core], minlength=n) / np.maximum(np.bincount(lab.ravel(), minlength=n), 1)
    whole = share >= solid_share
    whole[0] = False
    return core | whole[lab]


def _close(mask: NDArray[np.uint8], kernel: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Closing with paper (0) outside the image: the default border would join strokes to the edge."""
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)


def _fill_outline_walls(
    ink: NDArray[np.bool_],
    max_width_px: float,
    faces: NDArray[np.bool_] | None = None,
    min_width_px: float = 0.0,
    one_face_percentile: float = 90.0,
) -> NDArray[np.bool_]:
    """Fill the space between facing ink lines closer than max_width_px (outline-drawn walls, CAD style)
    along rows and columns: a run of paper is filled when ink bounds it on both sides within the width
    (a closing with a 1 x L and an L x 1 segment). With `faces` (the lines of a drawing's wall layers),
    a run is filled when both of its ink ends are wall faces, or when one is and the run is no wider than
    the walls drawn with two faces (their one_face_percentile of widths from min_width_px up): where
    furniture or a window abuts a wall its face may be drawn in another layer, but two lines of other
    layers never make a wall, and neither does furniture standing farther from a wall than a wall is
    thick. A disc or diagonal closing would also round every room corner; walls drawn at other angles
    than 0/90 degrees as outlines are therefore not filled."""
    L = int(max_width_px) | 1
    if L < 3:
        return ink
    runs = []
    for m, f in ((ink, faces), (ink.T, None if faces is None else faces.T)):
        h, w = m.shape
        idx = np.arange(w, dtype=np.int32)
        left = np.maximum.accumulate(np.where(m, idx, -1), axis=1)
        right = np.minimum.accumulate(np.where(m, idx, w)[:, ::-1], axis=1)[:, ::-1]
        width = right - left - 1
        fill = (left >= 0) & (right < w) & (width < L)
        n_faces = None
        if f is not None:
            rows = np.arange(h)[:, None]
            n_faces = f[rows, np.clip(left, 0, w - 1)].astype(np.uint8) + f[rows, np.clip(right, 0, w - 1)]
        runs.append((fill, width, n_faces))
    if faces is not None:
        both = np.concatenate([wd[fl & (nf == 2) & (wd >= min_width_px)] for fl, wd, nf in runs])
        one_max = float(np.percentile(both, one_face_percentile)) if len(both) else -1.0
        runs = [(fl & ((nf == 2) | ((nf == 1) & (wd <= one_max))), wd, nf) for fl, wd, nf in runs]
    return ink | runs[0][0] | runs[1][0].T


def _ink_layers(image: NDArray[np.uint8], ink: NDArray[np.bool_], cfg: PlanConfig) -> NDArray[np.uint8]:
    """Drawing layer of every ink pixel, by colour: 0 for black and grey ink, 1-12 for coloured ink by hue
    (30 degree bins centred on 0, 30, ... 330 degrees: the pens of a CAD drawing's layers). Pale
    anti-aliased rims keep the hue of their line."""
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)
    hue_bin = ((hsv[..., 0].astype(np.int32) * 2 + 15) // 30) % 12 + 1
    return np.where(ink & (hsv[..., 1] >= cfg.layer_min_saturation), hue_bin, 0).astype(np.uint8)


def _wall_layers(
    ink: NDArray[np.bool_], layers: NDArray[np.uint8], px: float, cfg: PlanConfig
) -> tuple[list[int], dict[int, float]]:
    """Layers that draw walls, and every layer's wall evidence (metres of wall face). A drawing in one
    colour has one layer. In a drawing with coloured layers (walls, windows, furniture, text, axes each in
    their pen), the wall layer is the one whose long straight lines most often pair up at wall spacing
    (min_wall_thickness_m to max_outline_width_m) into bands; furniture is drawn in shorter or wider-spaced
    lines. Layers with at least wall_layer_share of the best evidence are wall layers too. Scored on a
    grid about wall_layer_grid_m coarse (max-pooled masks keep thin lines) to stay quick."""
    n_ink = max(int(ink.sum()), 1)
    counts = np.bincount(layers[ink], minlength=13)
    cand = [int(c) for c in np.flatnonzero(counts >= cfg.layer_min_share * n_ink)]
    if len(cand) <= 1:
        return cand, {}
    c = max(1, round(cfg.wall_layer_grid_m * px))
    cpx = px / c
    line = max(3, round(cfg.wall_face_min_m * cpx) | 1)
    k = max(1, round(cfg.min_wall_thickness_m * cpx)) | 1
    evidence: dict[int, float] = {}
    for lay in cand:
        m = cv2.dilate(((layers == lay) & ink).astype(np.uint8), np.ones((c, c), np.uint8), anchor=(0, 0))[
            ::c, ::c
        ]
        long_h = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((1, line), np.uint8))
        long_v = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((line, 1), np.uint8))
        faces = 0
        for lines_m in (long_h, long_v):
            band = _fill_outline_walls(lines_m.astype(bool), cfg.max_outline_width_m * cpx).astype(np.uint8)
            band = cv2.morphologyEx(band, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
            faces += int((lines_m & cv2.dilate(band, np.ones((3, 3), np.uint8))).sum())
        evidence[lay] = faces / cpx
    best = max(evidence.values())
    return [lay for lay in cand if best > 0 and evidence[lay] >= cfg.wall_layer_share * best], evidence


def _remove_small_components(mask: NDArray[np.bool_], max_size_px: float) -> tuple[NDArray, NDArray]:
    """Drop components whose bounding box fits in max_size_px; returns (mask, (T, 2) centres of them)."""
    _n, lab, stats, cents = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    small = np.maximum(stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]) < max_size_px
    small[0] = False
    return mask & ~small[lab], cents[small]


def _inside_shell(walls: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Keep the wall components whose centre lies within the building: the union of the bounding boxes
    of the big components (diagonal at least half the largest one's). Legend frames, title blocks and
    north arrows beside the building go; free-standing walls inside it stay."""
    n, lab, stats, cents = cv2.connectedComponentsWithStats(walls.astype(np.uint8), connectivity=8)
    if n <= 2:
        return walls
    diag = np.hypot(stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT])
    big = 1 + np.flatnonzero(diag >= 0.5 * diag.max())
    x0, y0 = stats[big, 0].min(), stats[big, 1].min()
    x1 = (stats[big, 0] + stats[big, 2]).max()
    y1 = (stats[big, 1] + stats[big, 3]).max()
    inside = (cents[:, 0] >= x0) & (cents[:, 0] <= x1) & (cents[:, 1] >= y0) & (cents[:, 1] <= y1)
    inside[0] = False
    return inside[lab]


def _legend_frames(dark: NDArray[np.bool_], min_side_px: float, cover: float) -> list[tuple[int, ...]]:
    """Bounding boxes (x, y, w, h) of the ink components drawn as a rectangle frame (every side of the
    box covered by the component's ink) at least min_side_px wide and high: legend and title frames."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(dark.astype(np.uint8), connectivity=8)
    out = []
    for k in range(1, n):
        x, y, w, h, _a = (int(v) for v in stats[k])
        if min(w, h) < min_side_px:
            continue
        comp = lab[y : y + h, x : x + w] == k
        b = 3  # a frame line a few pixels wide, or anti-aliased
        sides = (comp[:b].any(0), comp[-b:].any(0), comp[:, :b].any(1), comp[:, -b:].any(1))
        if min(float(side.mean()) for side in sides) >= cover:
            out.append((x, y, w, h))
    return out


def _drop_framed(walls: NDArray[np.bool_], frames: list[tuple[int, ...]]) -> NDArray[np.bool_]:
    """Drop the wall components inside a legend frame; a frame around the largest wall component (a
    drawing's border, or the outline of a building drawn in thin lines) holds the building and stays."""
    if not frames:
        return walls
    n, lab, stats, cents = cv2.connectedComponentsWithStats(walls.astype(np.uint8), connectivity=8)
    if n <= 1:
        return walls
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    drop = np.zeros(n, bool)
    for x, y, w, h in frames:
        bx, by, bw, bh = stats[big, :4]
        if bx >= x and by >= y and bx + bw <= x + w and by + bh <= y + h:
            continue
        drop |= (cents[:, 0] > x) & (cents[:, 0] < x + w) & (cents[:, 1] > y) & (cents[:, 1] < y + h)
    drop[0] = False
    return walls & ~drop[lab]


def _bridge_symbols(
    walls: NDArray[np.bool_], symbols: NDArray[np.bool_], length_px: int, run_px: int
) -> NDArray:
    """Restore wall pixels hidden under symbols. Walls running along a direction (with the symbols, their
    runs along it are longer than run_px, more than any wall thickness) are closed along that direction
    with gaps up to length_px, and a gap is filled only when symbols cover all of it: door gaps (paper,
    even with an escape arrow drawn across) stay open, and a symbol between two parallel walls (an arrow
    in a corridor) is not taken for a wall across them. Horizontal and vertical walls only (the plans'
    prevailing directions; diagonal kernels are slow)."""
    if length_px < 3 or not symbols.any():
        return walls
    w8 = walls.astype(np.uint8)
    ws8 = (walls | symbols).astype(np.uint8)
    L, R = int(length_px) | 1, max(3, int(run_px) | 1)
    out = walls.copy()
    for axis, run, gap in ((1, (1, R), (1, L)), (0, (R, 1), (L, 1))):
        # wall pieces between symbols are short, but with the symbols they run along the direction
        along = cv2.morphologyEx(ws8, cv2.MORPH_OPEN, np.ones(run, np.uint8)) & w8
        gaps = _close(along, np.ones(gap, np.uint8)).astype(bool) & ~along.astype(bool)
        # a gap is bridged only when symbols cover all of it: an arrow drawn across a door leaves paper
        # on both of its sides, and the door stays open
        structure = np.zeros((3, 3), int)
        structure[1, :] = 1
        runs, _ = ndimage.label(gaps if axis == 1 else gaps.T, structure=structure)
        if axis == 0:
            runs = runs.T
        bad = np.zeros(runs.max() + 1, bool)
        bad[np.unique(runs[gaps & ~symbols & ~walls])] = True
        bad[0] = True
        out |= ~bad[runs]
    return out


# ---------------------------------------------------------------- vector side


def _sample_mask(mask_f: NDArray[np.float32], pts: NDArray) -> NDArray[np.float32]:
    """Bilinear samples of a float raster at (N, 2) pixel positions (u, v); 0 outside."""
    if len(pts) == 0:
        return np.zeros(0, np.float32)
    mx = pts[:, 0].astype(np.float32).reshape(-1, 1)
    my = pts[:, 1].astype(np.float32).reshape(-1, 1)
    return cv2.remap(mask_f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)[:, 0]


def _thickness_px(
    seg: NDArray, mask_f: NDArray[np.float32], max_px: float, lines_f: NDArray[np.float32] | None = None
) -> tuple[float, float]:
    """(median width, median offset of the run's centre along the left normal) of the ink run across
    the centreline, sampled along the middle of the wall: the distance across the wall raster, and a
    sub-pixel correction of the skeleton's position (thinning is biased by up to a pixel).

    With `lines_f` (the drawn lines before outline walls were filled), a run that holds paper between
    two lines is an outline-drawn wall: its width is the distance between the centres of its first and
    last line (CAD draws a wall's faces as lines centred on the faces), not the outer width of the ink."""
    a, b = seg[:2], seg[2:]
    d = b - a
    L = float(np.hypot(*d))
    if L <= 0:
        return 0.0, 0.0
    u = d / L
    nrm = np.array([-u[1], u[0]])
    ts = np.linspace(0.15, 0.85, max(3, min(40, int(L / 2))))
    step = 0.25
    offs = np.arange(-max_px, max_px + step, step)
    pts = ((a + ts[:, None, None] * d) + offs[None, :, None] * nrm).reshape(-1, 2)
    vals = _sample_mask(mask_f, pts).reshape(len(ts), len(offs))
    drawn = None if lines_f is None else _sample_mask(lines_f, pts).reshape(len(ts), len(offs))
    c = len(offs) // 2
    widths, centres = [], []
    for r, row in enumerate(vals):
        inside = row > 0.01  # down to the bilinear tails, so the run's mass is the full width
        if not inside[c - 4 : c + 5].any():
            continue
        j = c - 4 + int(np.argmax(row[c - 4 : c + 5]))
        lo = j
        while lo > 0 and inside[lo - 1]:
            lo -= 1
        hi = j
        while hi < len(row) - 1 and inside[hi + 1]:
            hi += 1
        mass = row[lo : hi + 1]
        width = float(mass.sum()) * step
        if drawn is not None:
            faces = _line_centres(drawn[r, lo : hi + 1], offs[lo : hi + 1])
            if len(faces) >= 2:
                width = faces[-1] - faces[0]
        widths.append(width)
        centres.append(float((mass * offs[lo : hi + 1]).sum() / max(float(mass.sum()), 1e-9)))
    return (float(np.median(widths)), float(np.median(centres))) if widths else (0.0, 0.0)


def _line_centres(profile: NDArray, offs: NDArray) -> list[float]:
    """Centres (mass-weighted offsets) of the ink runs of a profile across a wall, separated by paper."""
    ink = profile > 0.5
    out = []
    k = 0
    while k < len(ink):
        if not ink[k]:
            k += 1
            continue
        e = k
        while e + 1 < len(ink) and ink[e + 1]:
            e += 1
        w = profile[k : e + 1]
        out.append(float((w * offs[k : e + 1]).sum() / max(float(w.sum()), 1e-9)))
        k = e + 1
    return out


def _centre_and_measure(segs: NDArray, mask_f: NDArray[np.float32], max_px: float) -> tuple[NDArray, NDArray]:
    """Segments moved onto the middle of their ink band, and their thickness (px)."""
    out = segs.copy()
    thick = np.zeros(len(segs))
    for i, sg in enumerate(segs):
        thick[i], off = _thickness_px(sg, mask_f, max_px)
        d = sg[2:] - sg[:2]
        nrm = np.array([-d[1], d[0]]) / max(float(np.hypot(*d)), 1e-9)
        # thinning is biased by up to a pixel; a larger offset is another wall's ink met at a junction
        out[i] += np.tile(float(np.clip(off, -1.5, 1.5)) * nrm, 2)
    return out, thick


def _free_ends(segs: NDArray, tol: float, thick: NDArray | None = None) -> list[tuple[int, int]]:
    """(segment, end) pairs of the ends farther than tol from every other segment (with `thick`, also
    outside its ink: farther than half its thickness)."""
    if len(segs) == 0:
        return []
    ends = np.concatenate([segs[:, :2], segs[:, 2:]])
    owner = np.concatenate([np.arange(len(segs))] * 2)
    dist = lines.point_segment_distances(ends, segs)
    if thick is not None:
        dist -= np.maximum(np.asarray(thick)[None, :] / 2 - tol, 0.0)
    dist[np.arange(len(ends)), owner] = np.inf
    free = dist.min(axis=1) > tol if len(segs) > 1 else np.ones(len(ends), bool)
    return [(int(owner[k]), int(k >= len(segs))) for k in np.flatnonzero(free)]


def _spur_free(segs: NDArray, keep: NDArray[np.bool_], short_px: NDArray) -> NDArray[np.bool_]:
    """False for the short segments (length below short_px), off the plan's main axes, that are not on the
    line of another kept segment (both ends within 1.5 px of it, directions within 2 degrees): a jamb beside a door or window
    continues its wall, a skeleton spur at a corner turns away from both walls."""
    out = np.ones(len(segs), bool)
    if len(segs) == 0:
        return out
    ang = lines.angles(segs)
    main = ang[int(np.argmax(lines.lengths(segs)))]
    # along or across the longest wall: the plan's main axes, where spurs (diagonal at corners) are not
    on_axes = np.abs(np.sin(2 * (ang - main))) < math.sin(math.radians(4.0))
    for i in np.flatnonzero((lines.lengths(segs) < short_px) & ~on_axes):
        others = np.flatnonzero(keep & (np.arange(len(segs)) != i))
        turn = np.abs(np.sin(np.asarray(lines.angle_difference(ang[others], ang[i]))))
        same = others[turn < math.sin(math.radians(2.0))]
        a = segs[same, :2]
        u = segs[same, 2:] - a
        u /= np.maximum(np.hypot(u[:, 0], u[:, 1]), 1e-9)[:, None]
        off = [np.abs(u[:, 0] * (e[1] - a[:, 1]) - u[:, 1] * (e[0] - a[:, 0])) for e in segs[i].reshape(2, 2)]
        out[i] = bool(len(same) and (np.maximum(*off) <= 1.5).any())
    return out


def _jamb(p: NDArray, u: NDArray, segs: NDArray, thick: NDArray, i: int, mask_f: NDArray[np.float32]) -> bool:
    """Whether wall ink runs on from the junction p along u past the face of the wall crossing there."""
    d = lines.point_segment_distances(p[None], segs)[0]
    d[i] = np.inf
    reach = thick[int(np.argmin(d))] / 2 + 2.0
    return bool(_sample_mask(mask_f, (p + reach * u)[None])[0] > 0.5)


def _regularize(segs: NDArray, band_px: NDArray, lcfg: lines.LinesConfig) -> NDArray[np.float64]:
    """`lines.regularize`, except that walls its orientation clusters would turn by more than the angle
    tolerance and more than their own angle is uncertain keep out of those clusters: a wing of the
    building drawn a few degrees off the main axes would otherwise be snapped to them, and would pull the
    main axes off by a fraction of a degree (0.3 degrees is 0.3 m over 60 m). The two sets are
    regularized apart. A skeleton piece can tilt across its ink band (band_px (N,) wide) by up to
    atan(band / length) and still lie in it: that is how uncertain its angle is."""
    out, rot = lines.regularize(segs, lcfg)
    uncertain = np.arctan2(np.maximum(band_px, 2.0), np.maximum(lines.lengths(segs), 1e-9))
    off = np.abs(rot) > np.maximum(math.radians(lcfg.angle_tol_deg), uncertain)
    if off.any() and not off.all():
        out[~off] = lines.regularize(segs[~off], lcfg)[0]
        out[off] = lines.regularize(segs[off], lcfg)[0]
    return out


def _join_hidden_junctions(
    segs: NDArray, thick: NDArray, support: NDArray[np.float32], door_min_px: float
) -> NDArray[np.float64]:
    """Free wall ends whose prolongation meets another wall after a gap narrower than the smallest door
    and drawn (ink or a removed symbol over all of it): the junction is hidden under a symbol, and the
    wall is prolonged to the other wall's centreline. A gap of paper stays open."""
    out = segs.copy()
    for i, e in _free_ends(segs, 1.0, thick):
        a, b = segs[i, :2], segs[i, 2:]
        p, q = (b, a) if e else (a, b)
        u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
        r = _first_wall_hit(p, u, segs, thick, i)
        if not r < door_min_px:
            continue
        pts = p + np.linspace(0, r, max(2, int(r) + 1))[:, None] * u
        if float((_sample_mask(support, pts) > 0.5).mean()) >= 0.99:
            out[i, 2 * e : 2 * e + 2] = p + r * u
    return out


def _on_other_wall(p: NDArray, q: NDArray, segs: NDArray, i: int, jamb: tuple[int, int] | None) -> bool:
    """Whether the middle of the gap p -> q (a quarter, half and three quarters along) lies on a wall
    other than i and the jamb's wall (within a pixel): the wall runs on there, the gap is no opening."""
    skip = [i] if jamb is None else [i, jamb[0]]
    others = np.delete(segs, skip, axis=0)
    probe = p + np.outer([0.25, 0.5, 0.75], q - p)
    return bool(len(others) and lines.point_segment_distances(probe, others).min() <= 1.0)


def _first_wall_hit(
    p: NDArray, u: NDArray, segs: NDArray, thick: NDArray, i: int, skip: int | None = None
) -> float:
    """Distance (px) from the end p of wall i along the unit direction u to the first other wall the
    prolongation meets (inf when none). A wall is met when the ray crosses its centreline within its
    length, lengthened by half the thickness of wall i plus a pixel (a wall ending beside the ray still
    blocks the gap's ink band). Walls crossing within their half thickness of p are the junction p sits
    at (a jamb at a corner), not an obstacle; nor is wall `skip`."""
    best = math.inf
    for k in range(len(segs)):
        if k == i or k == skip:
            continue
        t = segs[k]
        hit = lines.line_intersection(np.concatenate([p, p + u]), t)
        if hit is None:
            continue
        _x, s_ray, s_seg = hit
        slack = (thick[i] / 2 + 1.0) / max(float(np.hypot(*(t[2:] - t[:2]))), 1e-9)
        if s_ray > thick[k] / 2 + 1.0 and -slack <= s_seg <= 1 + slack:
            best = min(best, s_ray)
    return best


def _find_doors(
    segs: NDArray, thick: NDArray, cfg_px: dict[str, float], mask_f: NDArray[np.float32] | None = None
) -> NDArray[np.float64]:
    """Door gaps: a free wall end whose prolongation meets another wall (its collinear continuation or a
    crossing wall) after a gap between door_min and door_max."""
    doors: list[NDArray] = []
    used: set[tuple[int, int]] = set()
    ang = lines.angles(segs) if len(segs) else np.zeros(0)
    sin_tol = math.sin(math.radians(2.0))
    # an end inside another wall's ink is a junction the skeleton stopped short of, not a door jamb
    free = _free_ends(segs, 1.0, thick)
    for i, e in free:
        if (i, e) in used:
            continue
        s = segs[i]
        p = s[2:] if e else s[:2]
        q = s[:2] if e else s[2:]
        u = (p - q) / max(float(np.hypot(*(p - q))), 1e-9)
        # a door is a gap in one wall: the prolongation stops at the first wall it meets, and a wall end
        # beyond that (the same line on the far side of a corridor) is not the other jamb
        reach = _first_wall_hit(p, u, segs, thick, i)
        best = None
        for j in range(len(segs)):
            if j == i:
                continue
            t = segs[j]
            # the other jamb is the end of a wall on the same line: parallel (a crossing wall's end that
            # lies on the line is a corner, met by the ray below) and within half a thickness of the line
            parallel = abs(math.sin(float(lines.angle_difference(ang[i], ang[j])))) <= sin_tol
            for ej, pt in ((0, t[:2]), (1, t[2:])) if parallel else ():
                # collinear continuation: a facing end, free or at a corner (a door beside a T-junction)
                if (j, ej) in used or float((t[2:] if ej == 0 else t[:2]) @ u - pt @ u) <= 0:
                    continue
                v = pt - p
                along = float(v @ u)
                lateral = abs(float(v[0] * u[1] - v[1] * u[0]))
                if along > reach + thick[j] / 2 + 1.0:
                    continue
                if cfg_px["door_min"] <= along <= cfg_px["door_max"] and lateral < max(thick[i], 2.0) / 2:
                    if best is None or along < best[0]:
                        best = (along, pt.copy(), (j, ej))
            hit = lines.line_intersection(np.concatenate([p, p + u]), t)
            if hit is not None:
                x, s_ray, s_seg = hit
                # the wall's end may stop at the face of the wall the ray runs along (a door at a corner)
                slack = (thick[i] / 2 + 1.0) / max(float(np.hypot(*(t[2:] - t[:2]))), 1e-9)
                if (
                    -slack <= s_seg <= 1 + slack
                    and cfg_px["door_min"] <= s_ray <= cfg_px["door_max"]
                    and s_ray <= reach + 1e-6
                ):
                    foot = x - u * thick[j] / 2  # stop at the face of the crossing wall
                    if best is None or s_ray < best[0]:
                        best = (s_ray, foot, None)
        if best is not None and _on_other_wall(p, best[1], segs, i, best[2]):
            best = None  # the gap runs along another wall: the wall goes on, no opening
        if best is not None:
            doors.append(np.concatenate([p, best[1]]))
            used.add((i, e))
            if best[2] is not None:
                used.add(best[2])
    # a door beside two junctions (both jambs trimmed to a crossing wall) has no free end: collinear
    # walls whose facing ends are a door width apart with nothing crossing the gap
    for i, j in itertools.combinations(range(len(segs)), 2):
        if abs(math.sin(float(lines.angle_difference(ang[i], ang[j])))) > sin_tol:
            continue
        for ei, ej in itertools.product((0, 1), (0, 1)):
            if (i, ei) in used or (j, ej) in used:
                continue
            p, q = segs[i].reshape(2, 2)[ei], segs[j].reshape(2, 2)[ej]
            u = segs[i].reshape(2, 2)[ei] - segs[i].reshape(2, 2)[1 - ei]
            u /= max(float(np.hypot(*u)), 1e-9)
            v = q - p
            along, lateral = float(v @ u), abs(float(v[0] * u[1] - v[1] * u[0]))
            facing = float((segs[j].reshape(2, 2)[1 - ej] - q) @ u) > 0
            if not (facing and cfg_px["door_min"] <= along <= cfg_px["door_max"]):
                continue
            if lateral >= max(thick[i], 2.0) / 2:
                continue
            if _on_other_wall(p, q, segs, i, (j, ej)):
                continue
            if along > _first_wall_hit(p, u, segs, thick, i, j) + thick[j] / 2 + 1.0:
                continue  # another wall crosses the gap: the two ends face each other across a room
            if mask_f is not None and not (
                _jamb(p, u, segs, thick, i, mask_f) and _jamb(q, -u, segs, thick, j, mask_f)
            ):
                continue  # the walls turn at both ends (an alcove's mouth), no wall runs on into the gap
            doors.append(np.concatenate([p, q]))
            used.update({(i, ei), (j, ej)})
    return np.array(doors, dtype=np.float64).reshape(-1, 4)


def _to_metres(seg_px: NDArray, f: int, s: float) -> NDArray[np.float64]:
    """Working pixels (after min-pooling by f) -> plan metres (u s, -v s) of the input pixel grid."""
    out = (np.asarray(seg_px, dtype=np.float64) * f + (f - 1) / 2.0) * s
    out[..., 1::2] *= -1
    return out


def _rectify(
    image: NDArray[np.uint8], corners: NDArray, size_m: tuple[float, float] | None
) -> tuple[NDArray[np.uint8], float | None]:
    """Perspective rectification: the corners go to an axis-parallel rectangle with a 5 % margin. Its
    sides are the photo's mean side lengths, or, with `size_m`, the true aspect ratio at the photo's
    mean resolution (then also returns that scale, metres per pixel)."""
    c = np.asarray(corners, dtype=np.float32)
    w = 0.5 * (np.hypot(*(c[1] - c[0])) + np.hypot(*(c[2] - c[3])))
    h = 0.5 * (np.hypot(*(c[3] - c[0])) + np.hypot(*(c[2] - c[1])))
    s = None
    if size_m is not None:
        s = 0.5 * (size_m[0] / w + size_m[1] / h)
        w, h = size_m[0] / s, size_m[1] / s
    margin = 0.05 * max(w, h)
    dst = np.float32([[margin, margin], [margin + w, margin], [margin + w, margin + h], [margin, margin + h]])
    H = cv2.getPerspectiveTransform(c, dst)
    size = (round(w + 2 * margin), round(h + 2 * margin))
    return cv2.warpPerspective(image, H, size, flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255)), s


def _outline_scale(image: NDArray[np.uint8], length_m: float, cfg: PlanConfig) -> float:
    """Metres per pixel from the perimeter of the largest dark outline not touching the image border
    (a photo's own frame or background does)."""
    img = enhance(image, max(image.shape[:2]) // 4, cfg)
    dark = (255 - img.min(axis=2)).astype(np.uint8)
    _, ink = cv2.threshold(dark, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    ink = _close(ink, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(ink, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    h, w = ink.shape
    inner = []
    for c in contours:
        x, y, cw, ch = cv2.boundingRect(c)
        if x > 0 and y > 0 and x + cw < w and y + ch < h:
            inner.append(c)
    if not inner:
        raise ValueError("outline_length_m given but no building outline found")
    c = max(inner, key=cv2.contourArea)
    c = cv2.approxPolyDP(c, 0.002 * cv2.arcLength(c, True), True)
    return length_m / cv2.arcLength(c, True)


# ---------------------------------------------------------------- the stage


def parse_plan(
    image: NDArray[np.uint8],
    scale: PlanScale,
    cfg: PlanConfig,
    labels: dict[str, tuple[float, float]] | None = None,
    name: str = "plan image",
) -> ParsedPlan:
    """Parse a plan raster (H, W, 3) uint8 RGB into wall centrelines, thicknesses, rooms and doors (m).

    `labels` optionally maps room names to a point (plan-frame metres) inside the room. `name` is used in
    error messages. Raises ValueError (one line, naming the image) for empty images, implausible scales
    and images without a floor plan."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 16:
        raise ValueError(
            f"{name}: expected a non-empty (H, W, 3) uint8 RGB image, got {img.shape} {img.dtype}"
        )
    if int(img.max()) - int(img.min()) < 16:
        raise ValueError(f"{name}: the image is blank (no contrast), no floor plan in it")
    s_rect = None
    if scale.corners_px is not None:
        img, s_rect = _rectify(img, np.asarray(scale.corners_px), scale.outline_size_m)
    if s_rect is not None:
        s = s_rect
    elif scale.m_per_px is not None:
        s = float(scale.m_per_px)
    elif scale.known_distance is not None:
        x0, y0, x1, y1, d = scale.known_distance
        s = float(d) / math.hypot(x1 - x0, y1 - y0)
    else:
        s = _outline_scale(img, float(scale.outline_length_m), cfg)
    extent_m = max(img.shape[:2]) * s
    if not cfg.min_extent_m <= extent_m <= cfg.max_extent_m * 1.5:
        raise ValueError(
            f"{name}: scale {s:.4g} m/px makes the image {extent_m:.3g} m across, outside the plausible "
            f"{cfg.min_extent_m:g}-{cfg.max_extent_m:g} m (wrong units?)"
        )
    f = max(1, math.ceil(max(img.shape[:2]) / cfg.max_side_px))
    img = _min_pool(img, f)
    sp = s * f  # metres per working pixel
    px = 1.0 / sp
    timings["load_s"] = time.perf_counter() - t_start

    t = time.perf_counter()
    img = enhance(img, int(cfg.clahe_tile_m * px), cfg)
    syms = symbol_mask(img, cfg)
    darkness = (255 - img.min(axis=2)).astype(np.uint8)
    thr, _ = cv2.threshold(darkness, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    thr = float(np.clip(thr, *cfg.ink_threshold_bounds))
    dark = darkness > thr
    n_dark = max(int(dark.sum()), 1)
    # a colour carrying most of the line work is the drawing's pen (a one-colour CAD rendering), not symbols
    pen = [c for c, m in syms.items() if (m & dark).sum() > cfg.pen_colour_share * n_dark]
    sym_union = np.zeros(dark.shape, bool)
    hole = max(3, round(cfg.symbol_hole_m * px) | 1)
    solid_k = cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (max(3, round(cfg.symbol_min_width_m * px) | 1),) * 2
    )
    for c, m in syms.items():
        if c not in pen:
            syms[c] = _solid_symbols(m, hole, solid_k, cfg.symbol_solid_share)
            sym_union |= syms[c]
    grow = max(1, round(cfg.symbol_grow_m * px))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    sym_any = cv2.dilate(sym_union.astype(np.uint8), kernel)
    # white pictograms inside a sign belong to the sign
    sym_any = _close(sym_any, np.ones((hole, hole), np.uint8)).astype(bool)
    ink = dark & ~sym_any
    # vivid ink of another hue in a symbol's rim: line work of another layer running past the symbol
    # (a wall face past a window drawn in blue); given back below if it is the wall layer's
    rim_other = np.zeros(dark.shape, bool)
    rim_same = np.zeros(dark.shape, bool)
    if sym_union.any():
        hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV)
        hue = hsv[..., 0].astype(np.float32) * 2.0
        vivid = dark & (hsv[..., 1] >= cfg.symbol_min_saturation) & (hsv[..., 2] >= cfg.symbol_min_value)
        hues = {"green": cfg.green_hue_deg, "red": cfg.red_hue_deg, "blue": cfg.blue_hue_deg}
        for c, m in syms.items():
            if c in pen or not m.any():
                continue
            grown = _close(cv2.dilate(m.astype(np.uint8), kernel), np.ones((hole, hole), np.uint8)).astype(
                bool
            )
            own_hue = _hue_mask(hue, hues[c])
            rim_other |= grown & vivid & ~own_hue
            rim_same |= grown & own_hue
        rim_other &= ~rim_same & ~sym_union  # in the rim of a symbol of its own colour, it is that symbol
    timings["clean_s"] = time.perf_counter() - t

    t = time.perf_counter()
    # letters first, while they are still separate components; then outline walls are filled and thin
    # strokes (hatching, furniture, dimension lines) are opened away
    ink, text_px = _remove_small_components(ink, cfg.text_max_size_m * px)
    layers = _ink_layers(img, ink, cfg)
    wall_layers, layer_evidence = _wall_layers(ink, layers, px, cfg)
    faces = None
    if layer_evidence:  # several colour layers hold line work
        rim_layers = _ink_layers(img, rim_other, cfg)
        ink |= rim_other & np.isin(rim_layers, wall_layers)
        layers = _ink_layers(img, ink, cfg)
        # a drawing in coloured layers: only the wall layers' lines (rims included) are wall faces, and
        # where another layer's line is drawn over a face (a bath tub's rim, a window sill) the face runs on
        w8 = cv2.dilate((np.isin(layers, wall_layers) & ink).astype(np.uint8), np.ones((3, 3), np.uint8))
        span, run = int(cfg.bridge_max_m * px) | 1, max(3, round(cfg.min_wall_thickness_m * px) | 1)
        for ker_run, ker_span in (((1, run), (1, span)), ((run, 1), (span, 1))):
            # along the line only: a closing of the lines themselves, not of the space between two of them
            along = cv2.morphologyEx(w8, cv2.MORPH_OPEN, np.ones(ker_run, np.uint8))
            w8 |= _close(along, np.ones(ker_span, np.uint8))
        faces = w8.astype(bool) & ink
    lines_f = ink.astype(np.float32)  # the drawn lines: outline walls measure between their faces
    ink = _fill_outline_walls(ink, cfg.max_outline_width_m * px, faces, cfg.min_wall_thickness_m * px)
    k = max(1, round(cfg.min_wall_thickness_m * px)) | 1  # odd: an even kernel shifts by a pixel
    walls_r = cv2.morphologyEx(ink.astype(np.uint8), cv2.MORPH_OPEN, np.ones((k, k), np.uint8)).astype(bool)
    walls_r, more_text = _remove_small_components(walls_r, cfg.text_max_size_m * px)
    text_px = np.concatenate([text_px, more_text])
    walls_r = _bridge_symbols(
        walls_r, sym_any, int(cfg.bridge_max_m * px), int(cfg.max_outline_width_m * px) + 2
    )
    if cfg.drop_outside_shell:
        walls_r = _inside_shell(walls_r)
    if cfg.legend_frame_min_m > 0:
        frames = _legend_frames(dark, cfg.legend_frame_min_m * px, cfg.legend_frame_cover)
        walls_r = _drop_framed(walls_r, frames)
    timings["binarize_s"] = time.perf_counter() - t
    ink_area = int(walls_r.sum())
    if ink_area < 10:
        raise ValueError(f"{name}: no wall lines found in the image, no floor plan in it")
    ys, xs = np.nonzero(walls_r)
    size_m = max(xs.max() - xs.min(), ys.max() - ys.min()) * sp
    if not cfg.min_extent_m <= size_m <= cfg.max_extent_m:
        raise ValueError(
            f"{name}: the walls span {size_m:.3g} m at {s:.4g} m/px, outside the plausible "
            f"{cfg.min_extent_m:g}-{cfg.max_extent_m:g} m (wrong scale units?)"
        )

    t = time.perf_counter()
    skel = skeletonize(walls_r).astype(np.uint8) * 255
    min_len = max(3, round(cfg.hough_min_length_m * px))
    hough = cv2.HoughLinesP(
        skel,
        1,
        np.pi / 720,
        max(3, min_len // 2),
        minLineLength=min_len,
        maxLineGap=max(1, round(cfg.hough_max_gap_m * px)),
    )
    raw = hough.reshape(-1, 4).astype(np.float64) if hough is not None else np.zeros((0, 4))
    timings["skeleton_s"] = time.perf_counter() - t

    t = time.perf_counter()
    lcfg = cfg.lines.scaled(px)
    mask_f = walls_r.astype(np.float32)
    support = (walls_r | sym_any).astype(np.float32)
    segs = np.zeros((0, 4))
    if len(raw):
        segs = lines.merge_segments(raw, lcfg).segments
        band = np.array([_thickness_px(sg, mask_f, cfg.max_outline_width_m * px)[0] for sg in segs])
        segs = _regularize(segs, band, lcfg)
        segs = lines.merge_segments(segs, lcfg).segments
        segs, _ = _centre_and_measure(segs, mask_f, cfg.max_outline_width_m * px)

        def support_fn(pieces: NDArray, parent: NDArray) -> NDArray:
            out = np.zeros(len(pieces))
            for n, p in enumerate(pieces):
                L = float(np.hypot(p[2] - p[0], p[3] - p[1]))
                ts = np.linspace(0, 1, max(2, int(L) + 1))
                pts = p[:2] + ts[:, None] * (p[2:] - p[:2])
                out[n] = float((_sample_mask(support, pts) > 0.5).mean())
            return out

        segs, _ = lines.connect(segs, lcfg, support_fn)
    max_t = cfg.max_outline_width_m * px
    thick = np.array([_thickness_px(sg, mask_f, max_t)[0] for sg in segs])
    # reported thickness: between the face lines of outline-drawn walls (the raster width elsewhere)
    thick_faces = np.array([_thickness_px(sg, mask_f, max_t, lines_f)[0] for sg in segs])
    keep = (
        (lines.lengths(segs) >= cfg.min_wall_length_ratio * thick) & (thick > 0)
        if len(segs)
        else np.zeros(0, bool)
    )
    keep &= _spur_free(segs, keep, cfg.short_wall_length_ratio * thick)
    segs, thick, thick_faces = segs[keep], thick[keep], thick_faces[keep]
    # skeletons stop half a thickness short of a free wall end: prolong free ends to the wall face
    for i, e in _free_ends(segs, 1.0):
        a, b = segs[i, :2], segs[i, 2:]
        u = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
        if e:
            segs[i, 2:] = b + u * thick[i] / 2
        else:
            segs[i, :2] = a - u * thick[i] / 2
    segs = _join_hidden_junctions(segs, thick, support, cfg.door_min_m * px)
    timings["vectorize_s"] = time.perf_counter() - t
    if len(segs) < cfg.min_walls:
        raise ValueError(f"{name}: only {len(segs)} straight walls found, no floor plan in it")
    total_px = float(lines.lengths(segs).sum())
    if total_px < cfg.min_wall_length_diagonals * math.hypot(*walls_r.shape):
        raise ValueError(
            f"{name}: the straight walls add up to only {total_px * sp:.3g} m in a "
            f"{math.hypot(*walls_r.shape) * sp:.3g} m wide image, no floor plan in it"
        )
    rendered = np.zeros(walls_r.shape, np.uint8)
    long_walls = lines.lengths(segs) >= cfg.coverage_wall_length_ratio * thick
    for sg, th in zip(segs[long_walls], thick[long_walls], strict=True):
        p0, p1 = np.round(sg[:2]).astype(int), np.round(sg[2:]).astype(int)
        cv2.line(rendered, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 1, max(1, round(th) + 2))
    coverage = float((rendered.astype(bool) & walls_r).sum() / ink_area)
    if coverage < cfg.min_wall_coverage:
        raise ValueError(
            f"{name}: straight walls explain only {coverage:.0%} of the dark strokes, no floor plan in it"
        )

    t = time.perf_counter()
    doors = _find_doors(
        segs, thick, {"door_min": cfg.door_min_m * px, "door_max": cfg.door_max_m * px}, mask_f
    )
    n_windows = 0
    if len(doors) and cfg.window_ink_share <= 1.0:
        # a gap spanned by a thin line is a window drawn in its wall: the wall goes on through it
        thin = cv2.dilate((dark & ~sym_any).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
        window = np.zeros(len(doors), bool)
        for n, dr in enumerate(doors):
            L = float(np.hypot(*(dr[2:] - dr[:2])))
            pts = dr[:2] + np.linspace(0, 1, max(2, int(L) + 1))[:, None] * (dr[2:] - dr[:2])
            window[n] = float((_sample_mask(thin, pts) > 0.5).mean()) >= cfg.window_ink_share
        if window.any():
            near = lines.point_segment_distances(doors[window][:, :2], segs).argmin(axis=1)
            segs = np.concatenate([segs, doors[window]])
            thick = np.concatenate([thick, thick[near]])
            thick_faces = np.concatenate([thick_faces, thick_faces[near]])
            doors, n_windows = doors[~window], int(window.sum())
    closed = walls_r.astype(np.uint8)
    for sg, th in zip(segs, thick, strict=True):
        cv2.line(
            closed,
            tuple(int(v) for v in np.round(sg[:2])),
            tuple(int(v) for v in np.round(sg[2:])),
            1,
            max(1, round(th) - 2),  # inside the raster wall: closes its gaps, does not fatten it
        )
    for dr in doors:  # one 8-connected pixel line separates 4-connected free space
        cv2.line(
            closed, tuple(int(v) for v in np.round(dr[:2])), tuple(int(v) for v in np.round(dr[2:])), 1, 1
        )
    n, lab, stats, _ = cv2.connectedComponentsWithStats((1 - closed).astype(np.uint8), connectivity=4)
    border = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])).tolist())
    rooms_px: list[Polygon] = []
    for c in range(1, n):
        if c in border or stats[c, cv2.CC_STAT_AREA] * sp * sp < cfg.min_room_area_m2:
            continue
        comp = lab[stats[c, 1] : stats[c, 1] + stats[c, 3], stats[c, 0] : stats[c, 0] + stats[c, 2]] == c
        cs, _ = cv2.findContours(comp.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cont = max(cs, key=cv2.contourArea)
        cont = cv2.approxPolyDP(cont, 1.0, True).reshape(-1, 2).astype(np.float64)
        if len(cont) < 3:
            continue
        # pixel centres -> pixel edges: the component's outline lies half a pixel outside its centres
        poly = Polygon(cont + np.array([stats[c, 0], stats[c, 1]])).buffer(0.5, join_style="mitre")
        if poly.is_valid and poly.area * sp * sp >= cfg.min_room_area_m2:
            rooms_px.append(poly)
    rooms_m: list[tuple[Polygon, str | None]] = []
    for poly in sorted(rooms_px, key=lambda p: -p.area):
        xy = _to_metres(np.asarray(poly.exterior.coords), f, s)
        pm = Polygon(xy)
        label = None
        for lname, (lx, ly) in (labels or {}).items():
            if pm.contains(shapely.Point(lx, ly)):
                label = lname
                break
        rooms_m.append((pm, label))
    timings["rooms_s"] = time.perf_counter() - t

    preview = _preview(walls_r, segs, thick, rooms_px, doors)
    timings["total_s"] = time.perf_counter() - t_start
    metrics = {
        "m_per_px": s,
        "working_m_per_px": sp,
        "downsample_factor": f,
        "ink_threshold": thr,
        "symbol_pixels": {k2: int(v.sum()) for k2, v in syms.items() if k2 not in pen},
        "pen_colours": pen,
        "wall_layers": wall_layers,
        "layer_evidence_m": {int(k2): round(v, 1) for k2, v in layer_evidence.items()},
        "text_components": len(text_px),
        "text_positions_m": _to_metres(np.asarray(text_px).reshape(-1, 2), f, s).tolist(),
        "hough_segments": len(raw),
        "walls": len(segs),
        "wall_length_m": float(lines.lengths(segs).sum() * sp) if len(segs) else 0.0,
        "wall_coverage": coverage,
        "rooms": len(rooms_m),
        "doors": len(doors),
        "windows": n_windows,
        "timings": timings,
    }
    return ParsedPlan(
        walls=_to_metres(segs, f, s).reshape(-1, 4),
        thickness_m=thick_faces * sp,
        rooms=rooms_m,
        doors=_to_metres(doors, f, s).reshape(-1, 4),
        preview=preview,
        metrics=metrics,
        m_per_px=s,
    )


def _preview(
    walls_r: NDArray, segs: NDArray, thick: NDArray, rooms_px: list[Polygon], doors: NDArray
) -> NDArray[np.uint8]:
    out = np.full((*walls_r.shape, 3), 255, np.uint8)
    palette = np.array(
        [
            [255, 224, 178],
            [200, 230, 201],
            [187, 222, 251],
            [248, 187, 208],
            [225, 190, 231],
            [255, 249, 196],
        ],
        np.uint8,
    )
    for n, poly in enumerate(rooms_px):
        pts = np.round(np.asarray(poly.exterior.coords)).astype(np.int32)
        cv2.fillPoly(out, [pts], tuple(int(v) for v in palette[n % len(palette)]))
    out[walls_r] = (120, 120, 120)
    lw = max(1, round(min(walls_r.shape) / 800))
    for sg in segs:
        cv2.line(
            out,
            tuple(int(v) for v in np.round(sg[:2])),
            tuple(int(v) for v in np.round(sg[2:])),
            (220, 0, 0),
            lw,
        )
    for dr in doors:
        cv2.line(
            out,
            tuple(int(v) for v in np.round(dr[:2])),
            tuple(int(v) for v in np.round(dr[2:])),
            (0, 160, 0),
            lw + 1,
        )
    return out


def rectangle_centrelines(rects: NDArray[np.float64]) -> NDArray[np.float64]:
    """Centrelines (K, 4) of wall rectangles given as (K, 4, 2) corners in order: the segment joining the
    midpoints of the two short sides (how CAD data such as MLSTRUCT-FP store walls)."""
    p = np.asarray(rects, dtype=np.float64).reshape(-1, 4, 2)
    e01 = np.hypot(*(p[:, 1] - p[:, 0]).T)
    e12 = np.hypot(*(p[:, 2] - p[:, 1]).T)
    long01 = (e01 >= e12)[:, None]
    a = np.where(long01, (p[:, 0] + p[:, 3]) / 2, (p[:, 0] + p[:, 1]) / 2)
    b = np.where(long01, (p[:, 1] + p[:, 2]) / 2, (p[:, 2] + p[:, 3]) / 2)
    return np.concatenate([a, b], axis=1)


def thickness_errors(
    pred: NDArray, pred_thickness: NDArray, truth: NDArray, truth_thickness: NDArray, tol_m: float = 0.10
) -> NDArray[np.float64]:
    """|thickness error| (m) of every truth wall against the predicted wall nearest to most of its
    samples within tol_m (walls (M, 4) / (K, 4) metres); truth walls without a match are left out."""
    pts, owner = lines.sample_segments(lines.as_segments(truth), 0.02)
    pred = lines.as_segments(pred)
    if len(pred) == 0 or len(pts) == 0:
        return np.zeros(0)
    d = lines.point_segment_distances(pts, pred)
    near, dmin = d.argmin(axis=1), d.min(axis=1)
    errs = []
    for k in range(len(truth)):
        m = (owner == k) & (dmin <= tol_m)
        if m.sum() < 3:
            continue
        j = np.bincount(near[m]).argmax()
        errs.append(abs(float(pred_thickness[j]) - float(truth_thickness[k])))
    return np.array(errs)


def load_plan_image(path: Path) -> NDArray[np.uint8]:
    """A plan image file as (H, W, 3) RGB uint8, transparent pixels composited on white paper."""
    path = Path(path)
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise ValueError(f"{path}: empty or not a readable image")
    if raw.dtype != np.uint8:
        raw = (raw / max(float(raw.max()), 1.0) * 255).astype(np.uint8)
    if raw.ndim == 2:
        return cv2.cvtColor(raw, cv2.COLOR_GRAY2RGB)
    if raw.shape[2] == 4:
        a3 = cv2.merge([raw[..., 3]] * 3)
        bgr = cv2.add(
            cv2.multiply(np.ascontiguousarray(raw[..., :3]), a3, scale=1 / 255), cv2.bitwise_not(a3)
        )
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return cv2.cvtColor(raw[..., :3], cv2.COLOR_BGR2RGB)


def run_parse_plan(image_path: Path, out_dir: Path, scale: PlanScale, cfg: PlanConfig | None = None) -> dict:
    """CLI-level: parse IMAGE and write plan_walls.parquet, rooms.geojson, plan_preview.png into out_dir.
    Returns the metrics (with the written paths)."""
    from tasks import artefacts

    cfg = cfg or PlanConfig()
    image_path, out_dir = Path(image_path), Path(out_dir)
    if not image_path.is_file():
        raise ValueError(f"{image_path}: no such image file")
    image = load_plan_image(image_path)
    res = parse_plan(image, scale, cfg, name=str(image_path))
    out_dir.mkdir(parents=True, exist_ok=True)
    walls_p = artefacts.write_table(
        out_dir / "plan_walls.parquet", artefacts.segments_table(res.walls, thickness_m=res.thickness_m)
    )
    features = [
        {
            "type": "Feature",
            "geometry": shapely.geometry.mapping(poly),
            "properties": {"room_id": f"R{n + 1}", "label": label, "area_m2": float(poly.area)},
        }
        for n, (poly, label) in enumerate(res.rooms)
    ]
    features += [
        {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [d[:2].tolist(), d[2:].tolist()]},
            "properties": {"kind": "door"},
        }
        for d in res.doors
    ]
    rooms_p = artefacts.write_geojson(out_dir / "rooms.geojson", features, crs_note="plan frame, metres")
    prev_p = artefacts.write_png(out_dir / "plan_preview.png", res.preview)
    return {**res.metrics, "outputs": {"walls": str(walls_p), "rooms": str(rooms_p), "preview": str(prev_p)}}
