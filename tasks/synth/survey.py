"""Assemble a complete synthetic survey folder (PIPELINE.md "Survey folder" and "Truth") from a seed.

    survey.yaml
    plan/plan.png                      evacuation plan of the AS-PLANNED building, m_per_px known
    calibration/ir, rgb, flat          chessboard views and flat-target disparity frames (RGB-D profiles)
    track/track.csv                    foot-mounted IMU track with drift: t_ns,x,y (plan frame)
    rooms/<id>/capture.mcap            RGB-D rooms and the hallway (ROS 2 messages, zstd chunks)
    rooms/<id>/cloud.ply               the TLS-scanned room (registered, plan frame)
    truth/walls.parquet, walls.geojson, plan_walls.parquet, rooms.geojson, changes.parquet,
    truth/planned_walls.parquet, planned_rooms.geojson   what plan/plan.png draws (as planned)
    truth/poses/<id>.parquet, calibration.json, track.csv, overview.png

Every random draw comes from ``numpy.random.default_rng`` streams derived from (seed, purpose, room), and
no file carries a time of generation, so the same seed gives byte-identical files.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import shapely
import yaml
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from shapely.geometry import Point, Polygon
from shapely.ops import nearest_points

from tasks.artefacts import (
    CHANGES_SCHEMA,
    PLAN_WALLS_SCHEMA,
    POSES_SCHEMA,
    SEGMENT_FIELDS,
    write_bytes,
    write_geojson,
    write_json,
    write_ply_points,
    write_png,
    write_table,
)
from tasks.config import load_sensor_profile
from tasks.synth.building import Building, RoomSpec, generate_building
from tasks.synth.plan_raster import PlanRasterConfig, render_overview, render_plan
from tasks.synth.plan_raster import _opening_gap as opening_gap  # how the plan draws doors and walls
from tasks.synth.plan_raster import _wall_polygon as wall_outline
from tasks.synth.track import TrackConfig, TrackLeg, survey_track, walk_time_ns, walkable_area

TRUTH_WALLS_SCHEMA = pa.schema([*SEGMENT_FIELDS, ("room_id", pa.string())])
"""truth/walls.parquet: inner wall faces per room, plan frame."""

_SURVEY_ORDER = ("r1", "r2", "r3", "r4", "r5", "hall")
"""The order the surveyor visits the rooms (west to east, north then south, the corridor last)."""
_PRIORITY = ("r1", "r5", "r2", "r3", "r4")
"""Which rooms besides the hallway a reduced survey keeps first: an RGB-D and the TLS room, then the
other shapes."""
_SURVEY_PARTS = ("survey.yaml", "plan", "calibration", "rooms", "track", "truth")
"""What generate_survey writes under its output folder (and removes when overwriting)."""
_STREAM = {"walk": 1, "render": 2, "tls": 3, "track": 4, "calibration": 5}


@dataclass(frozen=True)
class SurveyConfig:
    """Sizes of a synthetic survey."""

    frames_mini: int = 24
    """Frames per RGB-D room (and the hallway) at size "mini"."""
    frames_full: tuple[int, int] = (20, 60)
    """Range of frames per room at size "full" (grows with the room's perimeter)."""
    frames_full_per_m: float = 2.0
    """Frames per metre of room perimeter at size "full"."""
    tls_step_deg_mini: float = 1.2
    """Angular step of the TLS scan at size "mini" (a modest cloud)."""
    tls_step_deg_full: float = 0.4
    """Angular step of the TLS scan at size "full"."""
    tls_height_m: float = 1.5
    """Height of the TLS scanner centre above the floor."""
    tls_stations: int = 2
    """Scanner stations per TLS room (registered into one cloud)."""
    t0_ns: int = 1_700_000_000_000_000_000
    """Time of the first track position (ns since the epoch; fixed for determinism)."""
    settle_s: float = 5.0
    """Time between arriving at a room's start and the first frame (s)."""
    max_walk_attempts: int = 6
    """New random walks tried when a walk leaves a room's clearance."""


def _rng(seed: int, stream: str, index: int = 0) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), 7919, _STREAM[stream], int(index)]))


