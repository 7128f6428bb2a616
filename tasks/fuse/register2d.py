"""2D registration of a room model (inner wall faces) to its plan room (thesis 7.1, eq 7.1-7.10).

- **Faces.** The plan room's outline (free space up to the drawn walls) gives the targets: its edges, each
  with the normal pointing into the room, minus the short edges drawn across door gaps.
- **Shell.** The model walls on the convex hull of the model (thesis fig 7.3 a), plus walls with a side
  looking out of the model (a notch of a non-convex room, which the hull cuts across). Partitions added
  inside the room are neither: they never pull the registration.
- **Correspondences** (fig 7.3 b): for every shell wall, among the faces of similar orientation whose
  inward normal agrees with the wall's, the closest one, preferring faces that the ray from the model's
  centroid through the wall's midpoint meets.
- **Optimal fit** (fig 7.4 right): first the rotation, the length-weighted mean of the orientation
  differences (eq 7.1-7.4) over the walls that agree with their weighted median, then the translation
  by Gauss-Newton on the distances of the walls' midpoints to their faces' lines (eq 7.5-7.10), doors
  that coincide in model and plan as extra observations; iterated until nothing moves. The `best_fit` (fig 7.4 left, joint rotation and translation on the
  walls' end points: springs) is here for comparison: an asymmetric room is turned by the springs' torque
  and, fitted to centrelines, pulled to the centre of its plan room; the optimal fit on the faces is not.
- **Approximate** registration: the model's centroid on the plan room's centroid; the orientation from
  the track, else every candidate turn (the four 90 degree turns of the model's principal wall direction
  onto the plan's, and the turns between any two principal directions for non-Manhattan rooms); the best
  fit score wins.

Convention: a placement maps room-frame points p to plan-frame points R(theta) p + t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from tasks.fuse.config import FuseConfig
from tasks.lines import (
    Segments,
    angle_difference,
    angles,
    as_segments,
    lengths,
    midpoints,
    point_segment_distances,
    rotate_segments,
    sample_segments,
    transform_segments,
)


@dataclass(frozen=True)
class Placement:
    """A rigid 2D transform room frame -> plan frame: p -> R(theta) p + t."""

    theta: float
    """Rotation (radians)."""
    t: tuple[float, float]
    """Translation (metres)."""

    @property
    def rotation(self) -> NDArray[np.float64]:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.array([[c, -s], [s, c]])

    def points(self, xy: NDArray) -> NDArray[np.float64]:
        """(N, 2) points mapped into the plan frame."""
        return np.asarray(xy, dtype=np.float64).reshape(-1, 2) @ self.rotation.T + np.asarray(self.t)

    def segments(self, segments: Segments) -> Segments:
        """(N, 4) segments mapped into the plan frame."""
        return transform_segments(as_segments(segments), self.theta, np.asarray(self.t))

    def polygon(self, poly: Polygon) -> Polygon:
        """A shapely polygon mapped into the plan frame."""
        r = self.rotation
        return shapely.affinity.affine_transform(
            poly, [r[0, 0], r[0, 1], r[1, 0], r[1, 1], self.t[0], self.t[1]]
        )

    def then(self, theta: float, centre: NDArray, shift: NDArray) -> Placement:
        """This placement followed by a turn by theta about `centre` (plan frame) and a shift."""
        c, s = math.cos(theta), math.sin(theta)
        r = np.array([[c, -s], [s, c]])
        t = r @ (np.asarray(self.t) - centre) + centre + np.asarray(shift)
        return Placement(self.theta + theta, (float(t[0]), float(t[1])))

    def matrix(self) -> list[list[float]]:
        """3x3 homogeneous matrix (for manifests)."""
        r = self.rotation
        return [[r[0, 0], r[0, 1], self.t[0]], [r[1, 0], r[1, 1], self.t[1]], [0.0, 0.0, 1.0]]


IDENTITY = Placement(0.0, (0.0, 0.0))


@dataclass(frozen=True)
class Faces:
    """Target lines of the registration: plan-frame segments with the unit normal pointing into their room."""

    segments: Segments
    """(F, 4)."""
    inward: NDArray[np.float64]
    """(F, 2)."""
    room: tuple[str, ...] = ()
    """(F,) the plan room of each face."""

    def __len__(self) -> int:
        return len(self.segments)

    @staticmethod
    def concat(parts: list[Faces]) -> Faces:
        if not parts:
            return Faces(np.zeros((0, 4)), np.zeros((0, 2)))
        return Faces(
            np.concatenate([p.segments for p in parts]),
            np.concatenate([p.inward for p in parts]),
            tuple(r for p in parts for r in p.room),
        )


def polygon_faces(
    polygon: Polygon,
    room: str = "",
    doors: Segments | None = None,
    simplify_m: float = 0.02,
    centrelines: Segments | None = None,
) -> Faces:
    """The edges of a room outline with inward normals, minus edges drawn across a door gap (an edge whose
    midpoint lies within 0.3 m of a door segment, over its span). With the plan's wall `centrelines`, an
    edge takes the orientation of the parallel wall (within 5 degrees) it lies against, turned about its
    midpoint: the outline's vertices carry the raster's pixel jitter (a 2 cm skew over 4 m is 0.3
    degrees), the vectorized wall does not."""
    poly = orient(polygon.simplify(simplify_m, preserve_topology=True), 1.0)  # interior on the left
    xy = np.asarray(poly.exterior.coords)
    segs = np.column_stack([xy[:-1], xy[1:]])
    segs = segs[lengths(segs) > 1e-6]
    d = segs[:, 2:] - segs[:, :2]
    inward = np.column_stack([-d[:, 1], d[:, 0]]) / lengths(segs)[:, None]
    keep = np.ones(len(segs), dtype=bool)
    if doors is not None and len(doors):
        mid = midpoints(segs)
        doors = as_segments(doors)
        a, u = doors[:, :2], doors[:, 2:] - doors[:, :2]
        uu = np.maximum((u**2).sum(1), 1e-12)
        t = ((mid[:, None, :] - a[None]) * u[None]).sum(-1) / uu[None]
        dist = point_segment_distances(mid, doors)
        keep = ~((dist < 0.3) & (t > 0.0) & (t < 1.0)).any(axis=1)
    segs, inward = segs[keep], inward[keep]
    if centrelines is not None and len(centrelines) and len(segs):
        segs, inward = _snap_orientation(segs, inward, as_segments(centrelines))
    return Faces(segs, inward, (room,) * len(segs))


def _snap_orientation(
    segs: Segments, inward: NDArray, centrelines: Segments, max_offset_m: float = 0.5
) -> tuple[Segments, NDArray]:
    """Faces turned about their midpoints to the orientation of the nearest parallel centreline."""
    fa, ca = angles(segs), angles(centrelines)
    diff = angle_difference(ca[None, :], fa[:, None])
    dist = point_segment_distances(midpoints(segs), centrelines)
    cost = np.where((np.abs(diff) <= math.radians(5)) & (dist <= max_offset_m), dist, np.inf)
    j = np.argmin(cost, axis=1)
    ok = np.isfinite(cost[np.arange(len(segs)), j])
    turn = np.where(ok, diff[np.arange(len(segs)), j], 0.0)
    out = rotate_segments(segs, turn)
    c, s = np.cos(turn), np.sin(turn)
    nin = np.column_stack([c * inward[:, 0] - s * inward[:, 1], s * inward[:, 0] + c * inward[:, 1]])
    return out, nin


# ------------------------------------------------------------------------------------------------ the model


def inward_normals(walls: Segments, polygon: Polygon | None, centre: NDArray | None = None) -> NDArray:
    """(N, 2) unit normal of every wall pointing into the room: the side where the room polygon is (probed
    5 cm beside the midpoint), else the side facing the centre."""
    walls = as_segments(walls)
    d = walls[:, 2:] - walls[:, :2]
    n = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(lengths(walls), 1e-12)[:, None]
    mid = midpoints(walls)
    if centre is None:
        centre = mid.mean(axis=0) if len(mid) else np.zeros(2)
    side = np.sign(((np.asarray(centre) - mid) * n).sum(1))
    if polygon is not None and not polygon.is_empty:
        left = shapely.contains_xy(polygon, *(mid + 0.05 * n).T)
        right = shapely.contains_xy(polygon, *(mid - 0.05 * n).T)
        side = np.where(left & ~right, 1.0, np.where(right & ~left, -1.0, side))
    side[side == 0] = 1.0
    return n * side[:, None]


def shell_mask(
    walls: Segments, tol_m: float, min_length_m: float = 0.3, reach_m: float = 50.0
) -> NDArray[np.bool_]:
    """(N,) walls of the outer shell: both ends within tol_m of the convex hull's boundary (thesis fig
    7.3 a), or a side that looks out of the model (perpendicular rays from the quarter points hit no other
    wall within reach_m: the notch of an L-shaped room). Walls shorter than min_length_m (the end of a
    partition) are never shell."""
    walls = as_segments(walls)
    if len(walls) == 0:
        return np.zeros(0, dtype=bool)
    ends = np.concatenate([walls[:, :2], walls[:, 2:]])
    hull = shapely.convex_hull(shapely.multipoints(ends))
    on_hull = np.zeros(len(walls), dtype=bool)
    if hull.geom_type == "Polygon":
        ring = hull.exterior
        d0 = shapely.distance(shapely.points(walls[:, :2]), ring)
        d1 = shapely.distance(shapely.points(walls[:, 2:]), ring)
        dm = shapely.distance(shapely.points(midpoints(walls)), ring)
        on_hull = (d0 <= tol_m) & (d1 <= tol_m) & (dm <= tol_m)
    return (on_hull | _free_side(walls, reach_m)) & (lengths(walls) >= min_length_m)


def _free_side(walls: Segments, reach_m: float) -> NDArray[np.bool_]:
    """(N,) walls with one side from which perpendicular rays (at 1/4, 1/2, 3/4 of the wall) hit no other
    wall, at least two of the three."""
    n_walls = len(walls)
    out = np.zeros(n_walls, dtype=bool)
    if n_walls < 2:
        return np.ones(n_walls, dtype=bool)
    # walls slightly thickened: a ray must not slip out between two walls that nearly meet
    lines = shapely.buffer(shapely.linestrings(walls.reshape(-1, 2, 2)), 0.05)
    tree = shapely.STRtree(lines)
    d = walls[:, 2:] - walls[:, :2]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / np.maximum(lengths(walls), 1e-12)[:, None]
    for i in range(n_walls):
        for side in (1.0, -1.0):
            free = 0
            for f in (0.25, 0.5, 0.75):
                p = walls[i, :2] + f * d[i] + 0.01 * side * normal[i]
                ray = shapely.linestrings([p, p + side * reach_m * normal[i]])
                hits = [j for j in tree.query(ray, predicate="intersects") if j != i]
                free += not hits
            if free >= 2:
                out[i] = True
                break
    return out


def principal_directions(walls: Segments, max_dirs: int = 3, tol_deg: float = 5.0) -> list[float]:
    """Dominant wall orientations (radians in [0, pi)), by length, longest first: the orientation histogram's
    peaks, each at least tol_deg from the others."""
    walls = as_segments(walls)
    if len(walls) == 0:
        return [0.0]
    th, w = angles(walls), lengths(walls)
    out: list[float] = []
    order = np.argsort(-w)
    for i in order:
        if all(abs(float(angle_difference(th[i], o))) > math.radians(tol_deg) for o in out):
            near = np.abs(angle_difference(th, th[i])) <= math.radians(tol_deg)
            c = np.sum(w[near] * np.cos(2 * th[near]))
            s = np.sum(w[near] * np.sin(2 * th[near]))
            out.append(float(np.mod(0.5 * math.atan2(s, c), math.pi)))
        if len(out) == max_dirs:
            break
    return out


# --------------------------------------------------------------------------------------- correspondences


def correspond(
    walls: Segments, inward: NDArray, centre: NDArray, faces: Faces, angle_tol: float
) -> NDArray[np.intp]:
    """(N,) index of the face each (plan-frame) wall corresponds to, -1 where none: faces within angle_tol
    (radians) of its orientation whose inward normal agrees with the wall's; the closest to the wall's
    midpoint, a face the ray from `centre` through the midpoint meets (lengthened by 0.5 m at both ends)
    counting 1 m closer."""
    n_walls = len(walls)
    out = np.full(n_walls, -1, dtype=np.intp)
    if n_walls == 0 or len(faces) == 0:
        return out
    fa, wa = angles(faces.segments), angles(walls)
    ok = np.abs(angle_difference(fa[None, :], wa[:, None])) <= angle_tol
    ok &= (inward @ faces.inward.T) > 0.0
    mid = midpoints(walls)
    dist = point_segment_distances(mid, faces.segments)
    hit = _ray_hits(np.asarray(centre, dtype=np.float64), mid, faces.segments, 0.5)
    cost = np.where(ok, dist - 1.0 * hit, np.inf)
    best = np.argmin(cost, axis=1)
    found = np.isfinite(cost[np.arange(n_walls), best])
    out[found] = best[found]
    return out


def _ray_hits(centre: NDArray, targets: NDArray, segments: Segments, extend_m: float) -> NDArray[np.bool_]:
    """(N, F) whether the ray from centre through targets[n] meets segment f lengthened by extend_m."""
    a, b = segments[:, :2], segments[:, 2:]
    u = (b - a) / np.maximum(lengths(segments), 1e-12)[:, None]
    a, b = a - extend_m * u, b + extend_m * u
    r = targets - centre  # (N, 2)
    s = b - a  # (F, 2)
    den = r[:, None, 0] * s[None, :, 1] - r[:, None, 1] * s[None, :, 0]
    qp = a[None, :, :] - centre[None, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ray = (qp[..., 0] * s[None, :, 1] - qp[..., 1] * s[None, :, 0]) / den
        t_seg = (qp[..., 0] * r[:, None, 1] - qp[..., 1] * r[:, None, 0]) / den
    return (np.abs(den) > 1e-12) & (t_ray > 0) & (t_seg >= 0) & (t_seg <= 1)


# ------------------------------------------------------------------------------------------------ fitting


@dataclass(frozen=True)
class DoorPair:
    """A door seen in the model (room frame) and the plan door it should coincide with (plan frame)."""

    model_centre: tuple[float, float]
    plan_centre: tuple[float, float]
    direction: tuple[float, float]
    """Unit vector along the plan door's wall (the constraint acts along it)."""
    width_m: float


