"""Doors in a room model, from its cloud, and what the capture saw (coverage).

The wall model is found in the slice near the ceiling, where a door's lintel closes the wall: a door is
not a gap in walls.parquet. It is a gap in the wall's face from the floor up to head height that the
capture saw *through*. Along each wall, in columns of a few centimetres (`wall_columns`):

- the **face** is where the points lie, not where the model put it: the densest offset within 15 cm of
  the model wall (a corridor wall modelled 11 cm outside its face is still read on its face);
- a column is **open** when its face is empty low down (0.15-1.0 m: below every window sill), mostly
  empty up to 1.9 m (a smeared capture leaves some points in an opening; a TV bench or a plant leaves the
  face above it) and nothing stands in front of it low down (a cabinet hides the face but shows its
  own front);
- an opening is a **door** only when the capture saw through it: points beyond the face, within the
  wall's thickness or just behind it (the floor running through the door, its jambs, the next room),
  in enough of its columns. An occluded stretch of face (behind a cabinet, seen from one side of it)
  or one the camera never looked at is empty too, but nothing lies beyond it.

Coverage: the floor and ceiling cells the capture saw (a grid of their points' positions); a plan wall
whose room side was seen and which has no model wall is removed, one whose room side was not seen is
unknown (the changes stage). Surfaces: the cells holding points from 0.15 to 1.9 m above the floor (walls,
furniture, anything standing): where the cloud shows a wall's face whatever the wall model made of it
(a wall the model missed still stands; a "wall" the model found at the ceiling, a lamp, does not reach
down). Tops: the cells holding points just below the ceiling: a wall reaches up there, furniture
modelled as a wall (a wardrobe's front) does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tasks.lines import Segments, as_segments, lengths, true_runs

LOW_M = (0.15, 1.0)
"""Height band (above the floor) where a door is open and a window's parapet or a sill is not."""
HIGH_M = (1.0, 1.9)
"""Height band above it, up to below every door's head."""


@dataclass(frozen=True)
class Door:
    """An opening in one model wall (room frame)."""

    wall: int
    """Index of the wall in walls.parquet."""
    segment: tuple[float, float, float, float]
    """Its extent along the wall's face."""
    through_share: float
    """Share of its columns in which the capture saw beyond the face (the evidence)."""
    through_points: int = 0
    """Points seen through it."""

    @property
    def width_m(self) -> float:
        return float(np.hypot(self.segment[2] - self.segment[0], self.segment[3] - self.segment[1]))

    @property
    def centre(self) -> NDArray[np.float64]:
        s = np.asarray(self.segment)
        return 0.5 * (s[:2] + s[2:])


@dataclass(frozen=True)
class WallColumns:
    """What the capture saw along one wall, per column of `bin_m` (the wall's start to its end)."""

    start: NDArray[np.float64]
    """(2,) the wall's start, on the model's line."""
    along: NDArray[np.float64]
    """(2,) unit vector along the wall."""
    inward: NDArray[np.float64]
    """(2,) unit normal into the room."""
    length_m: float
    bin_m: float
    face_offset_m: float
    """Where the face's points lie, along `inward` from the model's line."""
    face_spread_m: float
    """Interquartile range of the face's points' offsets: about 1 cm for a capture whose frames agree, 4-6
    cm for one whose frames disagree (a corridor registered by the IMU track), which smears the wall
    beside an opening into it."""
    face_low: NDArray[np.int64]
    """(B,) points on the face (within face_m) in LOW_M."""
    face_high: NDArray[np.int64]
    """(B,) points on the face in HIGH_M."""
    front: NDArray[np.int64]
    """(B,) points in front of the face (front_m into the room) in LOW_M: what stands before it."""
    through: NDArray[np.int64]
    """(B,) points beyond the face (through_m behind it: past a capture's depth noise on the face, up to
    the floor of the next room), floor to HIGH_M's top: seen through it."""

    def reference(self, counts: NDArray) -> float:
        """The wall's typical column count (median of the columns holding points)."""
        return float(np.median(counts[counts > 0])) if (counts > 0).any() else 0.0

    def bins_of(self, s0: float, s1: float) -> slice:
        """The columns between s0 and s1 metres along the wall."""
        i0 = int(np.clip(np.floor(min(s0, s1) / self.bin_m), 0, len(self.face_low)))
        i1 = int(np.clip(np.ceil(max(s0, s1) / self.bin_m), i0, len(self.face_low)))
        return slice(i0, i1)


