"""A seeded synthetic floor: a hallway and five rooms of different shapes, as built and as planned.

Layout (the structure is fixed, every dimension varies with the seed)::

        +--------+-----------/            north row: 101 rectangular (with an added partition stub),
        |  101   |   102    /             102 with a non-Manhattan (about 70 deg) exterior wall
        |        |         /
        +--D-----+---D----/----------+
        |  hallway (100)             |    the corridor, poorly textured (the SfM failure case)
        +--D---+-D-+----D-----+--D---+
        |  103   |WC|  104    |  105 |    south row: 103 L-shaped around a WC, 104 with an alcove,
        |        +--+         |      |    105 rectangular (the TLS-scanned room)
        +--------------+  +---+------+
                       +--+  alcove

Walls are modelled as centreline segments with a thickness; the free space of a room is its centreline
polygon minus every wall's rectangle, and the solid is the building footprint minus all free spaces, so
the mesh's inner faces and the truth walls come from the same polygons. The plan (as planned) differs
from the building in three recorded ways: a partition stub added in 101, a stub removed in 104, and the
door of 102 moved along the corridor wall.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.polygon import orient

from tasks.synth.scene import Material, SceneMesh


@dataclass(frozen=True)
class BuildingConfig:
    """Dimensions and ranges of the synthetic floor (each seed draws its own values inside them)."""

    slant_angle_deg: float = 70.0
    """Angle between the corridor and the non-Manhattan wall of room 102."""
    exterior_thickness_m: tuple[float, float] = (0.25, 0.30)
    """Range of the exterior wall thickness (one value per building)."""
    interior_thickness_m: tuple[float, float] = (0.10, 0.20)
    """Range of each interior wall's thickness."""
    partition_thickness_m: float = 0.10
    """Thickness of the partition stubs (the added and the removed one)."""
    room_height_m: tuple[float, float] = (2.5, 3.2)
    """Range of the per-room floor-to-ceiling height."""
    door_width_m: float = 0.9
    """Clear width of a room door."""
    door_height_m: float = 2.05
    """Height of every door opening."""
    window_sill_m: tuple[float, float] = (0.85, 0.95)
    """Range of the window sill height."""
    window_top_m: tuple[float, float] = (2.10, 2.25)
    """Range of the window head height."""
    door_move_min_m: float = 1.3
    """Least distance between the planned and the built door of room 102."""
    margin_m: float = 1.5
    """Free border between the building and the plan image edge (plan frame placement)."""


@dataclass(frozen=True)
class WallSegment:
    """A wall centreline in the plan frame (metres) with its thickness."""

    x0: float
    y0: float
    x1: float
    y1: float
    thickness_m: float
    exterior: bool
    kind: str = "wall"
    """"wall" | "partition" (the change stubs)."""

    @property
    def line(self) -> LineString:
        return LineString([(self.x0, self.y0), (self.x1, self.y1)])

    @property
    def length_m(self) -> float:
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)


@dataclass(frozen=True)
class Opening:
    """A door or window: its extent along a wall centreline (plan frame) and its vertical extent."""

    kind: str
    """"door" | "window"."""
    x0: float
    y0: float
    x1: float
    y1: float
    z0_m: float
    z1_m: float
    thickness_m: float
    """Thickness of the wall it pierces."""
    room_ids: tuple[str, ...]
    """Spaces it connects (a window: the one room)."""

    @property
    def centre(self) -> tuple[float, float]:
        return (0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1))

    @property
    def width_m(self) -> float:
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)


@dataclass(frozen=True)
class Change:
    """A difference between the building and its plan (plan frame segment)."""

    x0: float
    y0: float
    x1: float
    y1: float
    kind: str
    """"added" (in the building, not in the plan) | "removed" (in the plan, not in the building)."""
    room_id: str
    what: str
    """"partition_added" | "wall_removed" | "door_moved"."""


@dataclass(frozen=True)
class RoomSpec:
    """One space of the floor."""

    id: str
    """Survey room id ("r1", "hall", ...)."""
    label: str
    """Label on the plan ("101")."""
    shape: str
    """"rectangular" | "slanted" | "l_shaped" | "alcove" | "corridor" | "storage"."""
    capture: str
    """"rgbd" | "tls" | "hallway" | "none" (not surveyed)."""
    polygon: Polygon
    """Free space bounded by the inner wall faces, as built (plan frame, metres)."""
    free_space: Polygon
    """Part of ``polygon`` where a hand-held camera can go: furniture taller than 1 m (cabinets, shelves,
    plants, the TV), grown by 0.3 m, removed (plan frame, metres)."""
    height_m: float
    """Floor-to-ceiling height."""
    door: Opening | None
    """Its door to the corridor, as built (None for the corridor itself)."""
    cell: Polygon
    """Centreline polygon (the plan's room outline), as built."""


@dataclass(frozen=True)
class Furniture:
    """A piece of furniture, for the record and for placing the walk (plan frame)."""

    kind: str
    """"table" | "chair" | "cabinet" | "shelf" | "plant" | "lamp" | "tv" | "extinguisher" | "poster"."""
    room_id: str
    footprint: Polygon
    z0_m: float
    z1_m: float