@dataclass(frozen=True)
class Fit:
    """Result of one fine registration."""

    placement: Placement
    matched: NDArray[np.intp]
    """(S,) face of every shell wall (-1: none)."""
    residual_m: NDArray[np.float64]
    """(S,) signed distance of every shell wall's midpoint to its face's line (NaN: unmatched)."""
    angle_residual_deg: NDArray[np.float64]
    """(S,) orientation difference face - wall after the fit (NaN: unmatched)."""
    score: float
    """Share of the shell length within fit_tol_m of a face of the same orientation."""
    iterations: int
    converged: bool
    doors_used: int = 0
    extra: dict = field(default_factory=dict)

    @property
    def rms_m(self) -> float:
        r = self.residual_m[np.isfinite(self.residual_m)]
        return float(np.sqrt((r**2).mean())) if len(r) else float("nan")


def _translation_step(
    mid: NDArray,
    w: NDArray,
    faces: Faces,
    matched: NDArray,
    doors: list[tuple[NDArray, NDArray, NDArray, float]],
) -> NDArray[np.float64]:
    """Eq 7.5-7.9: one Gauss-Newton step of the translation minimizing the length-weighted distances of
    the wall midpoints to their faces' lines, plus door rows (model door centre onto the plan's, along
    the wall). The signed distance is used: it equals eq 7.5's absolute value on the room side and keeps
    the derivative defined at zero. A direction no observation fixes (a corridor without end walls) gets
    no update (minimum-norm solution)."""
    m = matched >= 0
    seg = faces.segments[matched[m]]
    n = faces.inward[matched[m]]
    f = ((mid[m] - seg[:, :2]) * n).sum(1)  # f_i(X_T0, Y_T0)
    rows_a, rows_l, rows_p = [n], [-f], [w[m]]
    for model_c, plan_c, u, weight in doors:
        rows_a.append(u[None])
        rows_l.append(np.array([float((plan_c - model_c) @ u)]))
        rows_p.append(np.array([weight]))
    a, l_obs, p = np.concatenate(rows_a), np.concatenate(rows_l), np.concatenate(rows_p)
    if len(a) == 0:
        return np.zeros(2)
    n_mat = a.T @ (p[:, None] * a)
    return np.linalg.pinv(n_mat, rcond=1e-6) @ (a.T @ (p * l_obs))


