"""Coarse floor-plan raster -> metric wall centrelines, thicknesses, rooms and doors (thesis 4.2.3).

The thesis (after Peter et al. 2010, 2013b) turns a photographed evacuation plan into a floor model:
white balance and Wallis filtering, perspective rectification from the building outline, removal of
symbols by colour segmentation, binarization, skeleton vectorization, bridging of the lines occluded by
symbols by prolonging free ends, and room polygons. The same steps serve CAD renderings (thin outline
walls are filled first). `parse_plan` runs them in order: the raster side in `tasks.plan.raster`, the
vectors in `tasks.plan.vectorize` (straight walls from the line code shared with the walls stage,
`tasks.lines`, never from a copy of it), doors in `tasks.plan.doors`, scale and rooms in
`tasks.plan.rooms`.

Plans drawn for people are never only walls. A photo of a posted sheet is rectified from the sheet's
border (or, when none shows, from the plan's two orthogonal directions) and its light evened out;
without a given scale, the printed scale bar is read (`tasks.plan.sheet`), else the dimension lines
(`tasks.plan.dimensions`). Architects' drawings draw the cut walls in a heavier pen than furniture, fixtures,
stairs and dimensions: when thin line work is present and the heavy strokes span the plan, only they are
walls (windows drawn thinly across their openings included), a door is a gap whose swing is drawn (a table
or a stub beside a wall leaves gaps too, and must not open or close a room), and a window or bay left as
a gap in an outer wall does not open its room to the outside. The plan region (the largest wall network)
is kept and recorded; legend panels, title blocks and scale bars beside it go. An image is refused only
when it is no plan: blank, mostly dark (a photo of a wall), without wall lines (a page of text), or
without a room enclosed.

Frames: the plan frame maps pixel (u, v) of the input image (after rectification, when four corners are
given) to metres (u * s, -v * s): x to the right, y up.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Polygon

from tasks import lines
from tasks.plan.config import PlanConfig, PlanScale
from tasks.plan.dimensions import read_dimension_scale
from tasks.plan.doors import doors_and_windows, wall_gaps
from tasks.plan.raster import clean_ink, enhance, min_pool, wall_raster
from tasks.plan.rooms import (
    free_space_rooms,
    outline_scale,
    plan_preview,
    rectify,
    rooms_in_metres,
    to_metres,
)
from tasks.plan.sheet import (
    direction_homography,
    find_sheet,
    read_scale_bar,
    residual_perspective,
    sheet_homography,
)
from tasks.plan.vectorize import hough_lines, vector_walls


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
    img, s, H_rect, scale_source, rectified = _scaled_image(_checked_image(image, name), scale, cfg, name)
    f = max(1, math.ceil(max(img.shape[:2]) / cfg.max_side_px))
    img = min_pool(img, f)
    sp = s * f  # metres per working pixel
    px = 1.0 / sp
    timings["load_s"] = time.perf_counter() - t_start

    t = time.perf_counter()
    found = clean_ink(img, px, cfg)
    timings["clean_s"] = time.perf_counter() - t
    dark_share = float(found.dark.mean())
    if dark_share > cfg.max_dark_share:
        raise ValueError(
            f"{name}: {dark_share:.0%} of the image is dark (a photo or a dark surface, not a line "
            "drawing), no floor plan in it"
        )

    t = time.perf_counter()
    raster = wall_raster(found, px, cfg)
    walls_r = raster.walls
    timings["binarize_s"] = time.perf_counter() - t
    ink_area = _check_wall_raster(walls_r, s, sp, cfg, name)

    t = time.perf_counter()
    # the second pass is taken in heavy-pen drawings only: on the survey generator's evacuation plans it
    # moves walls by millimetres and joins split pieces, which the fusion downstream was not checked on
    raw = hough_lines(walls_r, px, cfg, second_pass=raster.heavy_pen)
    timings["skeleton_s"] = time.perf_counter() - t

    t = time.perf_counter()
    segs, thick, thick_faces = vector_walls(
        raw,
        walls_r,
        raster.lines_f,
        found.symbols_any,
        px,
        cfg,
        raster.heavy_pen,
        outline_layers=bool(raster.layer_evidence) and not raster.heavy_pen,
    )
    timings["vectorize_s"] = time.perf_counter() - t
    coverage = _check_walls(segs, thick, walls_r, ink_area, sp, cfg, name)

    t = time.perf_counter()
    mask_f = walls_r.astype(np.float32)
    segs, thick, thick_faces, doors, n_windows = doors_and_windows(
        segs, thick, thick_faces, mask_f, found, px, cfg, raster.heavy_pen
    )
    gaps = None
    if raster.heavy_pen and cfg.seal_heavy_pen_outline:  # every door-wide gap, its swing drawn or not
        gaps = wall_gaps(segs, thick, mask_f, px, cfg)
    seal = round(cfg.door_min_m * px)
    # walls drawn by their faces' lines (the faces measured apart by less than the raster's width): the
    # lines' half width lies inside the room. Not from a stray wall or two (generator plan 3: one wall of
    # an evacuation plan's solid ones, 0.5 % of their length, took a room's IoU from 0.970 to 0.865)
    faced = thick_faces < thick - 1.0
    face_px = 0.0
    if (
        faced.any()
        and lines.lengths(segs)[faced].sum() >= cfg.face_lines_min_share * lines.lengths(segs).sum()
    ):
        face_px = float(np.median(thick[faced] - thick_faces[faced])) / 2
    rooms_px = free_space_rooms(walls_r, segs, thick, doors, sp, cfg, seal, found.dark, gaps, face_px)
    rooms_m = rooms_in_metres(rooms_px, f, s, labels)
    timings["rooms_s"] = time.perf_counter() - t
    if not rooms_m:
        raise ValueError(f"{name}: the straight walls enclose no room, no floor plan in it")

    preview = plan_preview(walls_r, segs, thick_faces, rooms_px, doors, sp, raster.region)
    timings["total_s"] = time.perf_counter() - t_start
    u0, v0, u1, v1 = raster.region
    metrics = {
        "m_per_px": s,
        "scale_source": scale_source,
        "rectification": H_rect.tolist(),
        "rectified_by": rectified,
        "plan_region_px": [u0 * f, v0 * f, u1 * f, v1 * f],
        "walls_heavy_pen": raster.heavy_pen,
        "face_line_half_width_m": face_px * sp,
        "dark_share": dark_share,
        "working_m_per_px": sp,
        "downsample_factor": f,
        "ink_threshold": found.threshold,
        "symbol_pixels": {k2: int(v.sum()) for k2, v in found.symbols.items() if k2 not in found.pen},
        "pen_colours": found.pen,
        "wall_layers": raster.wall_layers,
        "layer_evidence_m": {int(k2): round(v, 1) for k2, v in raster.layer_evidence.items()},
        "text_components": len(raster.text_px),
        "text_positions_m": to_metres(np.asarray(raster.text_px).reshape(-1, 2), f, s).tolist(),
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
        walls=to_metres(segs, f, s).reshape(-1, 4),
        thickness_m=thick_faces * sp,
        rooms=rooms_m,
        doors=to_metres(doors, f, s).reshape(-1, 4),
        preview=preview,
        metrics=metrics,
        m_per_px=s,
    )


def _checked_image(image: NDArray[np.uint8], name: str) -> NDArray[np.uint8]:
    """The image (H, W, 3) as an array, when it is an RGB picture with some contrast."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 16:
        raise ValueError(
            f"{name}: expected a non-empty (H, W, 3) uint8 RGB image, got {img.shape} {img.dtype}"
        )
    if int(img.max()) - int(img.min()) < 16:
        raise ValueError(f"{name}: the image is blank (no contrast), no floor plan in it")
    return img