@dataclass(frozen=True)
class Building:
    """A synthetic floor with its as-built geometry, its as-planned drawing and the differences."""

    seed: int
    mesh: SceneMesh
    rooms: tuple[RoomSpec, ...]
    truth_walls: tuple[tuple[float, float, float, float, str], ...]
    """Inner wall faces (x0, y0, x1, y1, room_id) of every surveyed room, as built (plan frame)."""
    built_walls: tuple[WallSegment, ...]
    """As-built centrelines with thickness."""
    planned_walls: tuple[WallSegment, ...]
    """What the plan draws."""
    built_openings: tuple[Opening, ...]
    planned_openings: tuple[Opening, ...]
    changes: tuple[Change, ...]
    furniture: tuple[Furniture, ...]
    you_are_here: tuple[float, float]
    """Where the plan hangs in the corridor (plan frame), the start of the IMU track."""
    extinguishers: tuple[tuple[float, float], ...]
    """Fire-equipment positions (plan frame), drawn as red symbols on the plan."""
    exit_xy: tuple[float, float]
    """The corridor end the escape-route arrows point to."""
    extent: tuple[float, float, float, float]
    """Plan image extent (xmin, ymin, xmax, ymax) in the plan frame: the image origin is (xmin, ymax) = (0, 0)."""
    footprint: Polygon = field(repr=False)
    """Outer outline of the building (as built)."""

    def room(self, room_id: str) -> RoomSpec:
        for r in self.rooms:
            if r.id == room_id:
                return r
        raise KeyError(f"no room {room_id!r} in the building")

    @property
    def room_polygons(self) -> dict[str, Polygon]:
        return {r.id: r.polygon for r in self.rooms}


class _MeshBuilder:
    """Collects triangles with one material each."""

    def __init__(self) -> None:
        self.vertices: list[tuple[float, float, float]] = []
        self.triangles: list[tuple[int, int, int]] = []
        self.material: list[int] = []
        self.materials: list[Material] = []

    def add_material(self, mat: Material) -> int:
        self.materials.append(mat)
        return len(self.materials) - 1

    def tri(self, a, b, c, mat: int) -> None:
        n = len(self.vertices)
        self.vertices.extend([tuple(map(float, a)), tuple(map(float, b)), tuple(map(float, c))])
        self.triangles.append((n, n + 1, n + 2))
        self.material.append(mat)

    def quad(self, a, b, c, d, mat: int) -> None:
        self.tri(a, b, c, mat)
        self.tri(a, c, d, mat)

    def vertical(self, p, q, z0: float, z1: float, mat: int) -> None:
        """A vertical rectangle over the segment p -> q; its normal is the left side of p -> q."""
        if z1 - z0 <= 1e-6:
            return
        self.quad((p[0], p[1], z0), (q[0], q[1], z0), (q[0], q[1], z1), (p[0], p[1], z1), mat)

    def horizontal(self, poly: Polygon, z: float, mat: int) -> None:
        for t in shapely.constrained_delaunay_triangles(poly).geoms:
            c = np.asarray(t.exterior.coords)[:3]
            self.tri((*c[0], z), (*c[1], z), (*c[2], z), mat)

    def box(self, cx: float, cy: float, z0: float, sx: float, sy: float, sz: float, yaw: float, mats) -> None:
        """An oriented box; ``mats`` is one material index or a callable(face_name, origin, u, v) -> index."""
        c, s = math.cos(yaw), math.sin(yaw)
        ex, ey = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
        ez = np.array([0.0, 0.0, 1.0])
        o = np.array([cx, cy, z0]) - ex * sx / 2 - ey * sy / 2
        p = [o + ex * sx * i + ey * sy * j + ez * sz * k for k in (0, 1) for j in (0, 1) for i in (0, 1)]
        faces = {
            "bottom": (0, 2, 3, 1, ex, ey),
            "top": (4, 5, 7, 6, ex, ey),
            "front": (0, 1, 5, 4, ex, ez),
            "back": (3, 2, 6, 7, -ex, ez),
            "left": (2, 0, 4, 6, -ey, ez),
            "right": (1, 3, 7, 5, ey, ez),
        }
        for name, (a, b, cc, d, u, v) in faces.items():
            mat = mats(name, p[a], u, v) if callable(mats) else mats
            self.quad(p[a], p[b], p[cc], p[d], mat)

    def cylinder(self, cx: float, cy: float, z0: float, z1: float, r: float, mat: int, n: int = 16) -> None:
        ang = np.linspace(0.0, 2 * math.pi, n + 1)
        ring = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in ang]
        for i in range(n):
            self.vertical(ring[i], ring[i + 1], z0, z1, mat)
            self.tri((cx, cy, z1), (*ring[i], z1), (*ring[i + 1], z1), mat)
            self.tri((cx, cy, z0), (*ring[i + 1], z0), (*ring[i], z0), mat)

    def mesh(self) -> SceneMesh:
        return SceneMesh(
            vertices=np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3),
            triangles=np.asarray(self.triangles, dtype=np.int32).reshape(-1, 3),
            material=np.asarray(self.material, dtype=np.int32),
            materials=tuple(self.materials),
        )


def _u(rng: np.random.Generator, lo_hi: tuple[float, float], nd: int = 2) -> float:
    return round(float(rng.uniform(*lo_hi)), nd)


def _noded_walls(cells: dict[str, Polygon]) -> list[tuple[tuple[float, float], tuple[float, float], bool]]:
    """Elementary centreline segments of all cell outlines, merged along lines: (p, q, exterior)."""
    verts = {tuple(np.round(c, 9)) for poly in cells.values() for c in poly.exterior.coords}
    pieces: dict[tuple, int] = {}
    for poly in cells.values():
        coords = list(poly.exterior.coords)
        for a, b in itertools.pairwise(coords):
            a, b = np.asarray(a), np.asarray(b)
            d = b - a
            length = float(np.hypot(*d))
            ts = [0.0, 1.0]
            for v in verts:
                w = np.asarray(v) - a
                t = float(w @ d) / length**2
                if 1e-9 < t < 1 - 1e-9 and abs(d[0] * w[1] - d[1] * w[0]) / length < 1e-7:
                    ts.append(t)
            ts.sort()
            for t0, t1 in itertools.pairwise(ts):
                p = tuple(np.round(a + t0 * d, 9))
                q = tuple(np.round(a + t1 * d, 9))
                key = (min(p, q), max(p, q))
                pieces[key] = pieces.get(key, 0) + 1
    # merge collinear touching pieces with the same exterior flag
    groups: dict[tuple, list] = {}
    for (p, q), count in sorted(pieces.items()):
        d = np.subtract(q, p)
        ang = math.atan2(d[1], d[0]) % math.pi
        n = np.array([-math.sin(ang), math.cos(ang)])
        off = float(n @ np.asarray(p))
        groups.setdefault((round(ang, 6), round(off, 6), count == 1), []).append((p, q, ang))
    merged = []
    for (ang, _, exterior), segs in sorted(groups.items()):
        u = np.array([math.cos(ang), math.sin(ang)])
        spans = sorted(
            (min(u @ np.asarray(p), u @ np.asarray(q)), max(u @ np.asarray(p), u @ np.asarray(q)), p, q)
            for p, q, _ in segs
        )
        cur = None
        for s0, s1, p, q in spans:
            a, b = (p, q) if u @ np.asarray(p) <= u @ np.asarray(q) else (q, p)
            if cur is not None and abs(s0 - cur[1]) < 1e-7:
                cur = (cur[0], s1, cur[2], b)
            else:
                if cur is not None:
                    merged.append((cur[2], cur[3], exterior))
                cur = (s0, s1, a, b)
        merged.append((cur[2], cur[3], exterior))
    return merged