def optimal_fit(
    shell: Segments,
    inward: NDArray,
    centre: NDArray,
    faces: Faces,
    start: Placement,
    cfg: FuseConfig,
    doors: list[DoorPair] | None = None,
    refine: bool = False,
    first_gate_m: float = math.inf,
) -> Fit:
    """The thesis' optimal (constrained) fit from `start`: per iteration, correspondences, the rotation
    from the length-weighted orientation differences (eq 7.4, about the model's centroid), then the
    Gauss-Newton translation (eq 7.9, 7.10) with door constraints. A door pair is gated like a wall: once
    converging, a door whose model centre lies farther than the gate from its plan door's along the wall
    is dropped (a door detected only in part, a plan door drawn off: a corridor's few constraints along
    its axis must not be pulled by one of them). With `refine` the start is a converged fit (adding the
    doors to it): the converged window and gate apply from the first iteration, so a door drawn off
    cannot drag the room away from its walls before the gate sees it. `first_gate_m` bounds the first
    iteration's gate for a start already known to be close (a room registered in the plan frame)."""
    shell = as_segments(shell)
    w = lengths(shell)
    placement = start
    converged = False
    it = 0
    for it in range(1, cfg.max_iterations + 1):
        tol = math.radians(cfg.approx_angle_tol_deg if it == 1 and not refine else cfg.angle_tol_deg)
        moved = placement.segments(shell)
        nin = inward @ placement.rotation.T
        c = placement.points(centre)[0]
        matched = correspond(moved, nin, c, faces, tol)
        gate = cfg.max_residual_m if refine else _GATES_M[min(it, len(_GATES_M)) - 1] or cfg.max_residual_m
        gate = min(gate, first_gate_m)
        matched = _gate(moved, faces, matched, gate)
        m = matched >= 0
        if not m.any():
            break
        d_alpha = angle_difference(angles(faces.segments[matched[m]]), angles(moved[m]))
        d_theta = rotation_update(d_alpha, w[m], math.radians(cfg.rotation_outlier_deg))
        placement = placement.then(d_theta, c, np.zeros(2))
        # the walls that agree on one translation (a wall modelled on a wardrobe's front has no face
        # of its own and must not pull the ones that have)
        moved = placement.segments(shell)
        options = collinear_faces(moved, faces, matched, cfg.max_residual_m, 2 * cfg.plan_simplify_m)
        matched = consensus(midpoints(moved), w, faces, matched, cfg.consensus_tol_m, options, cfg.fit_tol_m)
        shift = np.zeros(2)
        for _ in range(5):  # Gauss-Newton (eq 7.9, 7.10); linear in t, so it settles at once
            moved = placement.segments(shell)
            door_rows = _door_rows(doors or [], placement, gate)
            step = _translation_step(midpoints(moved), w, faces, matched, door_rows)
            placement = placement.then(0.0, np.zeros(2), step)
            shift += step
            if np.hypot(*step) < cfg.converge_m * 0.1:
                break
        settled = refine or it >= len(_GATES_M)
        if settled and abs(math.degrees(d_theta)) < cfg.converge_deg and np.hypot(*shift) < cfg.converge_m:
            converged = True
            break
    used = len(_door_rows(doors or [], placement, cfg.max_residual_m))
    return _finish(shell, inward, centre, faces, placement, cfg, it, converged, used)


