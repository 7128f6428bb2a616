"""Gap filling from the plan (thesis 7.2, fig 7.6), for a room model already placed in the plan frame.

1. The **shell**: the plan room's outline at the walls' inner faces with the fused thickness (its wall
   centrelines offset inward by half of each wall's thickness, door gaps closed);
2. the model's **free ends** (degree-1 nodes of its wall graph) lying on the shell are extended along and
   perpendicular to their walls up to the shell (fig 7.6 c);
3. the **shortest path** (networkx) over the shell and those extensions between the two most distant free
   ends closes the gap (fig 7.6 d); the shell's stretches the model already covers cost a thousand times
   their length, so the path runs through the gap, not over observed walls. More than one gap: the
   pairs of ends with the cheapest paths first; an end left without a partner (its gap ends at a
   junction of the model's walls) is joined to the nearest stretch of shell the model covers;
4. the walls added are marked `gap_filled`.

A room ends closed (its walls enclose a polygon) or open with the reason.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, Point, Polygon

from tasks.lines import (
    Segments,
    as_segments,
    is_closed,
    lengths,
    point_segment_distances,
    room_polygons,
    sample_segments,
    wall_graph,
)

GAP_FILLED = "gap_filled"


@dataclass(frozen=True)
class GapFill:
    """Result of filling one room's gaps."""

    walls: Segments
    """(K, 4) walls added (plan frame), origin gap_filled."""
    closed: bool
    polygon: Polygon | None
    """The room the walls (observed + filled) enclose, largest face."""
    reason: str
    """Why the room stays open ("" when closed)."""
    free_ends: int
    """Free ends of the model before filling."""


def shell_polygon(
    plan_room: Polygon,
    centrelines: Segments,
    thickness_m: NDArray,
    doors: Segments | None = None,
    reach_m: float = 0.8,
) -> Polygon:
    """The plan room's outline with its walls at the fused thickness: the free space left by the wall
    rectangles (centrelines buffered by half their thickness) and the door gaps (closed with the thickness
    of the nearest wall) around the room, the part holding the plan room. Falls back to the plan room
    itself when the walls do not enclose it."""
    centrelines = as_segments(centrelines)
    near = shapely.distance(shapely.linestrings(centrelines.reshape(-1, 2, 2)), plan_room) <= reach_m
    rects = [
        LineString(c.reshape(2, 2)).buffer(max(t, 1e-3) / 2, cap_style="square", join_style="mitre")
        for c, t in zip(centrelines[near], np.asarray(thickness_m)[near], strict=True)
    ]
    for d in as_segments(doors if doors is not None else np.zeros((0, 4))):
        line = LineString(d.reshape(2, 2))
        if line.distance(plan_room) > reach_m or not len(centrelines):
            continue
        k = int(np.argmin(point_segment_distances(np.asarray(line.centroid.coords), centrelines)[0]))
        rects.append(line.buffer(max(float(thickness_m[k]), 1e-3) / 2 + 0.01, cap_style="square"))
    if not rects:
        return plan_room
    free = plan_room.buffer(reach_m, join_style="mitre").difference(shapely.union_all(rects))
    inside = plan_room.representative_point()
    for part in getattr(free, "geoms", [free]):
        if isinstance(part, Polygon) and part.contains(inside):
            if 0.7 * plan_room.area <= part.area <= 1.3 * plan_room.area:
                return Polygon(part.exterior)
    return plan_room


def free_ends(walls: Segments, tol_m: float = 0.02) -> list[tuple[NDArray, NDArray]]:
    """(position, outward unit direction along the wall) of every degree-1 node of the wall graph."""
    g = wall_graph(as_segments(walls), tol=tol_m)
    out = []
    for node, deg in g.degree():
        if deg != 1:
            continue
        p = np.asarray(g.nodes[node]["xy"])
        ((_, other),) = g.edges(node)
        q = np.asarray(g.nodes[other]["xy"])
        d = p - q
        out.append((p, d / max(float(np.hypot(*d)), 1e-12)))
    return out


def _first_hit(ring: shapely.LinearRing, p: NDArray, d: NDArray, reach_m: float) -> NDArray | None:
    ray = LineString([p + 1e-4 * d, p + reach_m * d])
    hit = ray.intersection(ring)
    if hit.is_empty:
        return None
    pts = [np.asarray(g.coords[0]) for g in getattr(hit, "geoms", [hit]) if g.geom_type == "Point"]
    if not pts:
        return None
    return min(pts, key=lambda q: float(np.hypot(*(q - p))))


