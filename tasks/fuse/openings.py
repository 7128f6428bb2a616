"""Doors in a room model, from its cloud, and what the capture saw (coverage).

The wall model is found in the slice near the ceiling, where a door's lintel closes the wall: a door is
not a gap in walls.parquet. It is a gap low down: a stretch of the wall with no point on its face from
just above the floor (below every window sill) up to 1.9 m, with nothing in front of it. A window leaves
its parapet; a TV bench hides the face only low down; a cabinet shows its own front.

Coverage: the floor and ceiling cells the capture saw (a grid of their points' positions); a plan wall
whose room side was seen and which has no model wall is removed, one whose room side was not seen is
unknown (the changes stage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tasks.lines import Segments, as_segments, lengths


@dataclass(frozen=True)
class Door:
    """An opening in one model wall (room frame)."""

    wall: int
    """Index of the wall in walls.parquet."""
    segment: tuple[float, float, float, float]
    """Its extent along the wall's face."""
    beyond_points: int
    """Points seen through it (the evidence)."""

    @property
    def width_m(self) -> float:
        return float(np.hypot(self.segment[2] - self.segment[0], self.segment[3] - self.segment[1]))

    @property
    def centre(self) -> NDArray[np.float64]:
        s = np.asarray(self.segment)
        return 0.5 * (s[:2] + s[2:])


def find_doors(
    points: NDArray[np.float64],
    floor_z: float,
    walls: Segments,
    inward: NDArray[np.float64],
    band_m: tuple[float, float],
    width_m: tuple[float, float],
    bin_m: float = 0.05,
    face_m: float = 0.05,
    front_m: tuple[float, float] = (0.08, 0.8),
    empty_share: float = 0.2,
) -> list[Door]:
    """Openings (see the module doc) in each wall: runs of `bin_m` bins between width_m[0] and width_m[1]
    long where the wall's face (within face_m) has next to no points (less than empty_share of the wall's
    typical bin) both in the low band (band_m above the floor: below a window's sill) and up to 1.9 m
    (above a window's parapet), and nothing stands in front of it (a cabinet or a TV bench hides the face
    but shows its own front, front_m into the room). `points` (N, 3) in the
    walls' frame, z up."""
    walls = as_segments(walls)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = pts[:, 2] - floor_z
    low = pts[(z >= band_m[0]) & (z <= band_m[1]), :2]
    mid = pts[(z > band_m[1]) & (z <= 1.9), :2]
    doors: list[Door] = []
    for k, w in enumerate(walls):
        length = float(lengths(w[None])[0])
        if length < width_m[0]:
            continue
        a = w[:2]
        u = (w[2:] - a) / length
        nbins = max(int(np.ceil(length / bin_m)), 1)

        def counts(xy: NDArray, o_lo: float, o_hi: float, a=a, u=u, n=inward[k], length=length, nbins=nbins):
            s, o = (xy - a) @ u, (xy - a) @ n
            m = (s >= 0) & (s <= length) & (o >= o_lo) & (o <= o_hi)
            return np.bincount(np.clip((s[m] / bin_m).astype(int), 0, nbins - 1), minlength=nbins)

        face = counts(low, -face_m, face_m) + counts(mid, -face_m, face_m)
        front = counts(low, *front_m) + counts(mid, *front_m)
        beyond = counts(np.concatenate([low, mid]), -3.0, -0.12)
        ref = float(np.median(face[face > 0])) if (face > 0).any() else 0.0
        if ref <= 0:
            continue
        empty = (face <= empty_share * ref) & (front <= empty_share * ref)
        for i0, i1 in _runs(empty):
            if width_m[0] <= (i1 - i0) * bin_m <= width_m[1]:
                t0, t1 = i0 * bin_m, min(i1 * bin_m, length)
                p0, p1 = a + t0 * u, a + t1 * u
                doors.append(Door(k, (*p0, *p1), int(beyond[i0:i1].sum())))
    return doors