def collinear_faces(
    walls: Segments,
    faces: Faces,
    matched: NDArray[np.intp],
    max_offset_m: float,
    min_offset_m: float = 0.04,
    min_overlap_m: float = 0.25,
    angle_tol_deg: float = 5.0,
) -> list[NDArray[np.intp]]:
    """(N,) for every (plan-frame) wall, the faces it may stand for: its matched face first, then every
    other face of the same orientation (within angle_tol_deg) and inward normal whose line lies between
    min_offset_m (the plan raster's jitter: faces closer than that are the same face) and max_offset_m
    of the matched face's, and which the wall runs beside over at least min_overlap_m. A
    straight wall along a plan wall drawn in collinear pieces of different thickness (the vectorizer gave
    one piece the thickness of the wall it runs into) has a face on each piece, a few centimetres apart;
    which of them is right is for the room's other walls to say (`consensus`). Unmatched walls: empty."""
    walls = as_segments(walls)
    out: list[NDArray[np.intp]] = []
    if len(faces) == 0:
        return [np.zeros(0, dtype=np.intp) for _ in range(len(walls))]
    fa = angles(faces.segments)
    a, d = faces.segments[:, :2], faces.segments[:, 2:] - faces.segments[:, :2]
    length = np.maximum(lengths(faces.segments), 1e-12)
    u = d / length[:, None]
    for i, k in enumerate(matched):
        if k < 0:
            out.append(np.zeros(0, dtype=np.intp))
            continue
        par = np.abs(angle_difference(fa, fa[k])) <= math.radians(angle_tol_deg)
        par &= (faces.inward @ faces.inward[k]) > 0.0
        offset = np.abs(((a - a[k]) * faces.inward[k]).sum(1))
        s0 = ((walls[i, :2] - a) * u).sum(1)
        s1 = ((walls[i, 2:] - a) * u).sum(1)
        overlap = np.minimum(np.maximum(s0, s1), length) - np.maximum(np.minimum(s0, s1), 0.0)
        ok = par & (offset > min_offset_m) & (offset <= max_offset_m) & (overlap >= min_overlap_m)
        ok[k] = False
        out.append(np.concatenate([[k], np.flatnonzero(ok)]).astype(np.intp))
    return out