def _corner_patches(walls: list[WallSegment]) -> list[Polygon]:
    """Where exactly two walls end at an angle, their flat-capped rectangles leave the outer corner open:
    the patch is the overlap of the two walls' infinite strips (a parallelogram at the corner)."""
    ends: dict[tuple[float, float], list[WallSegment]] = {}
    for w in walls:
        for p in ((w.x0, w.y0), (w.x1, w.y1)):
            ends.setdefault((round(p[0], 6), round(p[1], 6)), []).append(w)
    patches = []
    for p, ws in sorted(ends.items()):
        if len(ws) != 2 or any(w.line.distance(Point(p)) < 1e-6 for w in walls if w not in ws):
            continue
        strips = []
        for w in ws:
            d = np.array([w.x1 - w.x0, w.y1 - w.y0]) / w.length_m
            line = LineString([np.asarray(p) - d, np.asarray(p) + d])
            strips.append(line.buffer(w.thickness_m / 2, cap_style="flat"))
        a, b = (np.array([w.x1 - w.x0, w.y1 - w.y0]) / w.length_m for w in ws)
        if abs(a[0] * b[1] - a[1] * b[0]) > 1e-6:
            patches.append(strips[0].intersection(strips[1]))
    return patches


def _largest(geom) -> Polygon:
    if isinstance(geom, Polygon):
        return geom
    polys = [g for g in getattr(geom, "geoms", []) if isinstance(g, Polygon)]
    if not polys:
        raise ValueError("building layout produced an empty room polygon")
    return max(polys, key=lambda g: g.area)


def _clean(poly: Polygon) -> Polygon:
    poly = orient(poly.simplify(1e-7), 1.0)
    return poly


def _ring_edges(poly: Polygon):
    """Edges (p, q) of all rings, oriented so the polygon interior lies on the left."""
    poly = orient(poly, 1.0)
    for ring in [poly.exterior, *poly.interiors]:
        c = list(ring.coords)
        yield from itertools.pairwise(c)


def _opening_rect(op: Opening, margin_m: float = 0.05) -> Polygon:
    return LineString([(op.x0, op.y0), (op.x1, op.y1)]).buffer(
        op.thickness_m / 2 + margin_m, cap_style="flat"
    )


