"""Placing every captured room into the plan: correspondence, approximate and fine registration (thesis
7.1), with the reason for every room that cannot be placed. Pure: loaded inputs in, placements out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Polygon

from tasks.fuse.config import FuseConfig
from tasks.fuse.correspond import Correspondence, PlanRoom, RoomEvidence, correspond_rooms
from tasks.fuse.openings import Coverage, Door, coverage, face_spread, find_doors, surfaces, tops
from tasks.fuse.register2d import (
    IDENTITY,
    DoorPair,
    Faces,
    Fit,
    Placement,
    candidate_turns,
    centroid_start,
    fine_register,
    inward_normals,
    optimal_fit,
    polygon_faces,
    shell_mask,
)
from tasks.lines import Segments, as_segments, room_polygons


@dataclass(frozen=True)
class RoomInput:
    """One captured room as the fuse stage reads it (its own frame unless `in_plan_frame`)."""

    id: str
    walls: Segments
    origin: NDArray[np.str_]
    support: NDArray[np.float64]
    height_m: float = 2.5
    in_plan_frame: bool = False
    """The IMU-track fallback registered it in the plan frame already: its start is kept."""
    plan_room: str | None = None
    """survey.yaml's label."""
    points: NDArray[np.float64] | None = None
    """(N, 3) the room's cloud in the walls' frame, z up (doors, coverage)."""
    floor_z: float = 0.0
    ceiling_z: float = 2.5
    camera_txy: NDArray[np.float64] | None = None
    """(K, 3) t_ns, x, y of the camera in the walls' frame (the track's orientation)."""


@dataclass(frozen=True)
class RoomModel:
    """What registration needs from a room model, derived once."""

    polygon: Polygon | None
    centre: NDArray[np.float64]
    inward: NDArray[np.float64]
    shell: NDArray[np.bool_]
    doors: list[Door]
    coverage: Coverage | None
    surfaces: Coverage | None = None
    """Where the cloud shows something standing (tasks.fuse.openings.surfaces), room frame."""
    face_spread_m: float = float("nan")
    """How crisp the capture's wall faces are (tasks.fuse.openings.face_spread)."""
    tops: Coverage | None = None
    """Where the cloud shows something just below the ceiling (tasks.fuse.openings.tops), room frame."""


def describe(room: RoomInput, cfg: FuseConfig) -> RoomModel:
    """The model's polygon (largest face of its walls), centroid, inward normals, shell, doors, coverage."""
    walls = as_segments(room.walls)
    polys = room_polygons(walls, tol=0.02)
    poly = polys[0] if polys else None
    centre = np.asarray(poly.centroid.coords[0]) if poly is not None else walls.reshape(-1, 2).mean(axis=0)
    inward = inward_normals(walls, poly, centre)
    doors: list[Door] = []
    cov, standing, spread, top = None, None, float("nan"), None
    if room.points is not None and len(room.points):
        doors = find_doors(
            room.points,
            room.floor_z,
            walls,
            inward,
            (cfg.door_min_m, cfg.door_max_m),
            min_through_share=cfg.door_through_share,
        )
        cov = coverage(room.points, room.floor_z, room.ceiling_z, 0.10)
        standing = surfaces(room.points, room.floor_z)
        spread = face_spread(room.points, room.floor_z, walls, inward)
        top = tops(room.points, room.ceiling_z, cfg.top_band_m)
    shell = shell_mask(walls, cfg.shell_tol_m)
    return RoomModel(poly, centre, inward, shell, doors, cov, standing, spread, top)


@dataclass(frozen=True)
class Placed:
    """A room's placement (or the reason it has none)."""

    room: str
    correspondence: Correspondence
    placement: Placement | None
    fit: Fit | None
    start: str
    """How the start was found: "plan frame" | "track" | "turns"."""
    reason: str = ""
    ambiguous: bool = False
    """Another turn fitted as well (a symmetric room without track or doors to tell)."""
    faces_rooms: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)


