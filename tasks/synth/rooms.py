"""Synthetic rooms with known answers, sampled as registered clouds: the inputs of the walls and preprocess
tests and benchmarks (the survey generator beside this module renders whole buildings instead).

Polygon rooms: `make_room(kind, rng)` gives a `Room` (outline, openings, clutter) in a random position and
heading, `truth_walls(room)` its inner wall faces (M, 4) (what a room model should find), and
`sample_room(room, sensor, rng)` a cloud (N, 3) in metres with z up, floor at z = 0.

Sensors:
- "kinect_v1": range noise along the ray sigma = 3 mm at 1 m growing with H^2 (thesis 6.1: 3 / 7 / 15 mm at
  1 / 1.8 / 2.6 m), depth quantization in steps that also grow with H^2 (8 cm at 5.5 m: the stripes of
  fig 5.3) with a different phase per frame, registration misalignment per camera position (a few mm and
  a few hundredths of a degree), 0.3 % flying pixels;
- "tls": 2 mm range noise from two scanner stations, 1 mm registration error.
Doors and windows leave gaps (glass gives no return); furniture against a wall hides the wall behind
it; a plant is a loose cloud of leaves. Only what lies inside `z_range` is sampled, to keep tests fast.

A tilted furnished box room: `tilted_box_room(n_points, seed)` gives a whole-room cloud (floor, ceiling,
furniture, outliers) in a tilted sensor-like frame and its `RoomTruth` (the true room frame, the surfaces,
which points are injected outliers), for the preprocess stage.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from tasks.cloud import Cloud


@dataclass(frozen=True)
class Opening:
    """A door or window in wall `wall` (edge outline[wall] -> outline[wall + 1])."""

    wall: int
    start_m: float
    """Distance of the opening's first jamb from the wall's first corner."""
    width_m: float
    bottom_m: float
    top_m: float


@dataclass(frozen=True)
class Box:
    """Furniture: a box with footprint corners (4, 2) standing on the floor, `height_m` tall."""

    footprint: tuple[tuple[float, float], ...]
    height_m: float
    against_wall: bool = True
    """Hides the wall behind it (up to its height)."""


@dataclass(frozen=True)
class Plant:
    centre: tuple[float, float]
    radius_m: float
    z_range: tuple[float, float]
    leaves: int = 4000


@dataclass(frozen=True)
class Room:
    name: str
    outline: NDArray[np.float64]
    """(K, 2) inner wall faces, counter-clockwise, metres."""
    height_m: float = 2.7
    columns: tuple[NDArray[np.float64], ...] = ()
    """Free-standing columns: (4, 2) counter-clockwise footprints; their faces are walls too."""
    openings: tuple[Opening, ...] = ()
    boxes: tuple[Box, ...] = ()
    plants: tuple[Plant, ...] = ()
    cameras_xy: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))
    """Where the capture stood (set by `make_room`)."""


# ------------------------------------------------------------------------------------------- rooms

KINDS = ("rectangle", "l_shape", "wall70", "alcove_column")
"""The rooms of the accuracy tests; "square10" (10 m x 10 m) is the benchmark's; "trapezoid<deg>" (e.g.
"trapezoid7.5") is the near-parallel family (`NEAR_PARALLEL_DEG`)."""
NEAR_PARALLEL_DEG = (3.0, 5.0, 7.5, 10.0, 15.0)
"""Opening angles of the near-parallel rooms: a 5 m x 4 m trapezoid whose long opposite walls are this many
degrees apart, with one wall at 70° to its neighbour (old town houses, wings meeting at 5-15°)."""


def _outline(kind: str) -> tuple[NDArray, tuple[NDArray, ...]]:
    if kind == "rectangle":
        return np.array([(0, 0), (5.0, 0), (5.0, 4.0), (0, 4.0)]), ()
    if kind == "square10":
        return np.array([(0, 0), (10.0, 0), (10.0, 10.0), (0, 10.0)]), ()
    if kind == "l_shape":
        return np.array([(0, 0), (6.0, 0), (6.0, 3.0), (3.5, 3.0), (3.5, 5.0), (0, 5.0)]), ()
    if kind == "wall70":
        return np.array([(0, 0), (5.0, 0), (5.0, 4.0), (4.0 / math.tan(math.radians(70)), 4.0)]), ()
    if kind.startswith("trapezoid"):
        # south wall along x, east wall at 90°, north wall turned by `delta` from the south wall (its
        # west end lower), west wall at 70° to the south wall
        delta = math.radians(float(kind.removeprefix("trapezoid")))
        t70 = math.tan(math.radians(70))
        # the north wall y = 4 - (5 - x) tan(delta) meets the west wall y = x tan70
        x_nw = (4.0 - 5.0 * math.tan(delta)) / (t70 - math.tan(delta))
        return np.array([(0, 0), (5.0, 0), (5.0, 4.0), (x_nw, x_nw * t70)]), ()
    if kind == "alcove_column":
        outline = np.array(
            [(0, 0), (1.5, 0), (1.5, 0.35), (2.0, 0.35), (2.0, 0), (6.0, 0), (6.0, 4.0), (4.0, 4.0),
             (4.0, 4.6), (2.8, 4.6), (2.8, 4.0), (0, 4.0)]
        )  # fmt: skip
        column = np.array([(4.3, 1.8), (4.7, 1.8), (4.7, 2.2), (4.3, 2.2)])
        return outline, (column,)
    raise ValueError(f"unknown room kind {kind!r}")


def _wall_point(outline: NDArray, wall: int, s: float) -> NDArray:
    a, b = outline[wall], outline[(wall + 1) % len(outline)]
    return a + (b - a) * s / np.hypot(*(b - a))


def _box_on_wall(outline: NDArray, wall: int, start: float, width: float, depth: float) -> NDArray:
    a, b = outline[wall], outline[(wall + 1) % len(outline)]
    u = (b - a) / np.hypot(*(b - a))
    n = np.array([-u[1], u[0]])  # inward for a counter-clockwise outline
    p0 = a + u * start
    return np.array([p0, p0 + u * width, p0 + u * width + n * depth, p0 + n * depth])


def make_room(kind: str, rng: np.random.Generator, *, clutter: bool = True, move: bool = True) -> Room:
    """A room of one of `KINDS` with a door, a window, a tall cabinet against a wall and a plant (when
    `clutter`), turned by a random heading and moved by a random offset (when `move`)."""
    outline, columns = _outline(kind)
    longest = int(np.argmax(np.hypot(*(np.roll(outline, -1, 0) - outline).T)))
    k = len(outline)
    walls_by_length = np.argsort(-np.hypot(*(np.roll(outline, -1, 0) - outline).T))
    door_wall, window_wall, cabinet_wall = int(longest), int(walls_by_length[1]), int(walls_by_length[2])

    def wall_len(i: int) -> float:
        return float(np.hypot(*(outline[(i + 1) % k] - outline[i])))

    openings: tuple[Opening, ...] = ()
    boxes: tuple[Box, ...] = ()
    plants: tuple[Plant, ...] = ()
    if clutter:
        door_h = float(rng.uniform(2.0, 2.1))
        openings = (
            Opening(door_wall, float(rng.uniform(0.5, wall_len(door_wall) - 1.5)), 0.9, 0.0, door_h),
            Opening(window_wall, float(rng.uniform(0.4, wall_len(window_wall) - 1.8)), 1.3, 0.9, 2.2),
        )
        cab_len = wall_len(cabinet_wall)
        cab = _box_on_wall(outline, cabinet_wall, float(rng.uniform(0.3, cab_len - 1.3)), 1.0, 0.6)
        boxes = (Box(tuple(map(tuple, cab)), float(rng.uniform(1.9, 2.2))),)
        centre = outline.mean(axis=0)
        corner = outline[int(rng.integers(k))]
        spot = corner + 0.5 * (centre - corner) / np.hypot(*(centre - corner))
        plants = (Plant((float(spot[0]), float(spot[1])), 0.35, (1.0, 1.9)),)
    room = Room(kind, outline, 2.7, columns, openings, boxes, plants)
    room = replace(room, cameras_xy=_camera_path(room))
    if move:
        room = moved(room, float(rng.uniform(0, 2 * np.pi)), rng.uniform(-20, 20, 2))
    return room


def _camera_path(room: Room, inset_m: float = 1.2, n: int = 12) -> NDArray:
    """Camera positions on a loop about `inset_m` inside the walls (someone walking round the room)."""
    from shapely.geometry import Polygon

    poly = Polygon(room.outline)
    for inset in (inset_m, 0.8, 0.5):
        inner = poly.buffer(-inset, join_style="mitre")
        if not inner.is_empty and inner.geom_type == "Polygon":
            ring = inner.exterior
            return np.array([ring.interpolate(t, normalized=True).coords[0] for t in np.arange(n) / n])
    return np.array([poly.representative_point().coords[0]])


def moved(room: Room, angle_rad: float, offset_xy: NDArray) -> Room:
    """The room turned by `angle_rad` about the origin and then shifted by `offset_xy`."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    r = np.array([[c, -s], [s, c]])
    t = np.asarray(offset_xy, dtype=np.float64)

    def tf(p: NDArray) -> NDArray:
        return np.asarray(p, dtype=np.float64) @ r.T + t

    return replace(
        room,
        outline=tf(room.outline),
        columns=tuple(tf(c_) for c_ in room.columns),
        boxes=tuple(replace(b, footprint=tuple(map(tuple, tf(np.array(b.footprint))))) for b in room.boxes),
        plants=tuple(replace(p, centre=tuple(tf(np.array(p.centre)))) for p in room.plants),
        cameras_xy=tf(room.cameras_xy),
    )


