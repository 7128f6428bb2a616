"""The wall model of one room (`model_walls`): the steps of tasks.walls run for every candidate α, the
chosen model refined on the points, oriented, extruded from floor to ceiling (thesis 5.2.6) and drawn."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.cloud import DegenerateInputError
from tasks.connect import EXTENDED, OBSERVED
from tasks.lines import angles, is_closed, lengths, transform_segments, wall_graph
from tasks.preview import Key, View, frame_picture
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import backed_bridges, support_sampler
from tasks.walls.image import Grid, coarse_projection, projection_image
from tasks.walls.round import round_objects
from tasks.walls.topology import choose_alpha, model_for, with_corners


@dataclass(frozen=True)
class WallModel:
    """A room's walls in the x-y frame of the levelled cloud (metres), extruded from floor to ceiling."""

    walls: NDArray[np.float64]
    """(M, 4) x0 y0 x1 y1 of the inner wall faces."""
    origin: NDArray[np.str_]
    """(M,) "observed" or "extended" (made only by extension, e.g. a perpendicular join)."""
    support: NDArray[np.float64]
    """(M,) share of each wall's length backed by data (0..1)."""
    floor_z_m: float
    ceiling_z_m: float
    polygon: Any
    """shapely Polygon of the room when the walls enclose one, else None."""
    mesh_vertices: NDArray[np.float64]
    """(V, 3) extruded walls (and floor and ceiling when closed)."""
    mesh_triangles: NDArray[np.int64]
    """(T, 3) vertex indices, counter-clockwise seen from inside the room."""
    preview: NDArray[np.uint8]
    """(H, W, 3) RGB: the projection image with the walls drawn over it, north up."""
    alpha: float | None
    """α used for eq 5.5 (None with eq 5.4)."""
    metrics: dict[str, Any]
    """Counts per step, α choice and reason, timings (s), warnings."""

    @property
    def height_m(self) -> float:
        return self.ceiling_z_m - self.floor_z_m

    @property
    def closed(self) -> bool:
        return self.polygon is not None

    def transformed(self, rotation_rad: float, translation_xy: NDArray) -> WallModel:
        """The model moved by the 2D rigid transform p -> R(rotation) p + t (z unchanged)."""
        import shapely.affinity

        c, s = math.cos(rotation_rad), math.sin(rotation_rad)
        r = np.array([[c, -s], [s, c]])
        t = np.asarray(translation_xy, dtype=np.float64).reshape(2)
        verts = self.mesh_vertices.copy()
        verts[:, :2] = verts[:, :2] @ r.T + t
        poly = None
        if self.polygon is not None:
            poly = shapely.affinity.affine_transform(self.polygon, [c, -s, s, c, t[0], t[1]])
        return replace(self, walls=transform_segments(self.walls, r, t), polygon=poly, mesh_vertices=verts)