def consensus(
    mid: NDArray,
    w: NDArray,
    faces: Faces,
    matched: NDArray[np.intp],
    tol_m: float,
    options: list[NDArray[np.intp]] | None = None,
    close_m: float = 0.0,
) -> NDArray[np.intp]:
    """The correspondences that agree on one translation (the others set to -1): every translation that
    puts two non-parallel walls (or one wall, along its normal) on their faces is tried, and the one that
    brings the most wall length within tol_m of its face wins (ties: the smaller sum of squared
    residuals, then the smaller shift). A least-squares translation over every wall is pulled by a
    minority of walls without a plan counterpart (furniture modelled as a wall, a changed wall) until
    the walls that do match drift out of the residual gate; the largest consistent set is not. With
    `options` (collinear_faces) a wall may stand for any of its faces: at every translation tried it
    counts with the one nearest to it, and the winner's choice is returned (a plan face drawn a few
    centimetres off its collinear neighbour is not followed when the room's other walls disagree).
    With `close_m`, ties on that length go to the most wall length within close_m, and a wall farther
    than close_m from its face at the winner is dropped where another wall facing the same way lies
    within close_m of its own: a wall 10 cm off a face the plan drew too thick lies within tol_m of
    every candidate and would otherwise pull the least-squares translation by centimetres, while the
    two ends of a corridor modelled 1 % long stay and centre it."""
    m = np.flatnonzero(matched >= 0)
    if len(m) < 2 or not math.isfinite(tol_m):
        return matched
    if options is None:
        options = [np.array([k]) for k in matched]
    wall = np.concatenate([np.full(len(options[i]), i) for i in m])  # the wall of every observation
    face = np.concatenate([options[i] for i in m])
    seg = faces.segments[face]
    n = faces.inward[face]
    f = ((mid[wall] - seg[:, :2]) * n).sum(1)  # residual after a shift s: f + n . s
    cands = [np.zeros(2)] + [-f[i] * n[i] for i in range(len(face))]
    i, j = np.triu_indices(len(face), 1)
    det = n[i, 0] * n[j, 1] - n[i, 1] * n[j, 0]
    ok = (np.abs(det) > math.sin(math.radians(30))) & (wall[i] != wall[j])
    i, j, det = i[ok], j[ok], det[ok]
    # solve [n_i; n_j] s = [-f_i; -f_j]
    sx = (-f[i] * n[j, 1] + f[j] * n[i, 1]) / det
    sy = (-n[i, 0] * f[j] + n[j, 0] * f[i]) / det
    s = np.concatenate([np.array(cands), np.column_stack([sx, sy])])
    r_obs = np.abs(f[None, :] + s @ n.T)  # (C, O)
    # per wall, its nearest face (the first on ties: the matched one)
    starts = np.concatenate([[0], np.cumsum([len(options[k]) for k in m])[:-1]])
    r = np.minimum.reduceat(r_obs, starts, axis=1)  # (C, M)
    ww = w[m]
    inl = r <= tol_m
    weight = (inl * ww[None]).sum(1)
    close = ((r <= close_m) * ww[None]).sum(1)
    ssr = (np.where(inl, r, 0.0) ** 2 * ww[None]).sum(1)
    order = np.lexsort((np.hypot(s[:, 0], s[:, 1]), ssr, -np.round(close, 9), -np.round(weight, 9)))
    win = order[0]
    keep = inl[win]
    if close_m > 0:
        # a wall off its face while a wall facing the same way sits on its own: the plan drew one of
        # them off (a stretched or shrunk model moves opposite faces apart, not faces facing one way)
        near = r[win] <= close_m
        nm = faces.inward[matched[m]]
        same_way = (nm @ nm.T) > math.cos(math.radians(5.0))
        keep = keep & (near | ~(same_way & near[None, :]).any(axis=1))
    out = matched.copy()
    for q, k in enumerate(m):
        if not keep[q]:
            out[k] = -1
            continue
        own = r_obs[win, starts[q] : starts[q] + len(options[k])]
        out[k] = options[k][int(np.argmin(own))]
    return out


