"""Walking trajectories of a person capturing a room with a hand-held RGB-D sensor.

The person walks a loop near the walls of the room, holding the sensor 1.2-1.6 m high and turning it
to face across the room (the opposite walls, seen whole from 2-4 m), so consecutive frames overlap for
sequential SfM (three-view overlap, which close-up views of the nearest wall lack) and the frames
together see every wall. In a texture-poor corridor the person looks ahead and sweeps
side to side instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Polygon


@dataclass(frozen=True)
class WalkConfig:
    """How the simulated surveyor walks."""

    wall_clearance_m: float = 0.5
    """Minimum distance of every camera position from the room polygon's boundary (m)."""
    loop_offset_share: float = 0.35
    """Offset of the loop from the walls as a share of the room's largest inscribed radius."""
    max_clearance_m: float = 1.0
    """Largest offset of the loop from the walls (m): the far walls stay within good Kinect range."""
    face_inwards: bool = True
    """Face across the room (the opposite walls, seen whole from 2-4 m) rather than the nearest wall."""
    height_range_m: tuple[float, float] = (1.2, 1.6)
    """Sensor height above the floor (m)."""
    pitch_deg: float = 0.0
    """Mean pitch (negative looks down)."""
    pitch_sweep_deg: float = 10.0
    """Amplitude of the up-and-down sweep a surveyor makes to cover the walls from floor to ceiling."""
    pitch_sweep_frames: float = 6.0
    """Frames per up-and-down sweep."""
    pitch_jitter_deg: float = 3.0
    """Amplitude of slow random pitch changes."""
    roll_jitter_deg: float = 2.0
    """Amplitude of slow random roll changes."""
    rotation_weight: float = 0.7
    """Share of the frame spacing given to turning (the rest to walking), 0..1."""
    smoothing_m: float = 1.0
    """Arc length over which the facing direction is smoothed around corners (m)."""
    walking_speed_m_s: float = 0.5
    """Walking speed used for the timestamps (m/s)."""
    turning_speed_deg_s: float = 30.0
    """Turning speed used for the timestamps (deg/s)."""
    room_sweep_deg: float = 12.0
    """Side-to-side sweep of the facing direction in a room, so that the walls beside the one faced (and
    the corners) are seen too (deg)."""
    room_sweep_frames: float = 6.0
    """Frames per side-to-side sweep cycle in a room."""
    corridor_sweep_deg: float = 25.0
    """Side-to-side sweep of the facing direction when walking a texture-poor corridor (deg)."""
    corridor_sweep_frames: int = 10
    """Frames per side-to-side sweep cycle in a corridor."""
    corridor_rotation_weight: float = 0.3
    """rotation_weight used in a corridor, where walking dominates."""
    t0_ns: int = 1_700_000_000_000_000_000
    """Timestamp of the first frame (ns since the epoch; fixed so that outputs are deterministic)."""


def _loop(room: Polygon, cfg: WalkConfig) -> LineString:
    """The loop the walker follows: the boundary of the room shrunk by the largest offset (up to the
    preferred clearance) that leaves one connected area of useful size."""
    min_clear = cfg.wall_clearance_m + 0.05  # margin for the position jitter
    inscribed = shapely.maximum_inscribed_circle(room)
    r_in = float(inscribed.length) if inscribed is not None else 0.0
    if r_in <= min_clear + 0.05:
        raise ValueError(
            f"room polygon is too narrow for a walk: largest inscribed radius {r_in:.2f} m, "
            f"needs more than {min_clear + 0.05:.2f} m"
        )
    offset = float(np.clip(cfg.loop_offset_share * r_in, min_clear, max(cfg.max_clearance_m, min_clear)))
    for off in np.linspace(offset, min_clear, 6):
        inner = room.buffer(-off, join_style="mitre")
        if inner.geom_type == "Polygon" and not inner.is_empty and inner.area > 1e-3:
            break
    else:
        inner = room.buffer(-min_clear, join_style="mitre")
        if inner.geom_type == "MultiPolygon":
            inner = max(inner.geoms, key=lambda g: g.area)
    ring = shapely.geometry.polygon.orient(inner, 1.0).exterior  # counter-clockwise
    return LineString(ring.coords)


def _smooth_periodic(values: NDArray, arc: NDArray, length: float, sigma: float) -> NDArray:
    """Gaussian smoothing of a periodic signal sampled at arc positions over a loop of `length`."""
    d = arc[:, None] - arc[None, :]
    d = (d + length / 2) % length - length / 2
    w = np.exp(-0.5 * (d / max(sigma, 1e-6)) ** 2)
    return (w @ values) / w.sum(axis=1)


def _rotation(yaw: float, pitch: float, roll: float) -> NDArray[np.float64]:
    """Camera-to-plan rotation of an OpenCV camera (x right, y down, z forward) looking along plan
    heading `yaw` (radians from +x), tilted up by `pitch` and rolled by `roll` about its optical axis."""
    forward = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), np.sin(pitch)])
    right = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    down = np.cross(forward, right)
    base = np.stack([right, down, forward], axis=1)
    cr, sr = np.cos(roll), np.sin(roll)
    return base @ np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])


def _slow_noise(rng: np.random.Generator, n: int, amplitude: float) -> NDArray[np.float64]:
    """A smooth random signal of n samples within about +-amplitude (sum of a few low harmonics)."""
    x = np.linspace(0.0, 1.0, n)
    out = np.zeros(n)
    for k in (1, 2, 3):
        out += rng.normal(0.0, 1.0 / k) * np.sin(2 * np.pi * k * x + rng.uniform(0, 2 * np.pi))
    return amplitude * out / 1.6