def track_positions(track: NDArray | None, camera_txy: NDArray | None) -> NDArray | None:
    """(K, 2) track positions (plan frame) at the camera's times, linearly interpolated; None without."""
    if track is None or camera_txy is None or len(track) < 2 or len(camera_txy) == 0:
        return None
    t = np.asarray(camera_txy)[:, 0]
    order = np.argsort(track[:, 0])
    tt, xy = track[order, 0], track[order, 1:3]
    inside = (t >= tt[0]) & (t <= tt[-1])
    if inside.sum() < 3:
        return None
    return np.column_stack([np.interp(t[inside], tt, xy[:, 0]), np.interp(t[inside], tt, xy[:, 1])])


def track_turn(camera_txy: NDArray, track_xy: NDArray) -> float | None:
    """Rotation (radians) of the camera path (walls' frame) onto the track (plan frame), by a 2D rigid
    fit; None when the path is too short to tell a direction (under 1 m across)."""
    src = np.asarray(camera_txy)[: len(track_xy), 1:3]
    if np.ptp(src, axis=0).max() < 1.0:
        return None
    ms, md = src.mean(axis=0), track_xy.mean(axis=0)
    h = (src - ms).T @ (track_xy - md)
    return math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])


def room_faces(
    plan_rooms: dict[str, PlanRoom], doors: Segments, centrelines: Segments, cfg: FuseConfig
) -> dict[str, Faces]:
    """The registration targets of every plan room."""
    return {
        pid: polygon_faces(p.polygon, pid, doors, cfg.plan_simplify_m, centrelines)
        for pid, p in plan_rooms.items()
    }


def door_pairs(
    model: RoomModel, walls: Segments, placement: Placement, plan_doors: Segments, cfg: FuseConfig
) -> list[DoorPair]:
    """Model doors that, placed, lie within door_match_m of a plan door along a parallel wall."""
    pairs = []
    plan_doors = as_segments(plan_doors)
    if len(plan_doors) == 0:
        return pairs
    centres = 0.5 * (plan_doors[:, :2] + plan_doors[:, 2:])
    for d in model.doors:
        c = placement.points(d.centre)[0]
        dist = np.hypot(*(centres - c).T)
        k = int(np.argmin(dist))
        u = plan_doors[k, 2:] - plan_doors[k, :2]
        u = u / max(float(np.hypot(*u)), 1e-12)
        seg = placement.segments(np.asarray(d.segment)[None])[0]
        v = (seg[2:] - seg[:2]) / max(float(np.hypot(*(seg[2:] - seg[:2]))), 1e-12)
        if dist[k] <= cfg.door_match_m and abs(float(u @ v)) >= math.cos(math.radians(10)):
            pairs.append(DoorPair(tuple(d.centre), tuple(centres[k]), tuple(u), d.width_m * cfg.door_weight))
    return pairs