def wall_columns(
    points: NDArray[np.float64],
    floor_z: float,
    wall: NDArray,
    inward: NDArray,
    bin_m: float = 0.05,
    face_m: float = 0.05,
    face_search_m: float = 0.15,
    front_m: tuple[float, float] = (0.08, 0.8),
    through_m: tuple[float, float] = (0.10, 1.5),
) -> WallColumns:
    """The columns of one wall (see the module doc). `points` (N, 3) in the walls' frame, z up; `wall`
    (4,) its segment, `inward` (2,) its normal into the room."""
    wall = np.asarray(wall, dtype=np.float64).reshape(4)
    n = np.asarray(inward, dtype=np.float64).reshape(2)
    a = wall[:2]
    length = float(np.hypot(*(wall[2:] - a)))
    u = (wall[2:] - a) / max(length, 1e-12)
    nbins = max(int(np.ceil(length / bin_m)), 1)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    s, o = (pts[:, :2] - a) @ u, (pts[:, :2] - a) @ n
    z = pts[:, 2] - floor_z
    keep = (s >= 0) & (s <= length) & (o >= -through_m[1] - face_search_m) & (o <= front_m[1] + face_search_m)
    s, o, z = s[keep], o[keep], z[keep]
    band = (z >= LOW_M[0]) & (z <= HIGH_M[1])
    near = band & (np.abs(o) <= face_search_m)
    offset, spread = 0.0, float("nan")
    if near.sum() >= 30:
        hist, edges = np.histogram(o[near], bins=np.arange(-face_search_m, face_search_m + 1e-9, 0.01))
        smooth = np.convolve(hist, np.ones(3), mode="same")
        offset = float(edges[int(np.argmax(smooth))] + 0.005)
        q1, q3 = np.percentile(o[near], [25, 75])
        spread = float(q3 - q1)
    oo = o - offset
    low = (z >= LOW_M[0]) & (z <= LOW_M[1])
    high = (z > HIGH_M[0]) & (z <= HIGH_M[1])
    on_face = np.abs(oo) <= face_m
    col = np.clip((s / bin_m).astype(int), 0, nbins - 1)

    def count(mask: NDArray[np.bool_]) -> NDArray[np.int64]:
        return np.bincount(col[mask], minlength=nbins)

    return WallColumns(
        a,
        u,
        n,
        length,
        bin_m,
        offset,
        spread,
        count(on_face & low),
        count(on_face & high),
        count(low & (oo >= front_m[0]) & (oo <= front_m[1])),
        count((z >= -0.1) & (z <= HIGH_M[1]) & (oo <= -through_m[0]) & (oo >= -through_m[1])),
    )


def find_doors(
    points: NDArray[np.float64],
    floor_z: float,
    walls: Segments,
    inward: NDArray[np.float64],
    width_m: tuple[float, float],
    empty_share: float = 0.2,
    high_share: float = 0.5,
    front_share: float = 0.5,
    min_through_share: float = 0.25,
    bin_m: float = 0.05,
) -> list[Door]:
    """Doors in each wall (see the module doc): runs of open columns between width_m[0] and width_m[1]
    long, through which the capture saw (two points or more beyond the face) in at least
    min_through_share of the columns. A column is open when, counted over it and its neighbours, its
    face holds at most empty_share of the wall's typical count low down and high_share of it up to
    1.9 m, and what stands in front of it low down at most front_share; a run's ends are then taken out
    to the last column whose own face is empty low down. `points` (N, 3) in the walls' frame, z up."""
    walls = as_segments(walls)
    doors: list[Door] = []
    for k, w in enumerate(walls):
        if float(lengths(w[None])[0]) < width_m[0]:
            continue
        cols = wall_columns(points, floor_z, w, inward[k], bin_m)
        ref_low, ref_high = cols.reference(cols.face_low), cols.reference(cols.face_high)
        if ref_low <= 0:
            continue
        three = np.ones(3) / 3.0  # a column and its neighbours: one stray point does not close a door
        low = np.convolve(cols.face_low, three, mode="same")
        high = np.convolve(cols.face_high, three, mode="same")
        front = np.convolve(cols.front, three, mode="same")
        open_ = (low <= empty_share * ref_low) & (front <= front_share * ref_low)
        if ref_high > 0:
            open_ &= high <= high_share * ref_high
        empty = cols.face_low <= empty_share * ref_low
        nbins = len(empty)
        for i0, i1 in true_runs(open_):
            while i0 > 0 and empty[i0 - 1] and not open_[i0 - 1]:  # the neighbours' average eroded it
                i0 -= 1
            while i1 < nbins and empty[i1] and not open_[i1]:
                i1 += 1
            if not width_m[0] <= (i1 - i0) * bin_m <= width_m[1]:
                continue
            seen = cols.through[i0:i1] >= 2
            if seen.mean() < min_through_share:
                continue
            t0, t1 = i0 * bin_m, min(i1 * bin_m, cols.length_m)
            p0, p1 = w[:2] + t0 * cols.along, w[:2] + t1 * cols.along
            doors.append(Door(k, (*p0, *p1), float(seen.mean()), int(cols.through[i0:i1].sum())))
    return doors