def _covered(pieces: Segments, walls: Segments, tol_m: float) -> NDArray[np.bool_]:
    """(P,) shell pieces whose samples mostly lie beside a model wall: within tol_m of it, their foot on
    the wall between its ends (`beside`). Past a wall's free end the shell is a gap, also within tol_m of
    that end: the stretch from where a wall stops short to the corner it should reach is filled."""
    if len(pieces) == 0 or len(walls) == 0:
        return np.zeros(len(pieces), dtype=bool)
    pts, owner = sample_segments(pieces, 0.05)
    near = beside(pts, as_segments(walls), tol_m)
    share = np.bincount(owner, near, len(pieces)) / np.bincount(owner, minlength=len(pieces))
    return share >= 0.5


def beside(points: NDArray, walls: Segments, tol_m: float) -> NDArray[np.bool_]:
    """(N,) points within tol_m of some wall whose foot on it lies between the wall's ends."""
    a, b = walls[:, :2], walls[:, 2:]
    length = np.maximum(lengths(walls), 1e-12)
    u = (b - a) / length[:, None]
    rel = np.asarray(points, dtype=np.float64)[:, None, :] - a[None]
    t = (rel * u[None]).sum(-1)
    off = np.abs(rel[..., 0] * u[None, :, 1] - rel[..., 1] * u[None, :, 0])
    return ((off <= tol_m) & (t >= -1e-9) & (t <= length[None] + 1e-9)).any(axis=1)


def _shell_graph(
    shell: Polygon,
    ends: list[tuple[NDArray, NDArray]],
    walls: Segments,
    reach_m: float,
    tol_m: float,
    jump_m: float,
) -> tuple[nx.Graph, list[int]]:
    """Graph of the shell's ring (noded at the extension hits) plus the extensions of every free end along
    and perpendicular to its wall, those no longer than jump_m or running along the shell (their middle
    within jump_m of it): an extension across the room to the far side of the shell is no gap of it (a
    corridor's wall end would close the corridor across); returns it and the node of each free end."""
    ring = shell.exterior
    g = nx.Graph()
    hits: list[tuple[int, NDArray]] = []
    end_nodes = []
    for k, (p, d) in enumerate(ends):
        node = ("end", k)
        g.add_node(node, xy=tuple(p))
        end_nodes.append(node)
        foot = ring.interpolate(ring.project(Point(*p)))
        hits.append((k, np.asarray(foot.coords[0])))  # an end on the shell joins it where it lies
        for direction in (d, np.array([-d[1], d[0]]), np.array([d[1], -d[0]])):
            h = _first_hit(ring, p, direction, reach_m)
            if h is None:
                continue
            along = ring.distance(Point(*(0.5 * (p + h)))) <= jump_m
            if along or float(np.hypot(*(h - p))) <= jump_m:
                hits.append((k, h))
    ring_xy = np.asarray(ring.coords)[:-1]
    along = [ring.project(Point(*xy)) for xy in ring_xy]
    # the ring is also cut where the model's walls end beside it, so that a stretch is covered or not
    # whole (a wall that stops halfway along the shell's edge leaves the rest of the edge a gap)
    stops = [
        ring.interpolate(ring.project(Point(*q)))
        for q in as_segments(walls).reshape(-1, 2)
        if ring.distance(Point(*q)) <= tol_m
    ]
    cuts = sorted(
        [(a, ("v", i), ring_xy[i]) for i, a in enumerate(along)]
        + [(ring.project(Point(*h)), ("h", n), h) for n, (_, h) in enumerate(hits)]
        + [(ring.project(q), ("w", n), np.asarray(q.coords[0])) for n, q in enumerate(stops)],
        key=lambda c: c[0],
    )
    for _, node, xy in cuts:
        g.add_node(node, xy=tuple(xy))
    pieces = np.array([[*a[2], *b[2]] for a, b in itertools.pairwise([*cuts, cuts[0]])]).reshape(-1, 4)
    cover = _covered(pieces, walls, tol_m)
    for (a, b), seg, cov in zip(itertools.pairwise([*cuts, cuts[0]]), pieces, cover, strict=True):
        if a[1] == b[1]:
            continue
        length = float(lengths(seg[None])[0])
        g.add_edge(a[1], b[1], weight=length * (1000.0 if cov else 1.0), segment=seg, covered=bool(cov))
    for n, (k, h) in enumerate(hits):
        seg = np.array([*ends[k][0], *h])
        g.add_edge(
            ("end", k), ("h", n), weight=float(lengths(seg[None])[0]) + 1e-9, segment=seg, covered=False
        )
    return g, end_nodes