def extrude(walls: NDArray, floor_z: float, ceiling_z: float, polygon: Any) -> tuple[NDArray, NDArray]:
    """Wall quads from floor to ceiling (two triangles each), plus floor and ceiling caps when the room
    is closed. Walls must have the room on their left (`orient_walls`); every triangle then faces into
    the room (counter-clockwise seen from inside). Returns vertices (V, 3) and triangles (T, 3)."""
    m = len(walls)
    verts = np.zeros((4 * m, 3))
    verts[0::4, :2], verts[0::4, 2] = walls[:, :2], floor_z
    verts[1::4, :2], verts[1::4, 2] = walls[:, 2:], floor_z
    verts[2::4, :2], verts[2::4, 2] = walls[:, 2:], ceiling_z
    verts[3::4, :2], verts[3::4, 2] = walls[:, :2], ceiling_z
    base = 4 * np.arange(m)[:, None]
    tris = np.concatenate([base + np.array([0, 2, 1]), base + np.array([0, 3, 2])]).astype(np.int64)
    if polygon is not None:
        import shapely

        cap = shapely.constrained_delaunay_triangles(polygon)
        tri_xy = [np.asarray(t.exterior.coords)[:3] for t in shapely.get_parts(cap)]
        if tri_xy:
            txy = np.array(tri_xy)  # (T, 3, 2)
            # counter-clockwise seen from above for the floor (normal up, into the room), reversed above
            area = (txy[:, 1, 0] - txy[:, 0, 0]) * (txy[:, 2, 1] - txy[:, 0, 1]) - (
                txy[:, 2, 0] - txy[:, 0, 0]
            ) * (txy[:, 1, 1] - txy[:, 0, 1])
            txy[area < 0] = txy[area < 0][:, ::-1]
            k = len(txy)
            floor = np.concatenate([txy.reshape(-1, 2), np.full((3 * k, 1), floor_z)], axis=1)
            ceil = np.concatenate([txy.reshape(-1, 2), np.full((3 * k, 1), ceiling_z)], axis=1)
            n0 = len(verts)
            verts = np.concatenate([verts, floor, ceil])
            ft = n0 + np.arange(3 * k).reshape(k, 3)
            ct = (n0 + 3 * k + np.arange(3 * k).reshape(k, 3))[:, ::-1]
            tris = np.concatenate([tris, ft, ct])
    return verts, tris


def orient_walls(walls: NDArray, polygon: Any) -> NDArray:
    """Walls turned so that the room lies on their left (counter-clockwise round the room): judged by the
    room polygon when there is one, else by the side of the walls' length-weighted centre."""
    if len(walls) == 0:
        return walls.copy()
    d = walls[:, 2:] - walls[:, :2]
    L = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)
    left = np.column_stack([-d[:, 1], d[:, 0]]) / L[:, None]
    mid = 0.5 * (walls[:, :2] + walls[:, 2:])
    if polygon is not None:
        import shapely

        probe = mid + left * np.minimum(0.01, 0.1 * L)[:, None]
        inside = shapely.contains_xy(polygon, probe[:, 0], probe[:, 1])
    else:
        centre = (mid * L[:, None]).sum(axis=0) / L.sum()
        inside = ((centre - mid) * left).sum(axis=1) >= 0
    out = walls.copy()
    out[~inside] = walls[~inside][:, [2, 3, 0, 1]]
    return out


def render_preview(
    counts: NDArray,
    binary: NDArray,
    walls: NDArray,
    origin: NDArray,
    grid: Grid,
    min_side_px: int = 800,
    title: str = "walls",
) -> NDArray:
    """RGB picture, north up: data in grey (darker = taller column), the cells kept as wall data in light
    blue, observed walls in dark blue, extended ones in orange, wall ends as red dots; framed with `title`,
    axes in metres of the levelled room frame, a legend of those colours, a north arrow and a 1 m bar
    (tasks.preview). Coarse grids are enlarged (whole pixels) so that the longer side has at least
    `min_side_px`."""
    n_max = max(float(counts.max()), 1.0)
    grey = (255 - 140 * np.sqrt(counts / n_max)).astype(np.uint8)
    img = np.repeat(grey[..., None], 3, axis=2)
    img[binary] = WALL_CELLS
    scale = int(min(10, max(1, math.ceil(min_side_px / max(counts.shape)))))
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = np.ascontiguousarray(img[::-1])  # north up: row 0 is the largest y
    h = img.shape[0]
    shift = 4  # sub-pixel drawing
    thick = 3

    def at(p: NDArray) -> tuple[int, int]:
        col, row = (p[0] + 0.5) * scale - 0.5, h - 1 - ((p[1] + 0.5) * scale - 0.5)
        return round(col * (1 << shift)), round(row * (1 << shift))

    px = grid.to_pixels(walls.reshape(-1, 2)).reshape(-1, 4) if len(walls) else np.zeros((0, 4))
    for s, o in zip(px, origin, strict=True):
        colour = OBSERVED_WALL if o == OBSERVED else EXTENDED_WALL
        cv2.line(img, at(s[:2]), at(s[2:]), colour, thick, cv2.LINE_AA, shift)
    for s in px:
        for p in (s[:2], s[2:]):
            cv2.circle(img, at(p), 5 << shift, WALL_END, -1, cv2.LINE_AA, shift)
    legend = [Key("points (darker: taller)", (145, 145, 145), "box")]
    if binary.any():
        legend.append(Key("wall cells", WALL_CELLS, "box"))
    if any(o == OBSERVED for o in origin):
        legend.append(Key("observed wall", OBSERVED_WALL))
    if any(o != OBSERVED for o in origin):
        legend.append(Key("extended wall", EXTENDED_WALL))
    if len(px):
        legend.append(Key("wall end", WALL_END, "dot"))
    view = View(float(grid.origin[0]), float(grid.origin[1] + counts.shape[0] * grid.size), grid.size / scale)
    return frame_picture(img, view, title, legend, "metres, levelled room frame")


