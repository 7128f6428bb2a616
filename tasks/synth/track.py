"""A foot-mounted MEMS IMU track through the building: from the plan's "you are here" mark to each room.

The true walk follows shortest paths through the free space (a visibility graph over the walkable area,
doors included), one position per stride, and the captures' own camera paths while the surveyor records a
room. The measured track is dead reckoning of the true strides with the errors a ZUPT-aided foot-mounted
IMU shows (thesis 3.2.2.1, Peter et al. 2011): a constant stride-length scale error, an initial heading
error and a gyro z bias that performs a random walk, so the heading error grows with time and the
position error with distance walked.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import nearest_points

from tasks.synth.building import Building


@dataclass(frozen=True)
class TrackConfig:
    """Walking and IMU error model of the foot-mounted track."""

    stride_length_m: float = 1.3
    """Nominal stride (two steps; one position per stride of the instrumented foot)."""
    stride_period_s: float = 1.1
    """Time per stride."""
    clearance_m: float = 0.3
    """Distance kept from walls and furniture when planning the walk."""
    scale_error_sigma: float = 0.02
    """Standard deviation of the constant stride-length scale error (fraction)."""
    initial_heading_sigma_deg: float = 1.5
    """Standard deviation of the initial heading error."""
    gyro_bias_sigma_deg_s: float = 0.01
    """Standard deviation of the initial gyro z bias (deg/s)."""
    gyro_bias_walk_deg_s_sqrt_s: float = 0.001
    """Random-walk density of the gyro z bias (deg/s per sqrt(s))."""
    stride_noise_m: float = 0.01
    """White position noise per stride (m)."""
    tls_station_s: float = 90.0
    """Time the surveyor stands at each TLS station (s)."""


@dataclass(frozen=True)
class Track:
    """A foot-mounted IMU track: true and measured positions per stride, plan frame."""

    t_ns: NDArray[np.int64]
    """(N,) timestamps."""
    xy_true: NDArray[np.float64]
    """(N, 2) true positions (m)."""
    xy: NDArray[np.float64]
    """(N, 2) measured positions with drift (m), starting at the true start."""
    scale_error: float
    """The drawn stride-length scale error (fraction)."""
    initial_heading_error_deg: float
    """The drawn initial heading error."""


def walkable_area(building: Building, clearance_m: float) -> Polygon:
    """The floor a person can walk on: all rooms' free space joined through the door openings, shrunk by
    ``clearance_m`` (plan frame)."""
    parts = [r.polygon for r in building.rooms]
    for op in building.built_openings:
        if op.kind == "door" and len(op.room_ids) == 2:
            parts.append(
                LineString([(op.x0, op.y0), (op.x1, op.y1)]).buffer(
                    op.thickness_m / 2 + 0.05, cap_style="flat"
                )
            )
    area = shapely.union_all(parts)
    blocks = [f.footprint for f in building.furniture if f.kind not in ("lamp", "poster") and f.z0_m < 1.0]
    if blocks:
        area = area.difference(shapely.union_all(blocks))
    area = area.buffer(-clearance_m, join_style="mitre").simplify(0.02)
    if area.geom_type == "MultiPolygon":
        area = max(area.geoms, key=lambda g: g.area)
    return area


def shortest_path(area: Polygon, start, goal) -> NDArray[np.float64]:
    """Shortest polyline (K, 2) from start to goal inside ``area`` (visibility graph over its vertices).
    Points outside the area are first joined to its nearest point."""
    start, goal = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
    inner = area.buffer(-1e-4)
    head, tail = [], []
    s, g = start, goal
    if not area.contains(Point(s)):
        s = np.asarray(nearest_points(inner, Point(s))[0].coords[0])
        head = [start]
    if not area.contains(Point(g)):
        g = np.asarray(nearest_points(inner, Point(g))[0].coords[0])
        tail = [goal]
    cover = area.buffer(1e-6)
    shapely.prepare(cover)
    if cover.covers(LineString([s, g])):
        return np.array([*head, s, g, *tail])
    verts = [np.asarray(c) for ring in [area.exterior, *area.interiors] for c in list(ring.coords)[:-1]]
    nodes = [s, g, *verts]
    n = len(nodes)
    pts = np.array(nodes)
    ii, jj = np.triu_indices(n, 1)
    lines = shapely.linestrings(np.stack([pts[ii], pts[jj]], axis=1))
    ok = shapely.covers(cover, lines)
    graph = nx.Graph()
    for i, j in zip(ii[ok], jj[ok], strict=True):
        graph.add_edge(int(i), int(j), weight=float(np.linalg.norm(pts[i] - pts[j])))
    try:
        path = nx.shortest_path(graph, 0, 1, weight="weight")
    except (nx.NetworkXNoPath, nx.NodeNotFound) as exc:
        raise ValueError(f"no walkable path from {tuple(start)} to {tuple(goal)}") from exc
    return np.array([*head, *pts[path], *tail])


def stride_positions(polyline: NDArray[np.float64], cfg: TrackConfig) -> NDArray[np.float64]:
    """Positions (M, 2) every stride along a polyline, ending exactly at its last point."""
    line = LineString(polyline)
    n = max(1, math.ceil(line.length / cfg.stride_length_m))
    return np.array([line.interpolate(d).coords[0] for d in np.linspace(0.0, line.length, n + 1)])


def dead_reckon(
    t_ns: NDArray[np.int64], xy_true: NDArray[np.float64], rng: np.random.Generator, cfg: TrackConfig
):
    """Measured track (N, 2): the true stride vectors integrated with scale, heading and bias errors."""
    steps = np.diff(xy_true, axis=0)
    dt = np.diff(t_ns).astype(np.float64) * 1e-9
    scale = float(rng.normal(0.0, cfg.scale_error_sigma))
    psi0 = math.radians(float(rng.normal(0.0, cfg.initial_heading_sigma_deg)))
    bias = math.radians(float(rng.normal(0.0, cfg.gyro_bias_sigma_deg_s)))
    walk = (
        np.radians(cfg.gyro_bias_walk_deg_s_sqrt_s) * np.sqrt(np.maximum(dt, 0.0)) * rng.normal(size=len(dt))
    )
    bias_t = bias + np.cumsum(walk)
    heading_err = psi0 + np.cumsum(bias_t * dt)
    c, s = np.cos(heading_err), np.sin(heading_err)
    meas = (1.0 + scale) * np.stack(
        [c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]], axis=1
    )
    meas = (
        meas
        + rng.normal(0.0, cfg.stride_noise_m, size=meas.shape)
        * (np.linalg.norm(steps, axis=1) > 1e-6)[:, None]
    )
    xy = np.vstack([xy_true[:1], xy_true[0] + np.cumsum(meas, axis=0)])
    return xy, scale, math.degrees(psi0)


@dataclass(frozen=True)
class TrackLeg:
    """What the surveyor does in one room: the positions (K, 2) with times (K,) of its capture."""

    room_id: str
    t_ns: NDArray[np.int64]
    xy: NDArray[np.float64]


def survey_track(
    building: Building,
    legs: list[TrackLeg],
    t0_ns: int,
    rng: np.random.Generator,
    cfg: TrackConfig | None = None,
) -> Track:
    """The whole survey walk: from "you are here" at t0_ns to the first position of each leg (walking at
    the stride rate), through the leg's own positions and times, on to the next leg. Leg times must start
    no earlier than the walk can arrive (see :func:`walk_time_ns`).

    Returns the true positions per stride and the dead-reckoned ones (:func:`dead_reckon`)."""
    cfg = cfg or TrackConfig()
    area = walkable_area(building, cfg.clearance_m)
    ts: list[int] = [t0_ns]
    xys: list[NDArray[np.float64]] = [np.asarray(building.you_are_here, dtype=float)]
    for leg in legs:
        path = shortest_path(area, xys[-1], leg.xy[0])
        strides = stride_positions(path, cfg)[1:]
        arrive = int(leg.t_ns[0])
        n = len(strides)
        # the surveyor walks at the stride rate and waits (standing still) before starting the capture
        walk_ns = round(cfg.stride_period_s * 1e9)
        if ts[-1] + n * walk_ns > arrive:
            raise ValueError(
                f"leg {leg.room_id} starts at {arrive} before the walk from the last one can arrive"
            )
        for p in strides[:-1]:
            ts.append(ts[-1] + walk_ns)
            xys.append(p)
        for t, p in zip(leg.t_ns, leg.xy, strict=True):
            if t > ts[-1]:
                ts.append(int(t))
                xys.append(np.asarray(p[:2], dtype=float))
    t_ns = np.asarray(ts, dtype=np.int64)
    xy_true = np.asarray(xys, dtype=np.float64)
    xy, scale, psi0 = dead_reckon(t_ns, xy_true, rng, cfg)
    return Track(t_ns=t_ns, xy_true=xy_true, xy=xy, scale_error=scale, initial_heading_error_deg=psi0)


def walk_time_ns(area: Polygon, start, goal, cfg: TrackConfig | None = None) -> int:
    """Time (ns) the surveyor needs to walk from ``start`` to ``goal`` through ``area`` (see
    :func:`walkable_area`) at the stride rate."""
    cfg = cfg or TrackConfig()
    return round(
        (len(stride_positions(shortest_path(area, start, goal), cfg)) - 1) * cfg.stride_period_s * 1e9
    )