def _room_index(building: Building, room_id: str) -> int:
    return [r.id for r in building.rooms].index(room_id)


def select_rooms(building: Building, rooms: int | None) -> list[RoomSpec]:
    """The surveyed rooms in visiting order: ``rooms`` rooms besides the hallway (1..5, None: all), an
    RGB-D room and the TLS room first; the hallway is always surveyed."""
    ids = list(_PRIORITY)
    if rooms is not None:
        if not 1 <= rooms <= len(ids):
            raise ValueError(f"rooms (besides the hallway) must be within 1..{len(ids)}, got {rooms}")
        ids = ids[:rooms]
    return [building.room(rid) for rid in _SURVEY_ORDER if rid in [*ids, "hall"]]


def _n_frames(room: RoomSpec, size: str, cfg: SurveyConfig) -> int:
    if size == "mini":
        return cfg.frames_mini
    lo, hi = cfg.frames_full
    return int(np.clip(round(room.polygon.length * cfg.frames_full_per_m), lo, hi))


def _walk(room: RoomSpec, n: int, seed: int, index: int, cfg: SurveyConfig):
    from tasks.synth.walk import plan_walk

    last = None
    for attempt in range(cfg.max_walk_attempts):
        try:
            return plan_walk(
                room.free_space,
                room.height_m,
                n,
                _rng(seed, "walk", 100 * index + attempt),
                texture_poor=room.capture == "hallway",
            )
        except ValueError as exc:  # a jittered walk can graze the clearance: draw another
            last = exc
    raise ValueError(f"no valid walk in room {room.id} after {cfg.max_walk_attempts} attempts: {last}")


def tls_stations(
    room: RoomSpec, furniture: list[Polygon], n: int, height_m: float, clearance_m: float = 0.6
) -> NDArray[np.float64]:
    """Scanner positions (n, 3): spread along the room's long axis, each at the floor point nearest to
    its target that is at least ``clearance_m`` from walls and furniture footprints (tripod space)."""
    poly = room.polygon.difference(shapely.union_all(furniture)) if furniture else room.polygon
    poly = poly.buffer(-clearance_m)
    if poly.is_empty:
        raise ValueError(f"room {room.id} has no space for a TLS station {clearance_m} m from its walls")
    rect = room.polygon.minimum_rotated_rectangle
    c = np.asarray(rect.exterior.coords)[:4]
    e1, e2 = c[1] - c[0], c[2] - c[1]
    axis = e1 if np.linalg.norm(e1) >= np.linalg.norm(e2) else e2
    centre = c.mean(axis=0)
    out = []
    for k in range(n):
        target = Point(centre + axis * ((k + 0.5) / n - 0.5) * 0.6)
        p = nearest_points(poly, target)[0] if not poly.contains(target) else target
        out.append([p.x, p.y, height_m])
    return np.asarray(out, dtype=np.float64)


def _pose_columns(poses: NDArray[np.float64], t_ns: NDArray[np.int64], method: str) -> dict:
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # x y z w
    q = q * np.where(q[:, 3:4] < 0, -1.0, 1.0)  # one sign convention: qw >= 0
    return {
        "frame_id": np.arange(len(poses), dtype=np.int32),
        "t_ns": np.asarray(t_ns, dtype=np.int64),
        "qw": q[:, 3],
        "qx": q[:, 0],
        "qy": q[:, 1],
        "qz": q[:, 2],
        "tx": poses[:, 0, 3],
        "ty": poses[:, 1, 3],
        "tz": poses[:, 2, 3],
        "method": np.full(len(poses), method),
    }


