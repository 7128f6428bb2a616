"""The line stages' thresholds (`LinesConfig`): plain data, importable without numpy or networkx, so that
the stages' config modules load no computation."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class LinesConfig:
    """Thresholds of the line stages. Lengths are metres as stored; see `scaled` for other units."""

    max_orientation_clusters: int = 8
    """Largest k tried by the orientation k-means."""
    explained_variance: float = 0.99
    """Elbow criterion (eq 5.8): the smallest k whose clusters explain this share of the length-weighted
    variance of the doubled-angle unit vectors."""
    kmeans_restarts: int = 4
    """Deterministic k-means restarts per k (farthest-point seeds from different starting segments)."""
    split_min_length_m: float = 0.0
    """A cluster split into two directions a few degrees apart (`cluster_orientations`) needs a segment at
    least this long in each: a wall of its own direction is seen over that much, while a furniture face or
    a plant's facets a few degrees off the walls are shorter. 0: no such test."""
    angle_tol_deg: float = 3.0
    """Parallel / perpendicular tolerance: orientation clusters closer than this are made parallel; pairs
    within this of 90° are made exactly perpendicular (eq 5.9). Other angles are kept."""
    offset_tol_m: float = 0.05
    """Offset clustering: parallel segments whose offsets (distance of the line from the origin) differ by
    less than this, in a chain, are one line."""
    max_gap_m: float = 0.8
    """Connectivity clustering: collinear pieces separated by at most this gap are one wall (the largest
    expected occlusion, doors and windows aside; like the thesis, the same as `extend_m`)."""
    extend_m: float = 0.8
    """Extension / trimming threshold: ends move at most this far to reach an intersection, and a free end
    is joined perpendicularly to a line at most this far away (the largest occlusion to close: thesis
    table 6.3 finds 0.5-1 m; a two-station TLS scan of an alcove leaves 0.65 m unseen)."""
    trim_m: float | None = None
    """Trimming threshold: an end is cut back to an intersection at most this far (None: `extend_m`, as in
    the thesis). Observed data past a partition's face is wall, not overshoot: a T-junction must not cut
    the wall it stands on back to it."""
    step_window_m: float | None = 2.0
    """A step between two parallel walls of one chain (a jog) is also judged on the pieces this far either
    side of it, not only on the whole sides (`merge_segments`): a long wall's far stretch may hold a
    doubled face or a slow bend (a drifting registration) whose spread hides a jog that the data beside
    it show. None: the whole sides only."""
    min_length_m: float = 0.0
    """Merged lines shorter than this are dropped."""
    min_overlap: float = 0.5
    """Extensions whose share of length backed by data is below this are removed (thesis: 50 %)."""

    def scaled(self, units_per_metre: float) -> LinesConfig:
        """The same config with every length expressed in another unit (e.g. pixels: 1 / pixel size)."""
        scaled = {
            f: getattr(self, f) * units_per_metre for f in _LENGTH_FIELDS if getattr(self, f) is not None
        }
        return replace(self, **scaled)


_LENGTH_FIELDS = (
    "offset_tol_m",
    "max_gap_m",
    "extend_m",
    "trim_m",
    "step_window_m",
    "min_length_m",
    "split_min_length_m",
)