def rotation_update(d_alpha: NDArray, weights: NDArray, outlier: float) -> float:
    """Eq 7.4, the length-weighted mean of the orientation differences (radians), over the walls whose
    difference lies within `outlier` of their weighted median: a plan face vectorized a degree off (the
    slanted wall of a raster plan) is an outlier among walls that agree within a tenth of one, and must
    not turn the room by a quarter of a degree."""
    d_alpha, weights = np.asarray(d_alpha, dtype=np.float64), np.asarray(weights, dtype=np.float64)
    order = np.argsort(d_alpha)
    cum = np.cumsum(weights[order])
    median = float(d_alpha[order][np.searchsorted(cum, 0.5 * cum[-1])])
    keep = np.abs(d_alpha - median) <= outlier
    return float((weights[keep] * d_alpha[keep]).sum() / weights[keep].sum())


_GATES_M = (math.inf, 0.5, None)
"""Largest residual of a kept correspondence in iterations 1, 2 and after (None: the config's): the start may
be a metre off, the converged fit must not be pulled by a face the model does not have (a changed wall, a
window the plan drew thick)."""


def _gate(walls: Segments, faces: Faces, matched: NDArray[np.intp], gate_m: float) -> NDArray[np.intp]:
    """Correspondences whose wall midpoint lies farther than gate_m from its face's line dropped."""
    out = matched.copy()
    m = out >= 0
    if m.any() and math.isfinite(gate_m):
        seg = faces.segments[out[m]]
        f = np.abs(((midpoints(walls[m]) - seg[:, :2]) * faces.inward[out[m]]).sum(1))
        idx = np.flatnonzero(m)
        out[idx[f > gate_m]] = -1
    return out