def _scaled_image(
    img: NDArray[np.uint8], scale: PlanScale, cfg: PlanConfig, name: str
) -> tuple[NDArray[np.uint8], float, NDArray[np.float64], str, str | None]:
    """The image (rectified when four outline corners are given, or when no scale is given and a
    photographed sheet's border shows, or else its plan's two orthogonal directions show a perspective),
    its metres per pixel, the (3, 3) homography from input to rectified pixels, where the scale came
    from and what rectified it (None: nothing), checked to make the image a plausible size."""
    s_rect = None
    H = np.eye(3)
    rectified = None
    if scale.corners_px is not None:
        img, s_rect, H = rectify(img, np.asarray(scale.corners_px), scale.outline_size_m)
        rectified = "corners_px"
    elif scale.m_per_px is None and cfg.sheet_aspect > 0:
        corners = find_sheet(img, cfg.sheet_min_area_share)
        if corners is not None:  # a photo of the sheet: rectified to the sheet's side ratio
            H, size = sheet_homography(corners, cfg.sheet_aspect)
            warped = cv2.warpPerspective(img, H, size, flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255))
            # what perspective the border's corners left, from the plan's own lines (one warp in all)
            rest = residual_perspective(warped) if cfg.rectify_directions else None
            if rest is not None:
                H = rest @ H
                H /= H[2, 2]
                warped = cv2.warpPerspective(
                    img, H, size, flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255)
                )
            img = warped
            img = flat_field(img, cfg.flat_field_share)
            # the sheet's edge, a sliver of what is around it and the drawing's frame are no plan
            b = max(1, round(cfg.sheet_edge_share * min(img.shape[:2])))
            img[:b], img[-b:], img[:, :b], img[:, -b:] = 255, 255, 255, 255
            rectified = "sheet border"
        elif cfg.rectify_directions:
            found = direction_homography(img)
            if found is not None:  # a photo inside the sheet: from the plan's orthogonal directions
                H, size = found
                inside = np.full(img.shape[:2], 255, np.uint8)
                img = cv2.warpPerspective(img, H, size, flags=cv2.INTER_LINEAR, borderValue=(255, 255, 255))
                img = flat_field(img, cfg.flat_field_share)
                # the photo's edge and what it cut (a legend's frame) are no plan: a band inside it blanked
                inside = cv2.warpPerspective(inside, H, size, flags=cv2.INTER_NEAREST, borderValue=0)
                b = max(1, round(cfg.sheet_edge_share * min(img.shape[:2])))
                inside = cv2.erode(inside, np.ones((2 * b + 1, 2 * b + 1), np.uint8), borderValue=0)
                img[inside == 0] = 255
                rectified = "dominant directions"
    if s_rect is not None:
        s, source = s_rect, "outline_size_m"
    elif scale.m_per_px is not None:
        s, source = float(scale.m_per_px), "m_per_px"
    elif scale.known_distance is not None:
        x0, y0, x1, y1, d = scale.known_distance
        p = np.array([[x0, y0, 1.0], [x1, y1, 1.0]]) @ H.T
        p = p[:, :2] / p[:, 2:]
        s, source = float(d) / float(np.hypot(*(p[1] - p[0]))), "known_distance"
    elif scale.outline_length_m is not None:
        s, source = outline_scale(img, float(scale.outline_length_m), cfg), "outline_length_m"
    else:
        enhanced = enhance(img, max(img.shape[:2]) // 4, cfg)
        darkness = (255 - enhanced.min(axis=2)).astype(np.uint8)
        _thr, dark = cv2.threshold(darkness, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        bar = read_scale_bar(enhanced, dark > 0)
        dims = None if bar is not None else read_dimension_scale(cv2.cvtColor(enhanced, cv2.COLOR_RGB2GRAY))
        if bar is not None:
            s, source = bar[0], "scale bar"
        elif dims is not None:
            s, source = dims[0], "dimension line"
        else:
            raise ValueError(
                f"{name}: no scale given (m_per_px, known_distance or outline_length_m) and no printed "
                "scale bar or dimension line read in the image"
            )
    extent_m = max(img.shape[:2]) * s
    if not cfg.min_extent_m <= extent_m <= cfg.max_extent_m * 1.5:
        raise ValueError(
            f"{name}: scale {s:.4g} m/px makes the image {extent_m:.3g} m across, outside the plausible "
            f"{cfg.min_extent_m:g}-{cfg.max_extent_m:g} m (wrong units?)"
        )
    return img, s, H, source, rectified


def flat_field(img: NDArray[np.uint8], share: float) -> NDArray[np.uint8]:
    """A photo's uneven light (shade, glare) divided out: every channel over its paper level, the
    brightest value within a window `share` of the image's short side (wider than any stroke), smoothed."""
    k = max(3, round(share * min(img.shape[:2])) | 1)
    paper = cv2.dilate(img, np.ones((k, k), np.uint8))
    paper = cv2.GaussianBlur(paper, (0, 0), k / 2).astype(np.float32)
    return np.clip(img.astype(np.float32) / np.maximum(paper, 1.0) * 255.0, 0, 255).astype(np.uint8)


def _check_wall_raster(walls_r: NDArray[np.bool_], s: float, sp: float, cfg: PlanConfig, name: str) -> int:
    """The wall raster's (h, w) pixel count, when it holds walls spanning a plausible extent."""
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
    return ink_area


def _check_walls(
    segs: NDArray[np.float64],
    thick: NDArray[np.float64],
    walls_r: NDArray[np.bool_],
    ink_area: int,
    sp: float,
    cfg: PlanConfig,
    name: str,
) -> float:
    """The share of the wall raster (h, w) that the straight walls (M, 4) explain (a figure, not a test:
    a plan drawn for people is never only walls), when they are enough walls, long enough to be a floor
    plan."""
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
    return coverage