WALL_CELLS, OBSERVED_WALL, EXTENDED_WALL, WALL_END = (
    (150, 190, 235),
    (25, 60, 170),
    (240, 140, 20),
    (210, 30, 30),
)
"""The preview's colours (RGB)."""


def _check_input(slice_points: NDArray, floor_z_m: float, ceiling_z_m: float, cfg: WallsConfig) -> NDArray:
    pts = np.asarray(slice_points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DegenerateInputError(f"slice points must be (N, 3), got {pts.shape}")
    if not np.isfinite(pts).all():
        raise DegenerateInputError(
            f"{int((~np.isfinite(pts).all(axis=1)).sum())} slice points are NaN or infinite"
        )
    if len(pts) < cfg.min_points:
        raise DegenerateInputError(f"slice has {len(pts)} points, at least {cfg.min_points} needed for walls")
    if not (math.isfinite(floor_z_m) and math.isfinite(ceiling_z_m) and ceiling_z_m > floor_z_m):
        raise DegenerateInputError(f"floor {floor_z_m} m and ceiling {ceiling_z_m} m do not bound a room")
    spread = float(np.quantile(pts[:, 2], 0.99) - np.quantile(pts[:, 2], 0.01))
    if spread < cfg.min_slice_height_m:
        raise DegenerateInputError(
            f"slice is {spread:.3f} m thick (a single horizontal plane?), at least {cfg.min_slice_height_m} m needed"
        )
    return pts


def point_spacing(points: NDArray, k: int = 6, max_points: int = 20000) -> float:
    """The points' spacing on their surfaces, 1 / sqrt(points per m²): from the median distance d_k to
    the k-th nearest neighbour (3D), as k points lie within pi d_k² of a surface, s = d_k sqrt(pi / k).
    A regular grid of spacing s and random points of that density give about s alike (the nearest
    neighbour alone would halve the random ones). Measured on at most `max_points` points taken evenly."""
    from scipy.spatial import cKDTree

    step = max(1, len(points) // max_points)
    # an unbalanced tree without node compaction, of leaves of 64 points, builds in half the time (for the few
    # queries made of it, a fifth less build and query than leaves of 16); the neighbours and their
    # distances are the same
    tree = cKDTree(points, leafsize=64, balanced_tree=False, compact_nodes=False)
    # the sample (every step-th point) queried in the tree's leaf order, so that consecutive queries walk
    # the same nodes: only the median of the distances is kept, whatever their order
    taken = np.zeros(len(points), dtype=bool)
    taken[::step] = True
    sample = points[tree.indices[taken[tree.indices]]]
    d, _ = tree.query(sample, k=k + 1)
    return float(np.median(d[:, k]) * math.sqrt(math.pi / k))


def grid_from_data(pts: NDArray, cfg: WallsConfig) -> tuple[WallsConfig, dict[str, Any]]:
    """The grid from the cloud (table 6.3): `grid_spacing_ratio` times the point spacing, at least
    `grid_size_m`, rounded to the millimetre; the lengths read in pixels of it follow (a line's end
    tolerance is at least a cell). Returns (config with that grid, the choice for the metrics)."""
    spacing = point_spacing(pts)
    grid = max(cfg.grid_size_m, round(cfg.grid_spacing_ratio * spacing, 3))
    if grid > cfg.grid_size_m:
        reason = (
            f"{cfg.grid_spacing_ratio} x point spacing {spacing:.4f} m (above grid_size_m {cfg.grid_size_m})"
        )
        cfg = replace(cfg, grid_size_m=grid, end_tol_m=max(cfg.end_tol_m, grid))
    else:
        reason = f"grid_size_m (point spacing {spacing:.4f} m x {cfg.grid_spacing_ratio} is finer)"
    return cfg, {"point_spacing_m": spacing, "grid_size_m": grid, "grid_reason": reason}


def model_walls(slice_points: NDArray, floor_z_m: float, ceiling_z_m: float, cfg: WallsConfig) -> WallModel:
    """The wall model of one room from the furniture slice (N, 3) of its levelled cloud (z up, metres).

    Raises DegenerateInputError (one line) for an input that cannot hold walls: too few points, NaN, a
    flat slice, an extent too large for the grid. A slice in which no wall is found gives an empty model
    with a warning in `metrics["warnings"]`."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pts = _check_input(slice_points, floor_z_m, ceiling_z_m, cfg)
    cfg, grid_choice = grid_from_data(pts, cfg)
    # a plant's pot, a bin: no wall, and its facets drawn as lines would make stubs and false corners
    t_round = time.perf_counter()
    on_round, round_things = round_objects(pts[:, :2], cfg.grid_size_m, cfg)
    if on_round.any() and (~on_round).sum() >= cfg.min_points:
        pts = pts[~on_round]
    else:
        on_round, round_things = np.zeros(len(pts), dtype=bool), []
    timings["round_objects_s"] = time.perf_counter() - t_round
    proj = projection_image(pts, cfg, ceiling_z_m)
    coarse = coarse_projection(pts, proj, cfg, ceiling_z_m)
    grid, counts = proj.grid, proj.counts
    xy = np.ascontiguousarray(pts[:, :2])
    # the input checks, the grid and the projection; the round things are timed on their own
    timings["projection_s"] = time.perf_counter() - t0 - timings["round_objects_s"]

    t1 = time.perf_counter()
    if cfg.binarization == "gaussian":
        alphas: list[float | None] = [None]
    elif cfg.alpha is not None:
        alphas = [float(cfg.alpha)]
    else:
        alphas = sorted(float(a) for a in cfg.alpha_candidates)
    if len(alphas) == 1:
        cands = [model_for(proj, cfg, alphas[0], xy, coarse)]
        chosen, reason = 0, ("eq 5.4 (mean - 1.65 sigma)" if alphas[0] is None else "alpha fixed in config")
        best = cands[0]
    else:
        # candidates are compared on the pixel-accurate model; the chosen one is refined on the points
        cands = [model_for(proj, cfg, a) for a in alphas]
        wider = None
        if coarse is not None and not any(c.closed for c in cands):
            # no α closes the room on the fine grid: its sparsely seen stretches are looked for on the coarse
            # one (a room some α closes keeps its model, whatever the coarse grid would add to the others),
            # and kept only when they close it
            wider = [model_for(proj, cfg, a, coarse=coarse) for a in alphas]
        if wider is not None and any(c.closed for c in wider):
            cands = wider
        else:
            coarse = None
        corners = None
        if not any(c.closed for c in cands):
            # nor on the coarse one: the corners that one wall's data pin are closed along the other's line
            pinned = [with_corners(c, xy, cfg) for c in cands]
            if any(c.closed for c in pinned):
                cands, corners = pinned, xy
        chosen, reason = choose_alpha(cands, cfg.stable_tol_m, cfg.thin_wall_max_m, xy)
        if corners is not None:
            how = cands[chosen].counts.get("corners_closed")
            reason += (
                "; unseen spans closed along the seen walls' lines"
                if how == "across unseen spans"
                else "; a corner pinned by one wall's data closed along the other's line"
            )
        best = model_for(proj, cfg, alphas[chosen], xy, coarse, corners)
        if cands[chosen].closed and not best.closed and corners is None:
            # the refinement moved a borderline corner out of reach (a sparse stretch the pixel model bridged):
            # the refined walls closed at the corners their data pin, or across unseen spans, before the
            # pixel-accurate model, whose pieces each sit on their own cells (jogs of a cell or two); the
            # open refined model is the one `model_for` with `corners` would close, so it is not made again
            again = with_corners(best, xy, cfg)
            if again.closed:
                best = again
                reason += "; the refined walls closed at their corners (`close_at_corners`)"
        if cands[chosen].closed and not best.closed:
            # still open: keep the pixel-accurate model
            best = cands[chosen]
            reason += "; offsets not refined (the refined walls did not close)"
    timings["walls_s"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    walls, origin = best.walls, best.origin
    bridges = np.zeros((0, 4))
    if best.polygon is None and len(walls):
        # the room stays open: collinear gaps the slice data back are modelled all the same
        bridges = backed_bridges(walls, origin, xy, cfg)
        if len(bridges):
            walls = np.concatenate([walls, bridges])
            origin = np.concatenate([origin, np.full(len(bridges), EXTENDED)])
    # a join between two walls' coincident ends (no length: under 1 mm) is no wall
    real = lengths(walls) >= 1e-3
    walls, origin = walls[real], origin[real]
    share = support_sampler(best.binary, grid, cfg.support_tol_m)
    support = share(walls)
    polygon = best.polygon
    walls = orient_walls(walls, polygon)
    verts, tris = extrude(walls, floor_z_m, ceiling_z_m, polygon)
    preview = render_preview(counts, best.binary, walls, origin, grid)
    timings["outputs_s"] = time.perf_counter() - t2
    timings["total_s"] = time.perf_counter() - t0

    warnings = []
    if len(walls) == 0:
        warnings.append("no wall found in the slice")
    elif polygon is None:
        warnings.append("the walls do not enclose a room (open wall graph)")
    elif not is_closed(wall_graph(walls)):
        warnings.append("the walls enclose a room but some walls have free ends")
    metrics: dict[str, Any] = {
        "points": len(pts),
        **grid_choice,
        "round_objects": round_things,
        "round_object_points": int(on_round.sum()),
        "image_shape": list(counts.shape),
        "slice_voxel_layers": proj.n_levels,
        "alpha": best.alpha,
        "alpha_reason": reason,
        "alpha_candidates": [{"alpha": c.alpha, "closed": c.closed, **c.counts} for c in cands],
        **best.counts,
        "walls_observed": int((origin == OBSERVED).sum()),
        "walls_extended": int((origin != OBSERVED).sum()),
        "bridged_backed_m": [round(float(x), 3) for x in lengths(bridges)],
        "closed": polygon is not None,
        "room_area_m2": float(polygon.area) if polygon is not None else None,
        "orientations_deg": sorted({round(float(a), 2) for a in np.degrees(angles(walls))})
        if len(walls)
        else [],
        "timings": timings,
        "warnings": warnings,
    }
    return WallModel(
        walls=walls,
        origin=origin,
        support=support,
        floor_z_m=float(floor_z_m),
        ceiling_z_m=float(ceiling_z_m),
        polygon=polygon,
        mesh_vertices=verts,
        mesh_triangles=tris,
        preview=preview,
        alpha=best.alpha,
        metrics=metrics,
    )