def _door_rows(
    doors: list[DoorPair], placement: Placement, gate_m: float = math.inf
) -> list[tuple[NDArray, NDArray, NDArray, float]]:
    """(placed model centre, plan centre, direction, weight) of every door pair whose centres lie within
    gate_m of each other along the wall."""
    rows = []
    for d in doors:
        model_c = placement.points(np.asarray(d.model_centre))[0]
        plan_c = np.asarray(d.plan_centre, dtype=np.float64)
        u = np.asarray(d.direction, dtype=np.float64)
        if abs(float((plan_c - model_c) @ u)) <= gate_m:
            rows.append((model_c, plan_c, u, d.width_m))
    return rows


def _finish(
    shell: Segments,
    inward: NDArray,
    centre: NDArray,
    faces: Faces,
    placement: Placement,
    cfg: FuseConfig,
    iterations: int,
    converged: bool,
    doors_used: int,
) -> Fit:
    moved = placement.segments(shell)
    nin = inward @ placement.rotation.T
    matched = correspond(moved, nin, placement.points(centre)[0], faces, math.radians(cfg.angle_tol_deg))
    matched = _gate(moved, faces, matched, cfg.max_residual_m)
    # a wall along collinear faces a few centimetres apart reports the one it stands on (as fitted)
    mid = midpoints(moved)
    for i, opts in enumerate(
        collinear_faces(moved, faces, matched, cfg.max_residual_m, 2 * cfg.plan_simplify_m)
    ):
        if len(opts) > 1:
            r = np.abs(((mid[i] - faces.segments[opts, :2]) * faces.inward[opts]).sum(1))
            matched[i] = opts[int(np.argmin(r))]
    res = np.full(len(shell), np.nan)
    ang = np.full(len(shell), np.nan)
    m = matched >= 0
    if m.any():
        seg = faces.segments[matched[m]]
        res[m] = ((midpoints(moved[m]) - seg[:, :2]) * faces.inward[matched[m]]).sum(1)
        ang[m] = np.degrees(angle_difference(angles(seg), angles(moved[m])))
    return Fit(
        placement,
        matched,
        res,
        ang,
        fit_score(moved, faces, cfg.fit_tol_m),
        iterations,
        converged,
        doors_used,
    )


def fit_score(walls: Segments, faces: Faces, tol_m: float, step_m: float = 0.02) -> float:
    """Share of the walls' length (plan frame) lying within tol_m of a face within 5 degrees of the same
    orientation."""
    walls = as_segments(walls)
    if len(walls) == 0 or len(faces) == 0:
        return 0.0
    pts, owner = sample_segments(walls, step_m)
    d = point_segment_distances(pts, faces.segments)
    par = np.abs(angle_difference(angles(walls)[:, None], angles(faces.segments)[None, :])) <= math.radians(5)
    d = np.where(par[owner], d, np.inf)
    near = d.min(axis=1) <= tol_m
    w = lengths(walls)[owner]
    n_per = np.bincount(owner, minlength=len(walls))
    return float((near * w / n_per[owner]).sum() / lengths(walls).sum())