def face_share(
    points: NDArray[np.float64],
    floor_z: float,
    span: NDArray,
    inward: NDArray,
    band_m: tuple[float, float],
    reference_m: float = 1.0,
    face_m: float = 0.05,
) -> float | None:
    """How much of a span of a wall face (e.g. a plan door gap on a model wall) shows its face low down,
    relative to the face beside it (reference_m on either side): about 1 for a closed wall, about 0 for an
    opening; None when the face beside it was not seen either."""
    span = np.asarray(span, dtype=np.float64).reshape(4)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = pts[:, 2] - floor_z
    xy = pts[(z >= band_m[0]) & (z <= 1.9), :2]
    a = span[:2]
    length = float(np.hypot(*(span[2:] - a)))
    if length <= 0:
        return None
    u = (span[2:] - a) / length
    s, o = (xy - a) @ u, (xy - a) @ np.asarray(inward)
    on_face = np.abs(o) <= face_m
    inside = on_face & (s >= 0) & (s <= length)
    beside = on_face & (((s >= -reference_m) & (s < 0)) | ((s > length) & (s <= length + reference_m)))
    density_beside = beside.sum() / (2 * reference_m)
    if density_beside <= 0:
        return None
    return float(inside.sum() / length / density_beside)


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, end) of every run of True."""
    m = np.concatenate([[False], mask, [False]]).astype(int)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


@dataclass(frozen=True)
class Coverage:
    """Floor-plan cells a capture saw (from its floor and ceiling points), in one frame."""

    origin: tuple[float, float]
    cell_m: float
    seen: NDArray[np.bool_]
    """(H, W) rows along y, columns along x."""

    def at(self, xy: NDArray) -> NDArray[np.bool_]:
        """(N,) whether each point's cell was seen."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ij = np.floor((xy - np.asarray(self.origin)) / self.cell_m).astype(int)
        ok = (
            (ij[:, 0] >= 0)
            & (ij[:, 1] >= 0)
            & (ij[:, 0] < self.seen.shape[1])
            & (ij[:, 1] < self.seen.shape[0])
        )
        out = np.zeros(len(xy), dtype=bool)
        out[ok] = self.seen[ij[ok, 1], ij[ok, 0]]
        return out

    def moved(self, transform) -> TransformedCoverage:
        """The same coverage looked up from another frame (e.g. the plan's, through a placement)."""
        return TransformedCoverage(self, transform)


@dataclass(frozen=True)
class TransformedCoverage:
    """Coverage in a room frame seen from the plan frame: plan points are mapped back before the lookup."""

    base: Coverage
    placement: object
    """A tasks.fuse.register2d.Placement (room -> plan)."""

    def at(self, xy: NDArray) -> NDArray[np.bool_]:
        p = self.placement
        r = p.rotation  # type: ignore[attr-defined]
        back = (np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(p.t)) @ r  # type: ignore[attr-defined]
        return self.base.at(back)


def coverage(
    points: NDArray[np.float64], floor_z: float, ceiling_z: float, cell_m: float, slab_m: float = 0.08
) -> Coverage:
    """Cells holding points of the floor or of the ceiling (within slab_m of them): where the capture
    looked. (N, 3) points, z up."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    keep = (np.abs(pts[:, 2] - floor_z) <= slab_m) | (np.abs(pts[:, 2] - ceiling_z) <= slab_m)
    xy = pts[keep, :2]
    if len(xy) == 0:
        return Coverage((0.0, 0.0), cell_m, np.zeros((1, 1), dtype=bool))
    lo = xy.min(axis=0) - cell_m
    ij = np.floor((xy - lo) / cell_m).astype(int)
    shape = (int(ij[:, 1].max()) + 2, int(ij[:, 0].max()) + 2)
    seen = np.zeros(shape, dtype=bool)
    seen[ij[:, 1], ij[:, 0]] = True
    return Coverage((float(lo[0]), float(lo[1])), cell_m, seen)