def generate_building(seed: int, cfg: BuildingConfig | None = None) -> Building:
    """Draw a floor from ``seed``: the same seed always gives the same building, other seeds other
    dimensions (room sizes, wall thicknesses, heights, door/window/furniture positions) of the same
    structure."""
    cfg = cfg or BuildingConfig()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 3001]))
    wh = _u(rng, (1.8, 2.4))
    dn, ds = _u(rng, (4.0, 5.5)), _u(rng, (4.5, 6.0))
    b1, b2, b3 = _u(rng, (5.0, 6.5)), _u(rng, (3.8, 5.0)), _u(rng, (4.0, 5.5))
    nw, nd = _u(rng, (1.4, 1.9)), _u(rng, (1.5, 2.1))
    lx = b1 + b2 + b3
    a1 = _u(rng, (3.6, 5.0))
    a2 = min(_u(rng, (4.2, 5.5)), round(lx - a1 - 2.0, 2))
    cot = 1.0 / math.tan(math.radians(cfg.slant_angle_deg))
    aw, ad = _u(rng, (1.2, 1.6)), _u(rng, (0.5, 0.8))
    # the alcove sits off-centre so that one stretch of 104's exterior wall can take a window
    ac = round(b1 + float(rng.choice([-1, 1]) * rng.uniform(0.2, 0.28) + 0.5) * b2, 2)
    cells_local = {
        "hall": [(0, 0), (lx, 0), (lx, wh), (0, wh)],
        "r1": [(0, wh), (a1, wh), (a1, wh + dn), (0, wh + dn)],
        "r2": [(a1, wh), (a1 + a2, wh), (a1 + a2 + dn * cot, wh + dn), (a1, wh + dn)],
        "r3": [(0, -ds), (b1, -ds), (b1, -nd), (b1 - nw, -nd), (b1 - nw, 0), (0, 0)],
        "wc": [(b1 - nw, -nd), (b1, -nd), (b1, 0), (b1 - nw, 0)],
        "r4": [
            (b1, -ds),
            (ac - aw / 2, -ds),
            (ac - aw / 2, -ds - ad),
            (ac + aw / 2, -ds - ad),
            (ac + aw / 2, -ds),
            (b1 + b2, -ds),
            (b1 + b2, 0),
            (b1, 0),
        ],
        "r5": [(b1 + b2, -ds), (lx, -ds), (lx, 0), (b1 + b2, 0)],
    }
    # place the building so that it lies at x > 0, y < 0 with a margin (image origin = plan origin)
    xmin_l, ymax_l = 0.0, wh + dn
    ox = cfg.margin_m + cfg.exterior_thickness_m[1] - xmin_l
    oy = -(cfg.margin_m + cfg.exterior_thickness_m[1]) - ymax_l
    cells = {k: Polygon([(round(x + ox, 6), round(y + oy, 6)) for x, y in v]) for k, v in cells_local.items()}
    meta = {
        "hall": ("100", "corridor", "hallway"),
        "r1": ("101", "rectangular", "rgbd"),
        "r2": ("102", "slanted", "rgbd"),
        "r3": ("103", "l_shaped", "rgbd"),
        "wc": ("WC", "storage", "none"),
        "r4": ("104", "alcove", "rgbd"),
        "r5": ("105", "rectangular", "tls"),
    }
    heights = {k: round(float(rng.uniform(*cfg.room_height_m)), 2) for k in cells}
    heights["wc"] = heights["hall"]
    t_ext = _u(rng, cfg.exterior_thickness_m)

    walls: list[WallSegment] = []
    for p, q, exterior in _noded_walls(cells):
        t = t_ext if exterior else _u(rng, cfg.interior_thickness_m)
        walls.append(WallSegment(float(p[0]), float(p[1]), float(q[0]), float(q[1]), t, exterior))

    # the change stubs: added in 101 (from its west wall), removed in 104 (from its west wall)
    c1 = cells["r1"].bounds
    y_add = c1[1] + float(rng.uniform(0.45, 0.65)) * (c1[3] - c1[1])
    add_len = _u(rng, (1.2, 1.6))
    added = WallSegment(c1[0], y_add, c1[0] + add_len, y_add, cfg.partition_thickness_m, False, "partition")
    c4 = cells["r4"].bounds
    y_rem = oy - ds + float(rng.uniform(0.45, 0.6)) * (ds - nd)
    rem_len = _u(rng, (1.2, 1.8))
    removed = WallSegment(c4[0], y_rem, c4[0] + rem_len, y_rem, cfg.partition_thickness_m, False, "partition")
    built_walls = [*walls, added]
    planned_walls = [*walls, removed]

    rects = shapely.union_all(
        [w.line.buffer(w.thickness_m / 2, cap_style="flat") for w in built_walls]
        + _corner_patches(built_walls)
    )
    polys = {k: _clean(_largest(c.difference(rects))) for k, c in cells.items()}
    footprint = _clean(
        _largest(
            shapely.union_all(list(cells.values())).buffer(t_ext / 2, join_style="mitre", mitre_limit=10)
        )
    )

    def wall_on(seg: LineString) -> WallSegment:
        for w in walls:
            if all(w.line.distance(Point(c)) < 1e-6 for c in seg.coords):
                return w
        raise ValueError("opening segment lies on no wall")

    def door_in(room: str, s_frac: float, width: float) -> Opening:
        cc = list(cells[room].exterior.coords)
        seg = max(
            (
                LineString([a, b])
                for a, b in itertools.pairwise(cc)
                if cells["hall"].boundary.distance(LineString([a, b]).interpolate(0.5, normalized=True))
                < 1e-6
            ),
            key=lambda g: g.length,
        )
        w = wall_on(seg)
        (sx0, sy0), (sx1, sy1) = seg.coords[0], seg.coords[-1]
        if sx1 < sx0:
            sx0, sy0, sx1, sy1 = sx1, sy1, sx0, sy0
        clear = 0.35 + 0.1
        lo, hi = clear + width / 2, seg.length - clear - width / 2
        s = lo + s_frac * (hi - lo)
        ux, uy = (sx1 - sx0) / seg.length, (sy1 - sy0) / seg.length
        return Opening(
            "door",
            sx0 + ux * (s - width / 2),
            sy0 + uy * (s - width / 2),
            sx0 + ux * (s + width / 2),
            sy0 + uy * (s + width / 2),
            0.0,
            cfg.door_height_m,
            w.thickness_m,
            (room, "hall"),
        )

    doors = {}
    for room in ("r1", "r3", "r4", "r5"):
        doors[room] = door_in(room, float(rng.uniform(0.1, 0.9)), cfg.door_width_m)
    doors["wc"] = door_in("wc", 0.5, 0.8)
    # 102's door: built near one end of its corridor wall, planned near the other
    built_frac, plan_frac = (0.1, 0.9) if rng.random() < 0.5 else (0.9, 0.1)
    doors["r2"] = door_in("r2", built_frac, cfg.door_width_m)
    door2_planned = door_in("r2", plan_frac, cfg.door_width_m)
    if math.dist(doors["r2"].centre, door2_planned.centre) < cfg.door_move_min_m:
        raise ValueError("room 102's corridor wall is too short to move its door")

    # the exit: a double door in the corridor's west (exterior) wall
    hx0, hy0, _hx1, hy1 = cells["hall"].bounds
    ey = 0.5 * (hy0 + hy1)
    west = wall_on(LineString([(hx0, hy0), (hx0, hy1)]))
    exit_door = Opening(
        "door", hx0, ey - 0.6, hx0, ey + 0.6, 0.0, cfg.door_height_m, west.thickness_m, ("hall",)
    )
    windows = []
    sill, top = _u(rng, cfg.window_sill_m), _u(rng, cfg.window_top_m)
    avoid = shapely.union_all([_opening_rect(d, 0.3) for d in doors.values()] + [added.line.buffer(0.4)])
    alcove = _alcove_box(cells_local, ox, oy)
    for room in ("r1", "r2", "r3", "r4", "r5"):
        candidates = []
        for w in walls:
            if not w.exterior or abs(math.sin(2 * math.atan2(w.y1 - w.y0, w.x1 - w.x0))) > 1e-6:
                continue
            part = w.line.intersection(cells[room].boundary.buffer(1e-6))
            candidates += [
                (g, w) for g in getattr(part, "geoms", [part]) if isinstance(g, LineString) and g.length > 1.6
            ]
        if not candidates:
            raise ValueError(f"room {room} has no straight exterior wall long enough for a window")
        # the longest stretch first; the next when doors, the partition stub or the alcove leave no room
        candidates.sort(key=lambda c: -c[0].length)
        placed = None
        for seg, w in candidates:
            width = min(_u(rng, (1.2, 1.8)), round(seg.length - 1.0, 2))
            (sx0, sy0), (sx1, sy1) = seg.coords[0], seg.coords[-1]
            ux, uy = (sx1 - sx0) / seg.length, (sy1 - sy0) / seg.length
            for _ in range(50):
                s = float(rng.uniform(0.45 + width / 2, seg.length - 0.45 - width / 2))
                op = Opening(
                    "window",
                    sx0 + ux * (s - width / 2),
                    sy0 + uy * (s - width / 2),
                    sx0 + ux * (s + width / 2),
                    sy0 + uy * (s + width / 2),
                    sill,
                    top,
                    w.thickness_m,
                    (room,),
                )
                zone = _opening_rect(op, 0.3)
                if not zone.intersects(avoid) and not (room == "r4" and zone.intersects(alcove)):
                    placed = op
                    break
            if placed is not None:
                windows.append(placed)
                break
        if placed is None:
            raise ValueError(f"no place for a window in room {room}")
    built_openings = (*doors.values(), exit_door, *windows)
    planned_openings = tuple(door2_planned if o is doors["r2"] else o for o in built_openings)

    changes = (
        Change(added.x0, added.y0, added.x1, added.y1, "added", "r1", "partition_added"),
        Change(removed.x0, removed.y0, removed.x1, removed.y1, "removed", "r4", "wall_removed"),
        # the plan's door position is solid wall in the building (added), the built door cuts a wall the
        # plan draws (removed)
        Change(*_xy(door2_planned), "added", "r2", "door_moved"),
        Change(*_xy(doors["r2"]), "removed", "r2", "door_moved"),
    )

    yah = _you_are_here(polys["hall"], doors)
    exit_xy = (hx0 + 0.5, ey)
    ext = _extinguishers(polys["hall"], doors)

    mb = _MeshBuilder()
    mat_rng = np.random.default_rng(np.random.SeedSequence([seed, 3002]))
    room_ids = list(cells)
    palette = {
        k: tuple(int(v) for v in mat_rng.integers(170, 245, size=3)) if k != "hall" else (228, 226, 220)
        for k in room_ids
    }
    furniture: list[Furniture] = []
    _build_shell(mb, mat_rng, footprint, polys, heights, built_openings, palette, cfg)
    for room in ("r1", "r2", "r3", "r4", "r5"):
        furniture += _furnish(
            mb, mat_rng, room, polys[room], heights[room], doors[room], built_openings, added
        )
    for x, y in ext:
        furniture.append(_extinguisher(mb, mat_rng, polys["hall"], x, y))
    furniture += _hall_lamps(mb, mat_rng, polys["hall"], heights["hall"])

    rooms = []
    for k in room_ids:
        label, shape, capture = meta[k]
        # the hand-held camera (1.2-1.6 m) clears tables and chairs but not cabinets, shelves or plants
        walk_block = [
            f.footprint.buffer(0.3)
            for f in furniture
            if f.room_id == k and f.kind not in ("lamp", "poster") and f.z1_m > 1.0
        ]
        free = polys[k]
        if walk_block:
            free = free.difference(shapely.union_all(walk_block))
        rooms.append(
            RoomSpec(
                id=k,
                label=label,
                shape=shape,
                capture=capture,
                polygon=polys[k],
                free_space=_clean(_largest(free)),
                height_m=heights[k],
                door=doors.get(k),
                cell=cells[k],
            )
        )
    truth = tuple(
        (float(a[0]), float(a[1]), float(b[0]), float(b[1]), k)
        for k in room_ids
        if meta[k][2] != "none"
        for a, b in _ring_edges(polys[k])
    )
    fb = footprint.bounds
    extent = (0.0, fb[1] - cfg.margin_m, fb[2] + cfg.margin_m, 0.0)
    return Building(
        seed=seed,
        mesh=mb.mesh(),
        rooms=tuple(rooms),
        truth_walls=truth,
        built_walls=tuple(built_walls),
        planned_walls=tuple(planned_walls),
        built_openings=tuple(built_openings),
        planned_openings=planned_openings,
        changes=changes,
        furniture=tuple(furniture),
        you_are_here=yah,
        extinguishers=tuple(ext),
        exit_xy=exit_xy,
        extent=extent,
        footprint=footprint,
    )