def best_fit(
    shell: Segments, faces: Faces, matched: NDArray, start: Placement, iterations: int = 20
) -> Placement:
    """The 'best fit' of fig 7.4 (left), for comparison: rotation and translation estimated together by
    Gauss-Newton on the distances of every wall's end points to its face's line (springs at the ends),
    with the given correspondences."""
    shell = as_segments(shell)
    m = matched >= 0
    pts = np.concatenate([shell[m, :2], shell[m, 2:]])
    seg = np.concatenate([faces.segments[matched[m]]] * 2)
    n = np.concatenate([faces.inward[matched[m]]] * 2)
    w = np.concatenate([lengths(shell[m]) / 2] * 2)
    theta, t = start.theta, np.asarray(start.t, dtype=np.float64)
    for _ in range(iterations):
        c, s = math.cos(theta), math.sin(theta)
        r = np.array([[c, -s], [s, c]])
        dr = np.array([[-s, -c], [c, -s]])
        q = pts @ r.T + t
        f = ((q - seg[:, :2]) * n).sum(1)
        a = np.column_stack([((pts @ dr.T) * n).sum(1), n])
        step = np.linalg.lstsq(a * np.sqrt(w)[:, None], -f * np.sqrt(w), rcond=None)[0]
        theta, t = theta + step[0], t + step[1:]
        if np.abs(step).max() < 1e-10:
            break
    return Placement(float(theta), (float(t[0]), float(t[1])))


# ---------------------------------------------------------------------------------- approximate + fine


def candidate_turns(model_walls: Segments, faces: Faces, manhattan_tol_deg: float = 3.0) -> list[float]:
    """Turns (radians) worth trying without a track: the model's principal wall direction onto the plan
    room's, in the four 90 degree steps; for non-Manhattan rooms also the turns between any principal
    direction of the model and any of the plan's (both ways round)."""
    md = principal_directions(model_walls)
    pd = principal_directions(faces.segments)
    base = float(angle_difference(pd[0], md[0]))
    turns = [base + k * math.pi / 2 for k in range(4)]
    manhattan = all(
        min(abs(float(angle_difference(d, md[0] + k * math.pi / 2))) for k in (0, 1))
        <= math.radians(manhattan_tol_deg)
        for d in md
    )
    if not manhattan:
        for a in md:
            for b in pd:
                d = float(angle_difference(b, a))
                turns += [d, d + math.pi]
    out: list[float] = []
    for turn in turns:
        turn = math.atan2(math.sin(turn), math.cos(turn))
        if all(abs(math.atan2(math.sin(turn - o), math.cos(turn - o))) > math.radians(2) for o in out):
            out.append(turn)
    return out


def centroid_start(theta: float, model_centre: NDArray, plan_centre: NDArray) -> Placement:
    """The approximate registration: turned by theta, the model's centroid on the plan room's."""
    c, s = math.cos(theta), math.sin(theta)
    t = np.asarray(plan_centre) - np.array([[c, -s], [s, c]]) @ np.asarray(model_centre)
    return Placement(theta, (float(t[0]), float(t[1])))


def rotation_candidates(shell: Segments, faces: Faces, start: Placement, window_deg: float) -> list[float]:
    """Rotation corrections (radians, within +-window_deg) that bring the model's principal wall
    direction onto one of the plan faces' principal directions: the starts the fine fit tries from an
    approximate orientation (smallest first)."""
    md = principal_directions(start.segments(shell), max_dirs=1)[0]
    out = []
    for b in principal_directions(faces.segments, max_dirs=4):
        for k in range(4):
            d = float(angle_difference(b + k * math.pi / 2, md))
            if abs(d) <= math.radians(window_deg) and all(abs(d - o) > math.radians(1) for o in out):
                out.append(d)
    return sorted(out, key=abs) or [0.0]


def fine_register(
    shell: Segments,
    inward: NDArray,
    centre: NDArray,
    faces: Faces,
    start: Placement,
    cfg: FuseConfig,
    doors: list[DoorPair] | None = None,
) -> Fit:
    """The optimal fit from an approximate start that may be off by up to +-45 degrees and +-1 m: the
    rotation corrections that put the principal wall direction onto a plan direction are each tried (the
    thesis' 'most similar orientation'), each also from the start shifted by half a metre along the plan's
    principal directions (a wall may first pair with the parallel face of a notch or an alcove); the best
    fit score wins (ties: the first, i.e. the smallest correction without shift)."""
    best: Fit | None = None
    c = start.points(centre)[0]
    axis = principal_directions(faces.segments, max_dirs=1)[0]
    u = np.array([math.cos(axis), math.sin(axis)])
    shifts = [np.zeros(2)] + [
        sign * cfg.start_shift_m * v for v in (u, np.array([-u[1], u[0]])) for sign in (1, -1)
    ]
    for d in rotation_candidates(shell, faces, start, cfg.approx_angle_tol_deg):
        for shift in shifts:
            fit = optimal_fit(shell, inward, centre, faces, start.then(d, c, shift), cfg, doors)
            if best is None or fit.score > best.score + 1e-3:
                best = fit
    assert best is not None
    return best