def _edges(poly: NDArray) -> NDArray:
    return np.concatenate([poly, np.roll(poly, -1, axis=0)], axis=1)


def truth_walls(room: Room) -> NDArray[np.float64]:
    """(M, 4) the inner wall faces: the outline's edges (doors and windows included: the lintel above a
    door and the wall above a window are in the slice) and the faces of free-standing columns."""
    return np.concatenate([_edges(room.outline), *[_edges(c) for c in room.columns]])


# ------------------------------------------------------------------------------------------- sampling


@dataclass(frozen=True)
class Sensor:
    name: str
    sigma_1m: float
    """Range noise at 1 m (m); grows with H^2 when `quadratic`."""
    quadratic: bool
    quant_1m: float
    """Depth quantization step at 1 m (m), growing with H^2; 0 for none."""
    misreg_m: float
    """Per-station registration error (m), translation sigma; rotation gives as much at 3 m."""
    flying: float
    """Share of flying pixels (points pulled toward the camera)."""
    stations: int | None
    """Camera stations used (None: the room's whole camera path)."""


SENSORS = {
    "kinect_v1": Sensor("kinect_v1", 0.003, True, 0.0026, 0.003, 0.003, None),
    "tls": Sensor("tls", 0.002, False, 0.0, 0.001, 0.0, 2),
    "noise12": Sensor("noise12", 0.012, False, 0.0, 0.003, 0.003, None),
}
""""noise12": 12 mm range noise at any range (the near-parallel rooms of issue 14), Kinect-like otherwise."""