def _track_csv(t_ns: NDArray[np.int64], xy: NDArray[np.float64]) -> bytes:
    lines = ["t_ns,x,y"] + [f"{int(t)},{x:.4f},{y:.4f}" for t, (x, y) in zip(t_ns, xy, strict=True)]
    return ("\n".join(lines) + "\n").encode()


def planned_truth(building: Building) -> tuple[NDArray[np.float64], NDArray[np.float64], list[dict]]:
    """What the plan raster draws: as-planned wall centrelines (W, 4) metres cut at the planned doors
    (a door is a gap in the drawing; a window is drawn as part of its wall), their thickness (W,) m, and
    GeoJSON features of the as-planned rooms (centreline cell minus the drawn walls, so up to the
    middle of its door gaps; room_id and plan_room label)."""
    doors = [op for op in building.planned_openings if op.kind == "door"]
    segs, thick = [], []
    for w in building.planned_walls:
        rest = w.line
        for op in doors:
            if w.line.distance(Point(op.centre)) < 1e-6:
                rest = rest.difference(
                    shapely.geometry.LineString([(op.x0, op.y0), (op.x1, op.y1)]).buffer(
                        1e-9, cap_style="flat"
                    )
                )
        for g in getattr(rest, "geoms", [rest]):
            if g.length > 1e-6:
                (x0, y0), (x1, y1) = g.coords[0], g.coords[-1]
                segs.append((round(x0, 9), round(y0, 9), round(x1, 9), round(y1, 9)))
                thick.append(w.thickness_m)
    # the room reaches into its door gaps up to the door's centreline, where the cell boundary runs
    drawn = shapely.union_all([wall_outline(w) for w in building.planned_walls]).difference(
        shapely.union_all([opening_gap(op) for op in doors])
    )
    features = []
    for r in building.rooms:
        free = r.cell.difference(drawn)
        poly = max(getattr(free, "geoms", [free]), key=lambda g: g.area)
        poly = shapely.set_precision(poly, 1e-9)
        rings = [[list(c) for c in poly.exterior.coords]] + [
            [list(c) for c in i.coords] for i in poly.interiors
        ]
        features.append(
            {
                "type": "Feature",
                "properties": {"room_id": r.id, "plan_room": r.label},
                "geometry": {"type": "Polygon", "coordinates": rings},
            }
        )
    return np.array(segs, dtype=np.float64).reshape(-1, 4), np.array(thick, dtype=np.float64), features


def write_truth(folder: Path, building: Building, surveyed: list[RoomSpec]) -> None:
    """truth/walls.parquet + .geojson, plan_walls.parquet, rooms.geojson, changes.parquet (PIPELINE.md),
    planned_walls.parquet and planned_rooms.geojson (`planned_truth`)."""
    ids = {r.id for r in surveyed}
    walls = [w for w in building.truth_walls if w[4] in ids]
    write_table(
        folder / "walls.parquet",
        {
            "x0": np.array([w[0] for w in walls], dtype=np.float64),
            "y0": np.array([w[1] for w in walls], dtype=np.float64),
            "x1": np.array([w[2] for w in walls], dtype=np.float64),
            "y1": np.array([w[3] for w in walls], dtype=np.float64),
            "room_id": [w[4] for w in walls],
        },
        TRUTH_WALLS_SCHEMA,
    )
    write_geojson(
        folder / "walls.geojson",
        [
            {
                "type": "Feature",
                "properties": {"room_id": w[4]},
                "geometry": {"type": "LineString", "coordinates": [[w[0], w[1]], [w[2], w[3]]]},
            }
            for w in walls
        ],
        crs_note="plan",
    )
    bw = building.built_walls
    write_table(
        folder / "plan_walls.parquet",
        {
            "x0": [w.x0 for w in bw],
            "y0": [w.y0 for w in bw],
            "x1": [w.x1 for w in bw],
            "y1": [w.y1 for w in bw],
            "thickness_m": [w.thickness_m for w in bw],
        },
        PLAN_WALLS_SCHEMA,
    )
    features = []
    for r in building.rooms:
        rings = [[list(c) for c in r.polygon.exterior.coords]] + [
            [list(c) for c in i.coords] for i in r.polygon.interiors
        ]
        features.append(
            {
                "type": "Feature",
                "properties": {
                    "room_id": r.id,
                    "height_m": r.height_m,
                    "plan_room": r.label,
                    "shape": r.shape,
                    "capture": r.capture,
                    "surveyed": r.id in ids,
                },
                "geometry": {"type": "Polygon", "coordinates": rings},
            }
        )
    write_geojson(folder / "rooms.geojson", features, crs_note="plan")
    p_segs, p_thick, p_rooms = planned_truth(building)
    write_table(
        folder / "planned_walls.parquet",
        {
            "x0": p_segs[:, 0],
            "y0": p_segs[:, 1],
            "x1": p_segs[:, 2],
            "y1": p_segs[:, 3],
            "thickness_m": p_thick,
        },
        PLAN_WALLS_SCHEMA,
    )
    write_geojson(folder / "planned_rooms.geojson", p_rooms, crs_note="plan")
    ch = building.changes
    write_table(
        folder / "changes.parquet",
        {
            "x0": [c.x0 for c in ch],
            "y0": [c.y0 for c in ch],
            "x1": [c.x1 for c in ch],
            "y1": [c.y1 for c in ch],
            "kind": [c.kind for c in ch],
            "room_id": [c.room_id for c in ch],
        },
        CHANGES_SCHEMA,
    )