def register_room(
    room: RoomInput,
    model: RoomModel,
    plan_room: PlanRoom,
    faces: dict[str, Faces],
    plan_doors: Segments,
    track: NDArray | None,
    cfg: FuseConfig,
) -> tuple[Fit, str, bool]:
    """The best fit of a room onto its plan room: (fit, how the start was found, whether another turn fitted
    as well)."""
    walls = as_segments(room.walls)
    shell = walls[model.shell] if model.shell.any() else walls
    inward = model.inward[model.shell] if model.shell.any() else model.inward
    own = faces[plan_room.id]
    plan_centre = np.asarray(plan_room.polygon.centroid.coords[0])
    if room.in_plan_frame:
        starts, how = [IDENTITY], "plan frame"
    else:
        turn = None
        pos = track_positions(track, room.camera_txy)
        if pos is not None and room.camera_txy is not None:
            turn = track_turn(room.camera_txy, pos)
        if turn is not None:
            starts, how = [centroid_start(turn, model.centre, plan_centre)], "track"
        else:
            starts = [centroid_start(t, model.centre, plan_centre) for t in candidate_turns(shell, own)]
            how = "turns"
    if room.in_plan_frame:
        # refined, not searched: the start is the plan frame within a few centimetres, and a corridor's
        # walls seen through its doors would drag it along its axis to where they meet some face
        fits = [
            optimal_fit(shell, inward, model.centre, own, IDENTITY, cfg, first_gate_m=cfg.plan_frame_gate_m)
        ]
    else:
        fits = [fine_register(shell, inward, model.centre, own, s, cfg) for s in starts]
    fits.sort(key=lambda f: -f.score)
    best = fits[0]
    close = [f for f in fits if f.score >= best.score - 0.02]
    ambiguous = len(close) > 1
    if ambiguous:
        # a symmetric room: the turn whose doors coincide with the plan's wins, then the smallest turn from
        # the capture's own frame (a registered scanner cloud's frame means something; a track-less
        # RGB-D room's does not, and the tie is reported)
        def rank(f: Fit) -> tuple[int, float]:
            turn = abs(math.atan2(math.sin(f.placement.theta), math.cos(f.placement.theta)))
            return (-len(door_pairs(model, walls, f.placement, plan_doors, cfg)), turn)

        close.sort(key=rank)
        best = close[0]
        ambiguous = rank(close[0])[0] == rank(close[1])[0]
    doors = door_pairs(model, walls, best.placement, plan_doors, cfg)
    if doors:
        refined = optimal_fit(shell, inward, model.centre, own, best.placement, cfg, doors, refine=True)
        if refined.score >= best.score - 0.02:
            best = refined
    return best, how, ambiguous


def place_rooms(
    rooms: list[RoomInput],
    plan_rooms: list[PlanRoom],
    centrelines: Segments,
    plan_doors: Segments,
    track: NDArray | None,
    cfg: FuseConfig,
) -> tuple[dict[str, Placed], dict[str, RoomModel]]:
    """Correspond and register every room; a room with no walls, no plan room or a poor fit is reported
    with its reason and the others still go on."""
    by_id = {p.id: p for p in plan_rooms}
    faces = room_faces(by_id, plan_doors, centrelines, cfg)
    models = {r.id: describe(r, cfg) for r in rooms if len(as_segments(r.walls))}
    cache: dict[tuple[str, str], Fit] = {}

    def fit(rid: str, pid: str) -> Fit:
        if (rid, pid) not in cache:
            room = next(r for r in rooms if r.id == rid)
            cache[(rid, pid)] = register_room(room, models[rid], by_id[pid], faces, plan_doors, track, cfg)[0]
        return cache[(rid, pid)]

    evidence = []
    for r in rooms:
        if r.id not in models:
            continue
        m = models[r.id]
        area = m.polygon.area if m.polygon is not None else None
        evidence.append(
            RoomEvidence(r.id, r.plan_room, track_positions(track, r.camera_txy), m.polygon, area)
        )
    corr = correspond_rooms(evidence, plan_rooms, lambda rid, pid: fit(rid, pid).score)
    out: dict[str, Placed] = {}
    for r in rooms:
        if r.id not in models:
            out[r.id] = Placed(
                r.id, Correspondence(r.id, None, None), None, None, "", "the room's walls are empty"
            )
            continue
        c = corr[r.id]
        if c.plan_room is None:
            out[r.id] = Placed(r.id, c, None, None, "", "no plan room: " + "; ".join(c.notes))
            continue
        best, how, ambiguous = register_room(
            r, models[r.id], by_id[c.plan_room], faces, plan_doors, track, cfg
        )
        if best.score < cfg.min_fit_score:
            out[r.id] = Placed(
                r.id,
                c,
                None,
                best,
                how,
                f"fit score {best.score:.2f} below {cfg.min_fit_score} on plan room {c.plan_room}",
            )
            continue
        out[r.id] = Placed(r.id, c, best.placement, best, how, "", ambiguous, (c.plan_room,))
    return out, models