def _xy(op: Opening) -> tuple[float, float, float, float]:
    return (op.x0, op.y0, op.x1, op.y1)


def _alcove_box(cells_local, ox: float, oy: float) -> Polygon:
    """The alcove of 104 (plan frame), grown by 0.3 m: windows keep off it."""
    pts = np.asarray(cells_local["r4"], dtype=float)[1:5] + np.array([ox, oy])
    return Polygon(pts).buffer(0.3)


def _you_are_here(hall: Polygon, doors: dict[str, Opening]) -> tuple[float, float]:
    """The plan hangs on the corridor wall near its west end, away from the doors."""
    minx, miny, maxx, maxy = hall.bounds
    for x in np.arange(minx + 1.2, maxx - 1.0, 0.1):
        p = Point(x, miny + 0.4)
        if all(p.distance(Point(*d.centre)) > 1.0 for d in doors.values()) and hall.contains(p):
            return (round(float(x), 3), round(miny + 0.4, 3))
    return (minx + 1.0, 0.5 * (miny + maxy))


def _extinguishers(hall: Polygon, doors: dict[str, Opening]) -> list[tuple[float, float]]:
    """Two extinguishers on the corridor's north wall, a third and four fifths along, clear of doors."""
    minx, _miny, maxx, maxy = hall.bounds
    out = []
    for frac in (0.33, 0.8):
        x0 = minx + frac * (maxx - minx)
        for dx in np.arange(0.0, 3.0, 0.1):
            p = Point(x0 + dx, maxy - 0.12)
            if all(p.distance(Point(*d.centre)) > 0.9 for d in doors.values()) and hall.buffer(1e-9).contains(
                p
            ):
                out.append((round(float(x0 + dx), 3), round(maxy - 0.12, 3)))
                break
    return out