def generate_survey(
    out: Path,
    seed: int,
    rooms: int | None = None,
    profile: str = "kinect_v1",
    size: str = "mini",
    cfg: SurveyConfig | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a whole synthetic survey folder to ``out`` (created; existing files are overwritten) and
    return ``out``. ``rooms`` limits the surveyed rooms besides the hallway (1..5; None: all five; the
    hallway is always surveyed);
    ``profile`` is the sensor of the RGB-D rooms ("tls": every room is a registered TLS cloud); ``size``
    "mini" (320x240, 24 frames per room) or "full" (640x480, 20-60 frames per room).

    A non-empty ``out`` is an error unless ``overwrite``: then the folders and files a survey consists of
    (survey.yaml, plan, calibration, rooms, track, truth) are removed first, so no stale room survives."""
    from tasks.synth.calibration_set import write_calibration_set
    from tasks.synth.capture import write_capture_mcap
    from tasks.synth.sensor import render_rgbd, render_tls_cloud

    cfg = cfg or SurveyConfig()
    if size not in ("mini", "full"):
        raise ValueError(f"size must be 'mini' or 'full', got {size!r}")
    prof = load_sensor_profile(profile)
    all_tls = prof.get("kind") == "cloud"
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise FileExistsError(f"output folder {out} is not empty (pass overwrite to replace a survey)")
        for name in _SURVEY_PARTS:
            part = out / name
            if part.is_dir():
                shutil.rmtree(part)
            elif part.exists():
                part.unlink()
    out.mkdir(parents=True, exist_ok=True)
    building = generate_building(seed)
    surveyed = select_rooms(building, rooms)
    tcfg = TrackConfig()
    area = walkable_area(building, tcfg.clearance_m)

    plan = render_plan(building, PlanRasterConfig())
    write_png(out / "plan" / "plan.png", plan.image)

    entries, legs = [], []
    trajectories: dict[str, NDArray[np.float64]] = {}
    scanners: dict[str, NDArray[np.float64]] = {}
    here, t_free = np.asarray(building.you_are_here, dtype=float), cfg.t0_ns
    step = cfg.tls_step_deg_mini if size == "mini" else cfg.tls_step_deg_full
    for room in surveyed:
        index = _room_index(building, room.id)
        folder = out / "rooms" / room.id
        folder.mkdir(parents=True, exist_ok=True)
        if all_tls or room.capture == "tls":
            floor_items = [f.footprint for f in building.furniture if f.room_id == room.id and f.z0_m < 1.0]
            pos = tls_stations(room, floor_items, cfg.tls_stations, cfg.tls_height_m)
            start = t_free + walk_time_ns(area, here, pos[0, :2], tcfg) + int(cfg.settle_s * 1e9)
            # stand at each station for a scan, walk to the next
            times, xy = [], []
            t = start
            for k, p in enumerate(pos):
                if k:
                    t += walk_time_ns(area, pos[k - 1, :2], p[:2], tcfg)
                times += [t, t + int(tcfg.tls_station_s * 1e9)]
                xy += [p[:2], p[:2]]
                t = times[-1]
            points, colours = render_tls_cloud(building.mesh, pos, _rng(seed, "tls", index), step_deg=step)
            write_ply_points(folder / "cloud.ply", points, colours)
            poses = np.tile(np.eye(4), (len(pos), 1, 1))
            poses[:, :3, 3] = pos
            write_table(
                out / "truth" / "poses" / f"{room.id}.parquet",
                _pose_columns(poses, np.asarray(times[::2], dtype=np.int64), "tls_station"),
                POSES_SCHEMA,
            )
            scanners[room.id] = pos
            legs.append(TrackLeg(room.id, np.asarray(times, dtype=np.int64), np.asarray(xy)))
            entries.append({"id": room.id, "capture": f"rooms/{room.id}/cloud.ply", "plan_room": room.label})
            here, t_free = pos[-1, :2], times[-1]
            continue
        poses, t_walk = _walk(room, _n_frames(room, size, cfg), seed, index, cfg)
        start = t_free + walk_time_ns(area, here, poses[0, :2, 3], tcfg) + int(cfg.settle_s * 1e9)
        t_ns = (start + (t_walk - t_walk[0])).astype(np.int64)
        render_rng = _rng(seed, "render", index)

        def frames(poses=poses, t_ns=t_ns, room=room, render_rng=render_rng) -> Iterator:
            for pose, t in zip(poses, t_ns, strict=True):
                rgb, depth = render_rgbd(
                    building.mesh, pose, prof, size, render_rng, texture_poor=room.capture == "hallway"
                )
                yield int(t), rgb, depth

        write_capture_mcap(folder / "capture.mcap", frames(), prof, size)
        write_table(
            out / "truth" / "poses" / f"{room.id}.parquet", _pose_columns(poses, t_ns, "truth"), POSES_SCHEMA
        )
        trajectories[room.id] = poses[:, :3, 3]
        legs.append(TrackLeg(room.id, t_ns, poses[:, :2, 3]))
        entries.append({"id": room.id, "capture": f"rooms/{room.id}/capture.mcap", "plan_room": room.label})
        here, t_free = poses[-1, :2, 3], int(t_ns[-1])

    track = survey_track(building, legs, cfg.t0_ns, _rng(seed, "track"), tcfg)
    write_bytes(out / "track" / "track.csv", _track_csv(track.t_ns, track.xy))
    write_bytes(out / "truth" / "track.csv", _track_csv(track.t_ns, track.xy_true))

    doc: dict = {
        "name": f"synth-{size}-seed{seed}",
        "sensor": profile,
        "plan": {"image": "plan/plan.png", "m_per_px": plan.m_per_px},
    }
    if not all_tls:
        calib = write_calibration_set(out / "calibration", prof, size, _rng(seed, "calibration"))
        write_json(out / "truth" / "calibration.json", calib)
        doc["calibration"] = "calibration"
    doc["track"] = "track/track.csv"
    doc["rooms"] = entries
    doc["truth"] = "truth"
    write_bytes(out / "survey.yaml", yaml.safe_dump(doc, sort_keys=False).encode())
    write_truth(out / "truth", building, surveyed)
    overview = render_overview(building, plan, trajectories, scanners, track.xy, track.xy_true)
    write_png(out / "truth" / "overview.png", overview)
    return out