@dataclass(frozen=True)
class SpanState:
    """How a capture saw a span of one of its walls (e.g. a plan door gap)."""

    face_share: float | None
    """Share of its columns whose face shows up to a door's height (None: the wall's face was not seen)."""
    through_share: float
    """Share of its columns seen through (two points or more beyond the face)."""
    face_spread_m: float
    """The wall's WallColumns.face_spread_m."""

    def closed(self, face_share: float, through_share: float, crisp_m: float) -> bool:
        """The span is a closed wall: its face shows across face_share of it, less than through_share of
        it was seen through, and the capture's face is crisp enough (spread within crisp_m) to tell."""
        return (
            self.face_share is not None
            and self.face_share >= face_share
            and self.through_share < through_share
            and self.face_spread_m <= crisp_m
        )


def span_state(
    points: NDArray[np.float64],
    floor_z: float,
    wall: NDArray,
    inward: NDArray,
    s0: float,
    s1: float,
    min_points: int = 3,
    min_share: float = 0.05,
    bin_m: float = 0.05,
) -> SpanState:
    """How a span of a wall (s0..s1 metres along it) was seen: the share of its columns whose face shows
    from 0.15 to 1.9 m (a door's height), at least min_points points and min_share of the wall's typical
    column (about 1 for a closed wall, about 0 for an opening), and the share seen through. A face's
    density varies tenfold along a wall (near the camera, far and grazing): a closed span is one seen
    everywhere, not one seen as densely as beside it."""
    cols = wall_columns(points, floor_z, wall, inward, bin_m)
    face = cols.face_low + cols.face_high
    inside = cols.bins_of(s0, s1)
    n_in = inside.stop - inside.start
    through = float((cols.through[inside] >= 2).mean()) if n_in else 0.0
    ref = cols.reference(face)
    spread = cols.face_spread_m if np.isfinite(cols.face_spread_m) else float("inf")
    if ref <= 0 or n_in == 0:
        return SpanState(None, through, spread)
    seen = face[inside] >= max(min_points, min_share * ref)
    return SpanState(float(seen.mean()), through, spread)


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


def surfaces(
    points: NDArray[np.float64], floor_z: float, cell_m: float = 0.05, min_points: int = 2
) -> Coverage:
    """Cells holding at least min_points points from 0.15 to 1.9 m above the floor (LOW_M to HIGH_M):
    what stands there (module doc). (N, 3) points, z up."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = pts[:, 2] - floor_z
    return _cells(pts[(z >= LOW_M[0]) & (z <= HIGH_M[1]), :2], cell_m, min_points)


def tops(
    points: NDArray[np.float64],
    ceiling_z: float,
    band_m: tuple[float, float] = (0.30, 0.08),
    cell_m: float = 0.05,
    min_points: int = 2,
) -> Coverage:
    """Cells holding at least min_points points from band_m[0] to band_m[1] below the ceiling: what
    reaches up to it. A wall does; a wardrobe, a shelf or a partition screen stops short (in a scanner's
    cloud the wall behind shows above it). (N, 3) points, z up."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    below = ceiling_z - pts[:, 2]
    return _cells(pts[(below <= band_m[0]) & (below >= band_m[1]), :2], cell_m, min_points)


def _cells(xy: NDArray[np.float64], cell_m: float, min_points: int) -> Coverage:
    """The grid of cells holding at least min_points of the (N, 2) points."""
    if len(xy) == 0:
        return Coverage((0.0, 0.0), cell_m, np.zeros((1, 1), dtype=bool))
    lo = xy.min(axis=0) - cell_m
    ij = np.floor((xy - lo) / cell_m).astype(int)
    shape = (int(ij[:, 1].max()) + 2, int(ij[:, 0].max()) + 2)
    counts = np.zeros(shape, dtype=np.int32)
    np.add.at(counts, (ij[:, 1], ij[:, 0]), 1)
    return Coverage((float(lo[0]), float(lo[1])), cell_m, counts >= min_points)


def face_spread(points: NDArray[np.float64], floor_z: float, walls: Segments, inward: NDArray) -> float:
    """The capture's face spread: the length-weighted median of its walls' WallColumns.face_spread_m
    (NaN when no wall's face was seen)."""
    walls = as_segments(walls)
    spreads, weights = [], []
    for w, n in zip(walls, np.asarray(inward).reshape(-1, 2), strict=True):
        spread = wall_columns(points, floor_z, w, n).face_spread_m
        if np.isfinite(spread):
            spreads.append(spread)
            weights.append(float(lengths(w[None])[0]))
    if not spreads:
        return float("nan")
    order = np.argsort(spreads)
    cum = np.cumsum(np.asarray(weights)[order])
    return float(np.asarray(spreads)[order][np.searchsorted(cum, 0.5 * cum[-1])])