def _paint(rng, rgb, origin, u, v, kind="paint", scale=0.05) -> Material:
    jitter = rng.integers(-8, 9, size=3)
    col = tuple(int(np.clip(c + j, 0, 255)) for c, j in zip(rgb, jitter, strict=True))
    return Material(
        kind,
        col,
        int(rng.integers(0, 2**31 - 1)),
        tuple(float(x) for x in origin),
        tuple(float(x) for x in u),
        tuple(float(x) for x in v),
        float(scale),
    )


def _which(point, polys: dict[str, Polygon], others: list[tuple[str, Polygon]]) -> str:
    p = Point(point)
    for k, poly in polys.items():
        if poly.contains(p):
            return k
    for name, poly in others:
        if poly.contains(p):
            return name
    return "outside"


def _build_shell(mb: _MeshBuilder, rng, footprint, polys, heights, openings, palette, cfg) -> None:
    """Walls (inner faces, reveals, outer faces), floors, ceilings, door passages, window panes."""
    free_union = shapely.union_all(list(polys.values()))
    solid = footprint.difference(free_union)
    cut = {o: _opening_rect(o).intersection(solid) for o in openings}
    solid_cut = solid.difference(shapely.union_all(list(cut.values())))
    h_out = max(heights.values())
    others = [(f"op{i}", g) for i, g in enumerate(cut.values())] + [("solid", solid_cut)]
    op_by_name = {f"op{i}": o for i, o in enumerate(cut)}

    def face_mat(room: str, p, q) -> int:
        u = np.array([q[0] - p[0], q[1] - p[1], 0.0])
        u /= np.linalg.norm(u)
        if room == "outside":
            return mb.add_material(_paint(rng, (200, 190, 175), (*p, 0.0), u, (0, 0, 1), scale=0.2))
        scale = 0.6 if room == "hall" else 0.25
        return mb.add_material(_paint(rng, palette[room], (*p, 0.0), u, (0, 0, 1), scale=scale))

    def edge_side(p, q):
        # the polygon interior is on the left of p -> q: probe the right side
        d = np.subtract(q, p)
        n = np.array([d[1], -d[0]]) / np.hypot(*d)
        m = (np.asarray(p) + np.asarray(q)) / 2 + 0.004 * n
        return _which(m, polys, others)

    geoms = solid_cut.geoms if isinstance(solid_cut, MultiPolygon) else [solid_cut]
    for g in geoms:
        for p, q in _ring_edges(g):
            side = edge_side(p, q)
            # face the neighbour: traverse q -> p so the quad's left normal points out of the solid
            if side == "outside":
                mb.vertical(q, p, 0.0, h_out, face_mat("outside", q, p))
            elif side.startswith("op"):
                op = op_by_name[side]
                mb.vertical(q, p, op.z0_m, op.z1_m, face_mat(op.room_ids[0], q, p))
            elif side != "solid":  # solid on both sides: a sliver thinner than the probe, never seen
                mb.vertical(q, p, 0.0, heights[side], face_mat(side, q, p))
    for op, g in cut.items():
        room = op.room_ids[0]
        for part in getattr(g, "geoms", [g]):
            for p, q in _ring_edges(part):
                side = edge_side(p, q)
                if side.startswith("op") or side == "solid":
                    continue
                if side == "outside" or side in polys:
                    top = h_out if side == "outside" else heights[side]
                    mat = face_mat(side, q, p)
                    mb.vertical(q, p, 0.0, op.z0_m, mat)
                    mb.vertical(q, p, op.z1_m, top, mat)
            sill_mat = mb.add_material(
                _paint(
                    rng,
                    (235, 235, 230) if op.kind == "window" else palette[room],
                    (op.x0, op.y0, 0),
                    (1, 0, 0),
                    (0, 1, 0),
                )
            )
            if op.z0_m > 0:
                mb.horizontal(part, op.z0_m, sill_mat)
            else:
                mb.horizontal(
                    part,
                    0.0,
                    mb.add_material(
                        _paint(rng, (150, 120, 90), (op.x0, op.y0, 0), (1, 0, 0), (0, 1, 0), "floor", 0.1)
                    ),
                )
            mb.horizontal(part, op.z1_m, sill_mat)
        if op.kind == "window":
            glass = mb.add_material(
                _paint(rng, (200, 225, 235), (op.x0, op.y0, op.z0_m), (1, 0, 0), (0, 0, 1), "glass", 1.0)
            )
            mb.vertical((op.x0, op.y0), (op.x1, op.y1), op.z0_m, op.z1_m, glass)
    for k, poly in polys.items():
        floor_rgb = (120, 100, 80) if k != "hall" else (160, 158, 152)
        fscale = 0.5 if k != "hall" else 0.8
        # the corridor floor is plain linoleum: no tile joints for SfM to hold on to
        fkind = "floor" if k != "hall" else "paint"
        mb.horizontal(
            poly,
            0.0,
            mb.add_material(
                _paint(rng, floor_rgb, (*poly.bounds[:2], 0), (1, 0, 0), (0, 1, 0), fkind, fscale)
            ),
        )
        ceil = mb.add_material(
            _paint(rng, (238, 238, 235), (*poly.bounds[:2], heights[k]), (1, 0, 0), (0, 1, 0), "ceiling", 0.5)
        )
        mb.horizontal(poly, heights[k], ceil)