def _sample_quads(quads: list[tuple[NDArray, NDArray, float, float]], density: float, rng) -> tuple:
    """Uniform points on vertical rectangles (a, b, z0, z1): returns points (N, 3) and quad index."""
    pts, owner = [], []
    for i, (a, b, z0, z1) in enumerate(quads):
        area = float(np.hypot(*(b - a))) * max(z1 - z0, 0.0)
        n = rng.poisson(area * density)
        if n == 0:
            continue
        s = rng.random(n)
        xy = a + s[:, None] * (b - a)
        z = rng.uniform(z0, z1, n)
        pts.append(np.column_stack([xy, z]))
        owner.append(np.full(n, i))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    return np.concatenate(pts), np.concatenate(owner)


def _wall_quads(room: Room, z_lo: float, z_hi: float) -> list[tuple[NDArray, NDArray, float, float]]:
    """Visible wall rectangles: each wall minus its openings, and minus what furniture hides."""
    quads = []
    for poly, is_outline in [(room.outline, True), *[(c, False) for c in room.columns]]:
        k = len(poly)
        for i in range(k):
            a, b = poly[i], poly[(i + 1) % k]
            L = float(np.hypot(*(b - a)))
            u = (b - a) / L
            holes = []  # (s0, s1, z0, z1) regions of the wall with no return
            if is_outline:
                holes += [
                    (o.start_m, o.start_m + o.width_m, o.bottom_m, o.top_m)
                    for o in room.openings
                    if o.wall == i
                ]
                for box in room.boxes:
                    fp = np.array(box.footprint)
                    s = (fp - a) @ u
                    d = np.abs((fp - a) @ np.array([-u[1], u[0]]))
                    if box.against_wall and d.min() < 0.05:
                        holes.append((float(s.min()), float(s.max()), 0.0, box.height_m))
            quads += _split_wall(a, u, L, holes, z_lo, z_hi)
    return quads