def plan_walk(
    room_polygon: Polygon,
    height_m: float,
    n_frames: int,
    rng: np.random.Generator,
    texture_poor: bool = False,
    cfg: WalkConfig = WalkConfig(),
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Camera-to-plan poses (n, 4, 4) of the IR/depth camera (OpenCV axes) and timestamps t_ns (n,) of a
    hand-held capture of the room (plan frame, floor at z = 0, room height height_m).

    Positions stay at least cfg.wall_clearance_m inside the polygon; heights within cfg.height_range_m;
    the facing direction turns smoothly once around the loop (about 360/n degrees per frame) so that every
    wall is seen. texture_poor (a corridor): face along the walk with a side-to-side sweep."""
    if not isinstance(room_polygon, Polygon) or room_polygon.is_empty or not room_polygon.is_valid:
        raise ValueError("room polygon must be a valid, non-empty shapely Polygon")
    if n_frames < 2:
        raise ValueError(f"a walk needs at least 2 frames, got {n_frames}")
    if not 1.0 < height_m < 20.0:
        raise ValueError(f"room height must be within 1..20 m, got {height_m}")
    loop = _loop(room_polygon, cfg)
    length = loop.length
    # dense samples of the loop with the outward normal direction, unwrapped
    m = max(400, 8 * n_frames)
    arc = np.linspace(0.0, length, m, endpoint=False)
    xy = np.array([loop.interpolate(a).coords[0] for a in arc])
    nxt = np.array([loop.interpolate((a + 0.01) % length).coords[0] for a in arc])
    tangent = np.arctan2(nxt[:, 1] - xy[:, 1], nxt[:, 0] - xy[:, 0])
    if texture_poor:
        facing = np.unwrap(tangent)
    else:
        # left of a counter-clockwise walk = across the room, right = the nearest wall
        facing = np.unwrap(tangent + (np.pi / 2 if cfg.face_inwards else -np.pi / 2))
    # a simple counter-clockwise loop turns once: the unwrapped facing minus its trend is periodic
    total = 2.0 * np.pi
    trend = facing[0] + total * arc / length
    facing = trend + _smooth_periodic(facing - trend, arc, length, cfg.smoothing_m)
    arc_ext = np.concatenate([arc, [length]])
    facing_ext = np.concatenate([facing, [facing[0] + total]])
    # frames at equal steps of a cost mixing walked distance and turned angle, from a random start
    turn = np.abs(np.diff(facing_ext))
    w = cfg.corridor_rotation_weight if texture_poor else cfg.rotation_weight
    cost = np.concatenate([[0.0], np.cumsum((1 - w) * np.diff(arc_ext) / length + w * turn / turn.sum())])
    c = rng.uniform(0.0, 1.0) + np.arange(n_frames) / n_frames
    laps = np.floor(c)
    a_in = np.interp(c - laps, cost, arc_ext)
    yaw = np.interp(a_in, arc_ext, facing_ext) + total * laps
    a = a_in % length
    pos = np.array([loop.interpolate(x).coords[0] for x in a])
    if texture_poor:
        yaw = yaw + np.radians(cfg.corridor_sweep_deg) * np.sin(
            2 * np.pi * np.arange(n_frames) / cfg.corridor_sweep_frames
        )
    else:
        yaw = yaw + np.radians(cfg.room_sweep_deg) * np.sin(
            2 * np.pi * np.arange(n_frames) / cfg.room_sweep_frames
        )
    # hand-held wobble, kept inside the clearance margin
    pos = pos + np.stack([_slow_noise(rng, n_frames, 0.04), _slow_noise(rng, n_frames, 0.04)], axis=1)
    lo, hi = cfg.height_range_m
    hi = min(hi, height_m - 0.3)
    z = rng.uniform(lo + 0.1, hi - 0.1) + _slow_noise(rng, n_frames, 0.08)
    z = np.clip(z, lo, hi)
    sweep = cfg.pitch_sweep_deg * np.sin(2 * np.pi * np.arange(n_frames) / cfg.pitch_sweep_frames)
    pitch = np.radians(cfg.pitch_deg + sweep + _slow_noise(rng, n_frames, cfg.pitch_jitter_deg))
    roll = np.radians(_slow_noise(rng, n_frames, cfg.roll_jitter_deg))
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    for i in range(n_frames):
        poses[i, :3, :3] = _rotation(yaw[i], pitch[i], roll[i])
        poses[i, :3, 3] = (pos[i, 0], pos[i, 1], z[i])
    inner = room_polygon.buffer(-cfg.wall_clearance_m)
    inside = shapely.contains_xy(inner, pos[:, 0], pos[:, 1])
    if not np.all(inside):
        raise ValueError(
            f"walk left the {cfg.wall_clearance_m} m clearance at frames {np.flatnonzero(~inside)}"
        )
    # timestamps from walking and turning speeds
    dist = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    dturn = np.degrees(np.abs(np.diff(yaw)))
    dt_s = np.maximum(dist / cfg.walking_speed_m_s, dturn / cfg.turning_speed_deg_s) + 0.2
    t_ns = cfg.t0_ns + np.concatenate([[0], np.cumsum(np.rint(dt_s * 1e9).astype(np.int64))])
    return poses, t_ns.astype(np.int64)