def _place_against_wall(rng, room_poly: Polygon, depth: float, width: float, blocked, tries: int = 80):
    """A footprint (centre, yaw) with its back against one of the room's long-enough inner faces."""
    edges = [(p, q) for p, q in _ring_edges(room_poly) if math.dist(p, q) > width + 0.3]
    if not edges:
        return None
    for _ in range(tries):
        p, q = edges[int(rng.integers(len(edges)))]
        d = np.subtract(q, p) / math.dist(p, q)
        n = np.array([-d[1], d[0]])  # into the room
        s = float(rng.uniform(width / 2 + 0.15, math.dist(p, q) - width / 2 - 0.15))
        c = np.asarray(p) + d * s + n * (depth / 2 + 0.02)
        yaw = math.atan2(d[1], d[0])
        fp = _footprint(c, width, depth, yaw)
        if room_poly.buffer(-0.01).contains(fp) and not fp.buffer(0.05).intersects(blocked):
            return c, yaw, fp
    return None


def _place_free(
    rng, room_poly: Polygon, sx: float, sy: float, blocked, wall_clear: float = 0.7, tries: int = 80
):
    inner = room_poly.buffer(-wall_clear - max(sx, sy) / 2)
    if inner.is_empty:
        return None
    minx, miny, maxx, maxy = inner.bounds
    for _ in range(tries):
        c = np.array([rng.uniform(minx, maxx), rng.uniform(miny, maxy)])
        yaw = float(rng.choice([0.0, math.pi / 2])) + float(rng.uniform(-0.15, 0.15))
        fp = _footprint(c, sx, sy, yaw)
        if (
            inner.contains(Point(c))
            and room_poly.buffer(-0.05).contains(fp)
            and not fp.buffer(0.1).intersects(blocked)
        ):
            return c, yaw, fp
    return None


def _footprint(c, sx: float, sy: float, yaw: float) -> Polygon:
    cs, sn = math.cos(yaw), math.sin(yaw)
    pts = [(-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2)]
    return Polygon([(c[0] + cs * x - sn * y, c[1] + sn * x + cs * y) for x, y in pts])


def _frame_mats(mb: _MeshBuilder, rng, rgb, kind: str, scale: float):
    def make(_name, origin, u, v):
        return mb.add_material(_paint(rng, rgb, origin, u, v, kind, scale))

    return make


def _furnish(mb, rng, room: str, poly: Polygon, height: float, door: Opening, openings, added: WallSegment):
    """Tables, chairs, a tall cabinet, shelves, a plant, a ceiling lamp, a TV and posters, away from doors and windows."""
    out: list[Furniture] = []
    dc = Point(*door.centre)
    blocked = dc.buffer(1.3)
    for o in openings:
        if o.kind == "window" and room in o.room_ids:
            blocked = blocked.union(LineString([(o.x0, o.y0), (o.x1, o.y1)]).buffer(0.35))
    blocked = blocked.union(added.line.buffer(0.3))

    def record(kind, fp, z0, z1):
        nonlocal blocked
        out.append(Furniture(kind, room, fp, z0, z1))
        if kind != "poster":
            blocked = blocked.union(fp)

    wood = (int(rng.integers(120, 170)), int(rng.integers(80, 110)), int(rng.integers(50, 70)))
    # tall cabinet against a wall
    got = _place_against_wall(rng, poly, 0.45, 0.9, blocked)
    if got and room in ("r2", "r4", "r5"):
        c, yaw, fp = got
        mb.box(c[0], c[1], 0.0, 0.9, 0.45, 2.0, yaw, _frame_mats(mb, rng, (190, 185, 175), "wood", 0.4))
        record("cabinet", fp, 0.0, 2.0)
    # shelves: a frame with four boards
    got = _place_against_wall(rng, poly, 0.35, 1.0, blocked)
    if got and room in ("r1", "r3", "r5"):
        c, yaw, fp = got
        mats = _frame_mats(mb, rng, wood, "wood", 0.3)
        d = np.array([math.cos(yaw), math.sin(yaw)])
        for side in (-1, 1):
            e = c + d * side * 0.49
            mb.box(e[0], e[1], 0.0, 0.02, 0.35, 1.8, yaw, mats)
        for z in (0.05, 0.5, 0.95, 1.4, 1.78):
            mb.box(c[0], c[1], z, 0.96, 0.35, 0.02, yaw, mats)
        # books on two boards: colourful texture for SfM
        for z in (0.52, 0.97):
            for i in range(6):
                bx = c + d * (-0.4 + 0.16 * i)
                col = tuple(int(v) for v in rng.integers(30, 230, size=3))
                mb.box(
                    bx[0],
                    bx[1],
                    z,
                    0.12,
                    0.25,
                    float(rng.uniform(0.2, 0.32)),
                    yaw,
                    _frame_mats(mb, rng, col, "poster", 0.08),
                )
        record("shelf", fp, 0.0, 1.8)
    # a TV (dark screen: no depth) on a low cabinet
    if room in ("r2", "r3"):
        got = _place_against_wall(rng, poly, 0.4, 1.2, blocked)
        if got:
            c, yaw, fp = got
            mb.box(c[0], c[1], 0.0, 1.2, 0.4, 0.5, yaw, _frame_mats(mb, rng, wood, "wood", 0.4))
            n = np.array([-math.sin(yaw), math.cos(yaw)])
            s = c - n * 0.12
            mb.box(
                s[0],
                s[1],
                0.5,
                1.0,
                0.05,
                0.6,
                yaw,
                mb.add_material(_paint(rng, (20, 20, 25), (*s, 0.5), (1, 0, 0), (0, 0, 1), "dark", 0.1)),
            )
            record("tv", fp, 0.0, 1.1)
    # table with chairs
    sx, sy = float(rng.uniform(1.2, 1.8)), float(rng.uniform(0.7, 0.9))
    got = _place_free(rng, poly, sx, sy + 1.0, blocked)
    if got:
        c, yaw, _ = got
        fp = _footprint(c, sx, sy, yaw)
        mats = _frame_mats(mb, rng, wood, "wood", 0.4)
        mb.box(c[0], c[1], 0.71, sx, sy, 0.04, yaw, mats)
        metal = mb.add_material(_paint(rng, (90, 90, 95), (*c, 0), (1, 0, 0), (0, 0, 1), "metal", 0.1))
        d, n = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
        for i in (-1, 1):
            for j in (-1, 1):
                leg = c + d * i * (sx / 2 - 0.06) + n * j * (sy / 2 - 0.06)
                mb.box(leg[0], leg[1], 0.0, 0.05, 0.05, 0.71, yaw, metal)
        record("table", fp, 0.0, 0.75)
        seat_rgb = tuple(int(v) for v in rng.integers(40, 200, size=3))
        for i, j in ((-0.25, -1), (0.25, 1), (0.3, -1)):
            ch = c + d * i * sx + n * j * (sy / 2 + 0.3)
            yaw_c = yaw + (0.0 if j > 0 else math.pi) + float(rng.uniform(-0.3, 0.3))
            _chair(mb, rng, ch, yaw_c, seat_rgb, metal)
            record("chair", _footprint(ch, 0.45, 0.45, yaw_c), 0.0, 0.9)
    # plant in a corner-ish spot
    if room in ("r1", "r3", "r4", "r5"):
        got = _place_against_wall(rng, poly, 0.45, 0.45, blocked)
        if got:
            c, yaw, fp = got
            mb.cylinder(
                c[0],
                c[1],
                0.0,
                0.4,
                0.18,
                mb.add_material(_paint(rng, (170, 90, 60), (*c, 0), (1, 0, 0), (0, 0, 1), "paint", 0.05)),
            )
            leaf = mb.add_material(_paint(rng, (60, 130, 50), (*c, 0.4), (1, 0, 0), (0, 0, 1), "plant", 0.1))
            mb.cylinder(c[0], c[1], 0.4, 1.3, 0.3, leaf, n=10)
            record("plant", fp, 0.0, 1.3)
    # ceiling lamp: a rod and a shade near the room centre
    lc = poly.representative_point() if not poly.contains(poly.centroid) else poly.centroid
    metal = mb.add_material(
        _paint(rng, (210, 210, 200), (lc.x, lc.y, height), (1, 0, 0), (0, 1, 0), "metal", 0.1)
    )
    mb.cylinder(lc.x, lc.y, height - 0.35, height, 0.01, metal, n=6)
    mb.cylinder(lc.x, lc.y, height - 0.5, height - 0.35, 0.25, metal, n=20)
    record("lamp", Point(lc.x, lc.y).buffer(0.25), height - 0.5, height)
    # posters on free wall stretches: the texture SIFT needs
    posters = 0
    for _ in range(30):
        if posters == 4:
            break
        edges = [(p, q) for p, q in _ring_edges(poly) if math.dist(p, q) > 1.2]
        p, q = edges[int(rng.integers(len(edges)))]
        length = math.dist(p, q)
        w, h = float(rng.uniform(0.5, 0.9)), float(rng.uniform(0.6, 1.0))
        s = float(rng.uniform(0.1 + w / 2, length - 0.1 - w / 2))
        d = np.subtract(q, p) / length
        n = np.array([-d[1], d[0]])
        a = np.asarray(p) + d * (s - w / 2) + n * 0.004
        b = np.asarray(p) + d * (s + w / 2) + n * 0.004
        fp = LineString([a, b]).buffer(0.05)
        if fp.intersects(blocked) or any(f.footprint.intersects(fp) for f in out if f.kind == "poster"):
            continue
        posters += 1
        z0 = float(rng.uniform(1.0, 1.4))
        col = tuple(int(v) for v in rng.integers(60, 240, size=3))
        mb.vertical(
            tuple(a),
            tuple(b),
            z0,
            z0 + h,
            mb.add_material(
                _paint(rng, col, (*a, z0), (*d, 0), (0, 0, 1), "poster", float(rng.uniform(0.12, 0.2)))
            ),
        )
        record("poster", fp, z0, z0 + h)
    return out