def _split_wall(a, u, L, holes, z_lo, z_hi):
    """Rectangles covering [0, L] x [z_lo, z_hi] minus the hole rectangles (holes may not overlap)."""
    cuts = sorted(
        {0.0, L, *[max(0.0, min(L, h[0])) for h in holes], *[max(0.0, min(L, h[1])) for h in holes]}
    )
    quads = []
    for s0, s1 in itertools.pairwise(cuts):
        if s1 - s0 <= 1e-9:
            continue
        mid = 0.5 * (s0 + s1)
        zs = [(z_lo, z_hi)]
        for h in holes:
            if h[0] <= mid <= h[1]:
                zs = [(z0, min(z1, h[2])) for z0, z1 in zs] + [(max(z0, h[3]), z1) for z0, z1 in zs]
        for z0, z1 in zs:
            if z1 > z0:
                quads.append((a + u * s0, a + u * s1, z0, z1))
    return quads


def _box_quads(room: Room, z_lo: float, z_hi: float) -> list[tuple[NDArray, NDArray, float, float]]:
    quads = []
    for box in room.boxes:
        fp = np.array(box.footprint)
        for i in range(4):
            quads.append((fp[i], fp[(i + 1) % 4], max(z_lo, 0.0), min(z_hi, box.height_m)))
    return quads