def fill_gaps(
    walls: Segments, shell: Polygon, end_tol_m: float, cover_tol_m: float = 0.10, reach_m: float = 30.0
) -> GapFill:
    """Close the placed model's gaps along the shell (see the module doc)."""
    walls = as_segments(walls)
    if len(walls) == 0:
        return GapFill(np.zeros((0, 4)), False, None, "the room has no walls", 0)
    ends = free_ends(walls)
    ring = shell.exterior
    gap_ends = [(p, d) for p, d in ends if ring.distance(Point(*p)) <= end_tol_m]
    added: list[NDArray] = []
    if gap_ends:
        g, nodes = _shell_graph(shell, gap_ends, walls, reach_m, cover_tol_m, end_tol_m)
        paths = [nx.shortest_path(g, a, b, weight="weight") for a, b in _pairs(g, nodes, gap_ends)]
        joined = {n for path in paths for n in (path[0], path[-1])}
        for path in paths:
            for u, v in itertools.pairwise(path):
                data = g.edges[u, v]
                length = float(lengths(data["segment"][None])[0])
                # a covered piece shorter than the cover tolerance joins two filled ones: the model's
                # wall ends near it, not on it
                if length > 1e-6 and (not data["covered"] or length < cover_tol_m):
                    added.append(data["segment"])
        for node, end in zip(nodes, gap_ends, strict=True):
            if node not in joined:  # its gap ends at a junction, not at a free end
                added += _walk_to_cover(g, node, end, cover_tol_m)
    filled = np.array(added).reshape(-1, 4)
    every = np.concatenate([walls, filled])
    closed = is_closed(wall_graph(every, tol=0.02))
    polys = room_polygons(every, tol=0.02)
    polygon = polys[0] if polys else None
    reason = ""
    if not closed and polygon is not None and polygon.area >= 0.5 * shell.area:
        closed = True  # a dangling partition inside an enclosed room leaves free ends, not an open room
    if not closed:
        interior = len(ends) - len(gap_ends)
        reason = (
            f"{len(ends)} free ends, {len(gap_ends)} on the shell"
            + (f", {interior} inside the room" if interior else "")
            + (
                "; the filled walls enclose no room"
                if len(gap_ends) >= 2
                else "; nothing to join along the shell"
            )
        )
    return GapFill(filled, closed, polygon, reason, len(ends))


def _walk_to_cover(
    g: nx.Graph, node: object, end: tuple[NDArray, NDArray], connector_m: float
) -> list[NDArray]:
    """The shell's uncovered stretch ahead of a free end (beyond it along its wall), walked along the ring
    from the end's foot until the model covers the shell again: a gap whose other end is a junction of
    the model's walls (a wall that stops where a partition meets it), not a free end. The segments to
    add (the jump onto the shell, covered pieces shorter than connector_m that lead to the gap, the
    uncovered pieces), none when the ring is not covered again."""
    _, d = end
    ring_edges = [(n, data) for n, data in g[node].items() if n[0] != "end"]
    if not ring_edges:
        return []
    foot, jump = min(ring_edges, key=lambda e: e[1]["weight"])
    out = [jump["segment"]] if lengths(jump["segment"][None])[0] > 1e-6 else []
    ring = [n for n in g[foot] if n[0] != "end"]
    if not ring:
        return []
    here = np.asarray(g.nodes[foot]["xy"])
    prev, cur = foot, max(ring, key=lambda n: float((np.asarray(g.nodes[n]["xy"]) - here) @ d))
    gap = False
    for _ in range(g.number_of_nodes()):
        data = g.edges[prev, cur]
        if data["covered"] and gap:
            return out
        if not data["covered"]:
            gap = True
            out.append(data["segment"])
        elif float(lengths(data["segment"][None])[0]) < connector_m:
            out.append(data["segment"])
        ahead = [n for n in g[cur] if n[0] != "end" and n != prev]
        if not ahead or cur == foot:
            break
        prev, cur = cur, ahead[0]
    return []


def _pairs(g: nx.Graph, nodes: list, ends: list[tuple[NDArray, NDArray]]) -> list[tuple]:
    """Pairs of free-end nodes to join: the two most distant when there are two or three (thesis), else
    greedily the pairs with the cheapest shell paths."""
    if len(nodes) < 2:
        return []
    if len(nodes) <= 3:
        pts = np.array([p for p, _ in ends])
        dist = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        i, j = np.unravel_index(np.argmax(dist), dist.shape)
        return [(nodes[i], nodes[j])] if nx.has_path(g, nodes[i], nodes[j]) else []
    costs = []
    for i, j in itertools.combinations(range(len(nodes)), 2):
        if nx.has_path(g, nodes[i], nodes[j]):
            costs.append((nx.shortest_path_length(g, nodes[i], nodes[j], weight="weight"), i, j))
    used: set[int] = set()
    out = []
    for _, i, j in sorted(costs):
        if i not in used and j not in used:
            out.append((nodes[i], nodes[j]))
            used.update((i, j))
    return out