def _chair(mb, rng, c, yaw: float, rgb, metal: int) -> None:
    d, n = np.array([math.cos(yaw), math.sin(yaw)]), np.array([-math.sin(yaw), math.cos(yaw)])
    for i in (-1, 1):
        for j in (-1, 1):
            leg = c + d * i * 0.19 + n * j * 0.19
            mb.box(leg[0], leg[1], 0.0, 0.03, 0.03, 0.45, yaw, metal)
    seat = mb.add_material(_paint(rng, rgb, (*c, 0.45), (*d, 0), (*n, 0), "paint", 0.03))
    mb.box(c[0], c[1], 0.45, 0.44, 0.44, 0.04, yaw, seat)
    back = c + n * 0.2
    mb.box(back[0], back[1], 0.49, 0.44, 0.03, 0.42, yaw, seat)


def _extinguisher(mb, rng, hall: Polygon, x: float, y: float) -> Furniture:
    red = mb.add_material(_paint(rng, (200, 30, 30), (x, y, 0), (1, 0, 0), (0, 0, 1), "metal", 0.1))
    mb.cylinder(x, y - 0.02, 0.15, 0.75, 0.08, red, n=12)
    return Furniture("extinguisher", "hall", Point(x, y).buffer(0.1), 0.15, 0.75)


def _hall_lamps(mb, rng, hall: Polygon, height: float) -> list[Furniture]:
    minx, miny, maxx, maxy = hall.bounds
    out = []
    metal = mb.add_material(
        _paint(rng, (235, 235, 230), (minx, miny, height), (1, 0, 0), (0, 1, 0), "metal", 1.0)
    )
    for frac in (0.25, 0.75):
        x, y = minx + frac * (maxx - minx), 0.5 * (miny + maxy)
        mb.box(x, y, height - 0.06, 1.2, 0.3, 0.06, 0.0, metal)
        out.append(Furniture("lamp", "hall", _footprint((x, y), 1.2, 0.3, 0.0), height - 0.06, height))
    return out


def wall_angles_deg(walls) -> NDArray[np.float64]:
    """Direction of each segment (x0, y0, x1, y1, ...) in degrees, in [0, 180)."""
    return np.array([math.degrees(math.atan2(w[3] - w[1], w[2] - w[0])) % 180.0 for w in walls])