def _box_tops(room: Room, density: float, rng, z_lo: float, z_hi: float) -> NDArray:
    out = []
    for box in room.boxes:
        if not z_lo <= box.height_m <= z_hi:
            continue
        fp = np.array(box.footprint)
        e1, e2 = fp[1] - fp[0], fp[3] - fp[0]
        n = rng.poisson(abs(e1[0] * e2[1] - e1[1] * e2[0]) * density)
        st = rng.random((n, 2))
        xy = fp[0] + st[:, :1] * e1 + st[:, 1:] * e2
        out.append(np.column_stack([xy, np.full(n, box.height_m)]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _plants(room: Room, rng, z_lo: float, z_hi: float) -> NDArray:
    out = []
    for p in room.plants:
        n = p.leaves
        r = p.radius_m * rng.random(n) ** (1 / 3)
        phi = rng.uniform(0, 2 * np.pi, n)
        z = rng.uniform(*p.z_range, n)
        xy = np.array(p.centre) + np.column_stack([r * np.cos(phi), r * np.sin(phi)])
        pts = np.column_stack([xy, z])
        out.append(pts[(z >= z_lo) & (z <= z_hi)])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _ceiling_and_floor(room: Room, density: float, rng, z_lo: float, z_hi: float) -> NDArray:
    import shapely
    from shapely.geometry import Polygon

    poly = Polygon(room.outline)
    x0, y0, x1, y1 = poly.bounds
    out = []
    for z in (0.0, room.height_m):
        if not z_lo - 0.1 <= z <= z_hi + 0.1:
            continue
        n = rng.poisson((x1 - x0) * (y1 - y0) * density)
        xy = rng.uniform([x0, y0], [x1, y1], (n, 2))
        xy = xy[shapely.contains_xy(poly, xy[:, 0], xy[:, 1])]
        out.append(np.column_stack([xy, np.full(len(xy), z)]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def sample_room(
    room: Room,
    sensor: str,
    rng: np.random.Generator,
    *,
    density: float = 20000.0,
    z_range: tuple[float, float] = (1.4, 2.6),
    floor_ceiling_density: float = 500.0,
) -> NDArray[np.float64]:
    """A registered cloud (N, 3) of the room as `sensor` sees it, floor at z = 0, limited to `z_range`.

    `density` is points per m^2 of wall before noise (a registered RGB-D cloud after a 1 cm voxel filter
    holds about 1e4 per m^2 on every surface, more in the noise layer)."""
    sen = SENSORS[sensor]
    quads = _wall_quads(room, *z_range) + _box_quads(room, *z_range)
    surf, _ = _sample_quads(quads, density, rng)
    surf = np.concatenate([surf, _box_tops(room, density, rng, *z_range)])
    surf = np.concatenate([surf, _ceiling_and_floor(room, floor_ceiling_density, rng, *z_range)])
    leaves = _plants(room, rng, *z_range)

    cams = room.cameras_xy
    if sen.stations is not None:
        idx = np.linspace(0, len(cams), sen.stations, endpoint=False).astype(int)
        cams = cams[idx]
    cam_z = 1.5 if sen.quadratic else 1.6
    cam3 = np.column_stack([cams, np.full(len(cams), cam_z)])
    pts = np.concatenate([surf, leaves])
    # each point is seen from a random station among the nearer half (a walking capture sees each wall
    # mostly from across the room, sometimes from close)
    d = np.linalg.norm(pts[:, None, :] - cam3[None], axis=2)
    order = np.argsort(d, axis=1)
    half = max(1, (len(cams) + 1) // 2)
    pick = order[np.arange(len(pts)), rng.integers(0, half, len(pts))]
    cam = cam3[pick]
    ray = pts - cam
    rng_true = np.linalg.norm(ray, axis=1)
    ray /= rng_true[:, None]
    scale = rng_true**2 if sen.quadratic else np.ones_like(rng_true)
    meas = rng_true + rng.normal(0.0, 1.0, len(pts)) * sen.sigma_1m * scale
    if sen.quant_1m > 0:
        q = sen.quant_1m * scale
        phase = rng.random(len(cams))[pick]
        meas = q * (np.round(meas / q - phase) + phase)
    if sen.flying > 0:
        fly = rng.random(len(pts)) < sen.flying
        meas[fly] *= rng.uniform(0.6, 1.0, int(fly.sum()))
    out = cam + ray * meas[:, None]
    # registration misalignment: one small rigid motion per station
    ang = rng.normal(0.0, sen.misreg_m / 3.0, len(cams))  # radians: misreg_m at 3 m
    shift = rng.normal(0.0, sen.misreg_m, (len(cams), 3))
    centre = room.outline.mean(axis=0)
    c, s = np.cos(ang)[pick], np.sin(ang)[pick]
    dx, dy = out[:, 0] - centre[0], out[:, 1] - centre[1]
    out[:, 0] = centre[0] + c * dx - s * dy
    out[:, 1] = centre[1] + s * dx + c * dy
    out += shift[pick]
    return out


def furniture_slice(points: NDArray, floor_z: float = 0.0, lo_m: float = 1.5, hi_m: float = 2.5) -> NDArray:
    """The points between `lo_m` and `hi_m` above the floor (the preprocess stage's selective height
    filter, thesis 5.1.5)."""
    z = points[:, 2] - floor_z
    return np.ascontiguousarray(points[(z >= lo_m) & (z <= hi_m)])


# ------------------------------------------------------------------------------- tilted box room


@dataclass(frozen=True)
class RoomTruth:
    """What `tilted_box_room` knows about the cloud it made."""

    room_to_input: NDArray[np.float64]
    """(4, 4) true room frame (floor z = 0, walls axis-aligned) -> the cloud's frame."""
    boxes: NDArray[np.float64]
    """(B, 2, 3) min/max corners of the room and the furniture, room frame: surfaces are their faces."""
    height_m: float
    outliers: NDArray[np.bool_]
    """(N,) the injected outliers."""
    far_outliers: NDArray[np.bool_]
    """(N,) injected outliers more than FAR_M from every true surface."""


FAR_M = 0.10
"""Injected outliers farther than this from every true surface are "far" (the outlier filter must remove
them all)."""


def surface_distance(points: NDArray[np.float64], boxes: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance (N,) from each room-frame point to the nearest face of any box."""
    best = np.full(len(points), np.inf)
    for lo, hi in boxes:
        outside = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0), axis=1)
        inside = np.minimum(points - lo, hi - points).min(axis=1)
        best = np.minimum(best, np.where(inside > 0, inside, outside))
    return best


def tilted_box_room(
    n_points: int = 400_000,
    seed: int = 7,
    *,
    size: tuple[float, float, float] = (5.0, 4.0, 2.70),
    tilt_deg: float = 3.0,
    tilt_axis: tuple[float, float, float] = (0.8, 0.6, 0.0),
    outlier_ratio: float = 0.02,
    floor_fraction: float = 1.0,
    ceiling_fraction: float = 1.0,
    noise_scale: float = 1.0,
    colors: bool = True,
) -> tuple[Cloud, RoomTruth]:
    """A furnished box room captured like a Kinect room cloud, in a tilted sensor-like frame.

    Surfaces (room faces, a table, a tall cabinet, a sofa, a hanging lamp) are sampled evenly by area;
    `floor_fraction`/`ceiling_fraction` keep only that share of floor/ceiling (a strip by a wall).
    Noise is along the ray from a viewpoint in the middle of the room, σ = 2 mm + 1.5 mm per metre
    (3-7 mm), times `noise_scale`. Outliers, `outlier_ratio` of all points: a third spread through the
    room's volume grown by 0.5 m, a third flying pixels (surface points pushed 0.1-1 m along their ray),
    a third far (5-20 m). The room frame is tilted `tilt_deg` about `tilt_axis` (not a coordinate axis),
    turned 20° about z and shifted so the floor sits about 1.3 m below the origin, as in a capture whose
    frame is the first camera's."""
    rng = np.random.default_rng(seed)
    sx, sy, sz = size
    boxes = [
        ((0, 0, 0), (sx, sy, sz)),  # the room, seen from inside
        ((1.2, 1.0, 0.71), (2.8, 1.9, 0.75)),  # table top
        *[((x, y, 0), (x + 0.05, y + 0.05, 0.71)) for x in (1.25, 2.7) for y in (1.05, 1.8)],  # legs
        ((sx - 0.45, 0.5, 0), (sx, 1.5, 1.95)),  # tall cabinet against a wall: reaches into the slice
        ((0.3, sy - 0.95, 0), (2.3, sy, 0.45)),  # sofa
        ((2.3, 2.3, 2.45), (2.7, 2.7, 2.55)),  # lamp under the ceiling
    ]
    faces = []  # (origin, u edge, v edge, normal axis) of every visible face
    for b, (lo, hi) in enumerate(boxes):
        lo, hi = np.array(lo, float), np.array(hi, float)
        for axis in range(3):
            for side in (0, 1):
                if b > 0 and axis == 2 and side == 0 and lo[2] == 0:
                    continue  # furniture bottoms on the floor are hidden
                u_ax, v_ax = [a for a in range(3) if a != axis]
                origin = lo.copy()
                origin[axis] = (lo, hi)[side][axis]
                u = np.zeros(3)
                v = np.zeros(3)
                u[u_ax] = hi[u_ax] - lo[u_ax]
                v[v_ax] = hi[v_ax] - lo[v_ax]
                if b == 0 and axis == 2:  # partial floor or ceiling: a strip along the y = 0 wall
                    v *= floor_fraction if side == 0 else ceiling_fraction
                faces.append((origin, u, v))
    areas = np.array([np.linalg.norm(np.cross(u, v)) for _, u, v in faces])
    n_out = round(outlier_ratio * n_points)
    n_surf = n_points - n_out
    which = rng.choice(len(faces), n_surf, p=areas / areas.sum())
    st = rng.random((n_surf, 2))
    origins = np.array([f[0] for f in faces])[which]
    us = np.array([f[1] for f in faces])[which]
    vs = np.array([f[2] for f in faces])[which]
    surface = origins + st[:, :1] * us + st[:, 1:] * vs

    eye = np.array([sx / 2, sy / 2, 1.4])
    ray = surface - eye
    rng_m = np.linalg.norm(ray, axis=1, keepdims=True)
    ray /= rng_m
    surface = surface + ray * rng.normal(0, 1, (n_surf, 1)) * noise_scale * (0.002 + 0.0015 * rng_m)

    thirds = [n_out // 3, n_out // 3, n_out - 2 * (n_out // 3)]
    volume = rng.uniform((-0.5, -0.5, -0.5), (sx + 0.5, sy + 0.5, sz + 0.5), (thirds[0], 3))
    src = surface[rng.choice(n_surf, thirds[1])]
    src_ray = (src - eye) / np.linalg.norm(src - eye, axis=1, keepdims=True)
    flying = src + src_ray * rng.uniform(0.1, 1.0, (thirds[1], 1)) * rng.choice([-1, 1], (thirds[1], 1))
    direction = rng.normal(size=(thirds[2], 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    far = eye + direction * rng.uniform(5, 20, (thirds[2], 1))
    points = np.concatenate([surface, volume, flying, far])
    outliers = np.r_[np.zeros(n_surf, bool), np.ones(n_out, bool)]
    boxes_arr = np.array(boxes, float)
    far_outliers = outliers & (surface_distance(points, boxes_arr) > FAR_M)

    order = rng.permutation(len(points))
    points, outliers, far_outliers = points[order], outliers[order], far_outliers[order]
    axis = np.asarray(tilt_axis, float) / np.linalg.norm(tilt_axis)
    tilt = Rotation.from_rotvec(math.radians(tilt_deg) * axis)
    yaw = Rotation.from_euler("z", 20, degrees=True)
    transform = np.eye(4)
    transform[:3, :3] = (yaw * tilt).as_matrix()
    transform[:3, 3] = (-1.0, 0.5, -1.3)
    cloud_pts = points @ transform[:3, :3].T + transform[:3, 3]
    rgb = rng.integers(0, 256, (len(points), 3), dtype=np.uint8) if colors else None
    truth = RoomTruth(transform, boxes_arr, sz, outliers, far_outliers)
    return Cloud(cloud_pts, rgb), truth


def residual_tilt_deg(levelling: NDArray[np.float64], truth: RoomTruth) -> float:
    """Angle between the room's true up and z after levelling."""
    up = levelling[:3, :3] @ truth.room_to_input[:3, :3] @ np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(min(1.0, up[2])))


def to_room_frame(
    points: NDArray[np.float64], levelling: NDArray[np.float64], truth: RoomTruth
) -> NDArray[np.float64]:
    """Levelled-frame points (N, 3) back in the true room frame."""
    full = levelling @ truth.room_to_input
    return (points - full[:3, 3]) @ full[:3, :3]


# ------------------------------------------------------------------------------- handheld degradation


@dataclass(frozen=True)
class HandheldDegradation:
    """What `degrade_handheld` did to a room cloud (the parameters are drawn per room)."""

    spacing_m: float
    """Random subsampling to one point per cube of this edge (3-5 cm)."""
    cut_m: float
    """Nothing above this height over the floor (1.3-2.0 m): no ceiling, walls end there."""
    unseen_share: float
    """Share of the wall length left unseen (0.2-0.3), in two spans."""
    floor_share: float
    """Share of the floor's extent that was seen (0.3-0.7, one side of a line)."""
    unseen: NDArray[np.float64]
    """(U, 4) the unseen pieces of the walls (x0 y0 x1 y1)."""
    seen: NDArray[np.float64]
    """(S, 4) the seen pieces of the walls."""
    wall_tops_m: NDArray[np.float64] | None = None
    """(M,) with `wall_tops_m` given: the height over the floor each wall was seen up to (`cut_m` is then
    the lowest of them)."""


def _perimeter_pieces(walls: NDArray, spans: list[tuple[float, float]]) -> tuple[NDArray, NDArray]:
    """The walls cut at the perimeter positions of `spans` ((start, end) along the concatenated walls,
    metres): (pieces inside a span (U, 4), pieces outside (S, 4))."""
    L = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
    start = np.concatenate([[0.0], np.cumsum(L)[:-1]])
    inside, outside = [], []
    for w, s0, length in zip(walls, start, L, strict=True):
        cuts = {0.0, float(length)}
        for a, b in spans:
            cuts |= {float(np.clip(a - s0, 0, length)), float(np.clip(b - s0, 0, length))}
        cuts_sorted = sorted(cuts)
        for t0, t1 in itertools.pairwise(cuts_sorted):
            if t1 - t0 <= 1e-9:
                continue
            mid = s0 + 0.5 * (t0 + t1)
            p0 = w[:2] + (w[2:] - w[:2]) * t0 / length
            p1 = w[:2] + (w[2:] - w[:2]) * t1 / length
            (inside if any(a <= mid <= b for a, b in spans) else outside).append([*p0, *p1])
    return np.array(inside).reshape(-1, 4), np.array(outside).reshape(-1, 4)


def degrade_handheld(
    points: NDArray[np.float64],
    walls: NDArray[np.float64],
    rng: np.random.Generator,
    floor_z: float = 0.0,
    wall_tops_m: tuple[float, float] | None = None,
) -> tuple[NDArray[np.float64], HandheldDegradation]:
    """A room cloud (N, 3, z up, metres) degraded the way handheld and phone scans are: nothing above a
    random cut between 1.3 and 2.0 m over `floor_z` (no ceiling), 20-30 % of the wall length (`walls`
    (M, 4), the room's inner faces in order round the room) unseen in two spans (everything within 0.5 m
    of them in plan view removed), the floor seen only on one side of a random line (30-70 % of it),
    then randomly subsampled to one point per 3-5 cm cube. Returns (points, what was done).

    With `wall_tops_m` (low, high), each wall is seen up to its own height, drawn in that range, instead
    (a handheld capture's coverage: the issue's real rooms show 1.2-2.7 m), and every point up to the
    height of the wall nearest it in plan view; the ceiling stays unseen (nothing within 0.15 m under the
    cloud's top). The other draws are those of the single cut, so the unseen spans and the floor are the
    same."""
    walls = np.asarray(walls, dtype=np.float64).reshape(-1, 4)
    spacing = float(rng.uniform(0.03, 0.05))
    cut = float(rng.uniform(1.3, 2.0))
    unseen_share = float(rng.uniform(0.2, 0.3))
    floor_share = float(rng.uniform(0.3, 0.7))
    total = float(np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]).sum())
    # two spans, apart from each other, sharing the unseen length at random
    first = float(rng.uniform(0.3, 0.7)) * unseen_share * total
    second = unseen_share * total - first
    a = float(rng.uniform(0, total))
    b = a + first + float(rng.uniform(0.1, 0.4)) * total
    spans = []
    for s, length in ((a, first), (b, second)):
        s = s % total
        if s + length <= total:
            spans.append((s, s + length))
        else:
            spans += [(s, total), (0.0, s + length - total)]
    unseen, seen = _perimeter_pieces(walls, spans)

    pts = np.asarray(points, dtype=np.float64)
    h = pts[:, 2] - floor_z
    keep = h <= cut if wall_tops_m is None else np.ones(len(pts), dtype=bool)
    if len(unseen):
        keep &= _plan_distances(pts, unseen).min(axis=1) >= 0.5
    floor = h < 0.05
    phi = float(rng.uniform(0, 2 * np.pi))
    along = pts[:, :2] @ np.array([math.cos(phi), math.sin(phi)])
    if floor.any():
        keep &= ~floor | (along <= np.quantile(along[floor], floor_share))
    tops = None
    if wall_tops_m is not None:
        tops = np.minimum(rng.uniform(*wall_tops_m, len(walls)), float(np.quantile(h, 0.999)) - 0.15)
        keep &= h <= tops[_plan_distances(pts, walls).argmin(axis=1)]
        cut = float(tops.min())
    out = random_subsample(pts[keep], spacing, rng)
    return out, HandheldDegradation(spacing, cut, unseen_share, floor_share, unseen, seen, tops)


def _plan_distances(points: NDArray[np.float64], segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, M) plan-view distances of the points (N, 3) to the segments (M, 4), 20 000 points at a time."""
    from tasks.lines import point_segment_distances

    return np.concatenate(
        [point_segment_distances(points[k : k + 20000, :2], segments) for k in range(0, len(points), 20000)]
    )


def random_subsample(
    points: NDArray[np.float64], spacing_m: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """One random point (N, 3) of each cube of `spacing_m` that holds any: a handheld scan's sparse
    spacing."""
    order = rng.permutation(len(points))
    cells = np.floor(points[order] / spacing_m).astype(np.int64)
    _, first_idx = np.unique(cells, axis=0, return_index=True)
    return points[np.sort(order[first_idx])]


def wall_labels(
    points: NDArray[np.float64], walls: NDArray[np.float64], tol_m: float = 0.05
) -> NDArray[np.str_]:
    """(N,) "wall" for points within `tol_m` (plan view) of a wall face and above the floor's 5 cm,
    "other" for the rest: the labelled points a real dataset would give (doors and windows leave no
    points here)."""
    from tasks.lines import point_segment_distances

    d = np.full(len(points), np.inf)
    for k in range(0, len(points), 20000):
        d[k : k + 20000] = point_segment_distances(points[k : k + 20000, :2], walls).min(axis=1)
    return np.where((d <= tol_m) & (points[:, 2] > 0.05), "wall", "other")
