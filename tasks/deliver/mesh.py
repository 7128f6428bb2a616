"""floor.ply: the floor as a triangle mesh (plan frame, metres, z = 0 on the floor).

Every standing stretch of a wall and every added wall is a closed box (8 vertices, 12 outward
triangles) of its thickness from z = 0 to its height; above each door the wall's lintel is a box from
the door's height to the wall's; each room's floor is a slab (its polygon, constrained-Delaunay
triangulated, from -slab_thickness to 0, closed by its side walls). Boxes share no vertices, so every
box is its own connected component.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.deliver.floor import Floor, outline, standing_pieces

WALL, ADDED, LINTEL, SLAB = (200, 200, 200), (60, 170, 60), (170, 170, 170), (150, 120, 90)

BOX_TRIANGLES = np.array(
    [
        [0, 2, 1], [0, 3, 2],  # bottom (facing down)
        [4, 5, 6], [4, 6, 7],  # top
        [0, 1, 5], [0, 5, 4],
        [1, 2, 6], [1, 6, 5],
        [2, 3, 7], [2, 7, 6],
        [3, 0, 4], [3, 4, 7],
    ],
    dtype=np.int32,
)  # fmt: skip
"""A box over a counter-clockwise footprint 0-3 (bottom) and 4-7 (top): outward normals."""


def box(corners: NDArray[np.float64], z0: float, z1: float) -> tuple[NDArray, NDArray]:
    """(8, 3) vertices and (12, 3) triangles of a closed box over a (4, 2) footprint."""
    c = np.asarray(corners, dtype=np.float64)
    if _signed_area(c) < 0:
        c = c[::-1]
    verts = np.vstack([np.column_stack([c, np.full(4, z0)]), np.column_stack([c, np.full(4, z1)])])
    return verts, BOX_TRIANGLES.copy()


def _signed_area(ring: NDArray[np.float64]) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def slab(polygon: shapely.Polygon, z0: float, z1: float) -> tuple[NDArray, NDArray]:
    """A closed prism over a polygon (holes kept): top and bottom from its constrained Delaunay
    triangulation, one quad per boundary edge."""
    polygon = shapely.Polygon(shapely.geometry.polygon.orient(polygon, 1.0))
    rings = [
        np.asarray(polygon.exterior.coords)[:-1],
        *(np.asarray(r.coords)[:-1] for r in polygon.interiors),
    ]
    pts = np.vstack(rings)
    index = {(round(float(x), 9), round(float(y), 9)): i for i, (x, y) in enumerate(pts)}
    tris = []
    for tri in shapely.constrained_delaunay_triangles(polygon).geoms:
        coords = np.asarray(tri.exterior.coords)[:3]
        ids = [index.get((round(float(x), 9), round(float(y), 9))) for x, y in coords]
        if None in ids:
            raise ValueError("the triangulation added a vertex")
        if _signed_area(coords) < 0:
            ids = ids[::-1]
        tris.append(ids)
    t = np.asarray(tris, dtype=np.int32).reshape(-1, 3)
    n = len(pts)
    verts = np.vstack([np.column_stack([pts, np.full(n, z0)]), np.column_stack([pts, np.full(n, z1)])])
    faces = [t[:, ::-1], t + n]
    start = 0
    for ring in rings:  # exterior counter-clockwise, holes clockwise (orient): outward sides
        k = len(ring)
        a = start + np.arange(k)
        b = start + (np.arange(k) + 1) % k
        faces += [np.column_stack([a, b, b + n]), np.column_stack([a, b + n, a + n])]
        start += k
    return verts, np.vstack(faces).astype(np.int32)


def build(floor: Floor, slab_thickness_m: float, door_height_m: float) -> tuple[list, dict[str, int]]:
    """[(vertices, triangles, colour)] of every part, and how many of each kind."""
    parts: list[tuple[NDArray, NDArray, tuple[int, int, int]]] = []
    counts = {"wall_boxes": 0, "added_boxes": 0, "lintels": 0, "slabs": 0}
    for wall in floor.walls:
        for s0, s1 in standing_pieces(floor, wall):
            parts.append((*box(outline(wall.centreline, wall.thickness_m, s0, s1), 0.0, wall.height_m), WALL))
            counts["wall_boxes"] += 1
    for wall in floor.added:
        parts.append((*box(outline(wall.centreline, wall.thickness_m), 0.0, wall.height_m), ADDED))
        counts["added_boxes"] += 1
    for door in floor.doors:
        if door.wall_id is None:
            continue
        wall = floor.walls[door.wall_id]
        if wall.height_m <= door_height_m + 0.01 or wall.status == "demolished":
            continue
        s0, s1 = sorted((wall.along(door.segment[:2]), wall.along(door.segment[2:])))
        parts.append(
            (*box(outline(wall.centreline, wall.thickness_m, s0, s1), door_height_m, wall.height_m), LINTEL)
        )
        counts["lintels"] += 1
    for room in floor.rooms:
        for poly in getattr(room.polygon, "geoms", [room.polygon]):
            parts.append((*slab(poly, -slab_thickness_m, 0.0), SLAB))
            counts["slabs"] += 1
    return parts, counts


def write(floor: Floor, path: Path, slab_thickness_m: float, door_height_m: float) -> dict[str, int]:
    """Write floor.ply (binary, vertex colours); returns the part counts."""
    parts, counts = build(floor, slab_thickness_m, door_height_m)
    verts, tris, cols, base = [], [], [], 0
    for v, t, colour in parts:
        verts.append(v)
        tris.append(t + base)
        cols.append(np.tile(np.asarray(colour, dtype=np.uint8), (len(v), 1)))
        base += len(v)
    if not parts:
        raise ValueError("the floor has no wall and no room to mesh")
    art.write_ply_mesh(path, np.vstack(verts), np.vstack(tris), np.vstack(cols))
    return counts


def watertight_components(path: Path) -> tuple[int, int]:
    """(connected components, how many of them are watertight) of a mesh file (open3d)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    labels, _, _ = mesh.cluster_connected_triangles()
    labels = np.asarray(labels)
    verts, tris = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    good = 0
    for k in np.unique(labels):
        sub_tris = tris[labels == k]
        used, inverse = np.unique(sub_tris, return_inverse=True)
        part = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(verts[used]),
            o3d.utility.Vector3iVector(inverse.reshape(-1, 3).astype(np.int32)),
        )
        good += bool(part.is_watertight())
    return len(np.unique(labels)), good
