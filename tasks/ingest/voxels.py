"""Voxel reduction while a cloud streams in: per-voxel sums kept in arrays sorted by the packed voxel
index, so memory grows with the occupied surface, never with the number of points read.

Each chunk is reduced on its own (np.unique over its keys); a few chunks' sums are pooled, then merged
into the running sums: voxels already seen are added in place, new ones inserted at their sorted
positions (one copy of the running arrays per merge, hence the pooling). The result is one point per
voxel, the centroid of everything that fell into it, with colour and intensity averaged. It does not
depend on how the stream was cut into chunks beyond float rounding (sums are grouped differently).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

OFFSET = 1 << 20
"""Voxel indices are offset into 21 bits per axis: ±1 M voxels (±10 km at 1 cm) around the origin."""

POOL_VOXELS = 500_000
"""Chunk sums pooled before a merge into the running sums (about 20 MB)."""


class VoxelRangeError(ValueError):
    """A point too far from the origin for the packed voxel index."""


class VoxelAccumulator:
    """Running per-voxel sums of an origin-anchored grid of edge `voxel_m` (the grid of
    `tasks.preprocess.voxel_grid`, so a coarser preprocess voxel that is a whole multiple of this one
    is a union of these voxels).

    Per occupied voxel it holds the packed key (int64), the point count (uint32), the sum of the points'
    offsets from the voxel's corner (float32: offsets are under one voxel, so float32 keeps well under a
    micrometre) and, when asked for, colour and intensity sums (float32): 24 to 40 bytes a voxel."""

    def __init__(self, voxel_m: float, colour: bool, intensity: bool) -> None:
        if not voxel_m > 0:
            raise ValueError(f"voxel edge must be positive, got {voxel_m}")
        self.voxel = float(voxel_m)
        self.keys = np.zeros(0, np.int64)
        self.counts = np.zeros(0, np.uint32)
        self.offsets = np.zeros((0, 3), np.float32)
        self.colours = np.zeros((0, 3), np.float32) if colour else None
        self.intensity = np.zeros(0, np.float32) if intensity else None
        self._pool: list[tuple[NDArray[np.int64], NDArray[np.uint32], dict[str, NDArray[np.float32]]]] = []
        self._pooled = 0

    def __len__(self) -> int:
        self._flush()
        return len(self.keys)

    def _index(self, points: NDArray[np.float64]) -> NDArray[np.int64]:
        """(N, 3) integer voxel indices of (N, 3) points, checked against the packing range."""
        ijk = np.floor(points / self.voxel).astype(np.int64)
        if len(ijk) and (ijk.min() < -OFFSET or ijk.max() >= OFFSET):
            far = float(np.abs(points).max())
            raise VoxelRangeError(
                f"a point lies {far:.4g} m from the origin, beyond the {OFFSET * self.voxel:.4g} m a "
                f"{self.voxel} m voxel grid reaches"
            )
        return ijk

    def add(
        self,
        points: NDArray[np.float64],
        colours: NDArray[np.floating] | None = None,
        intensity: NDArray[np.floating] | None = None,
    ) -> None:
        """Add (N, 3) points (metres) with their (N, 3) colours and (N,) intensities when the
        accumulator keeps those (in the file's own units: the caller scales the means)."""
        if len(points) == 0:
            return
        # the chunk's working arrays are gone once _reduce returns, before any merge needs memory
        uniq, counts, columns = self._reduce(points, colours, intensity)
        self._pool.append((uniq, counts, columns))
        self._pooled += len(uniq)
        if self._pooled >= POOL_VOXELS:
            self._flush()

    def _reduce(
        self,
        points: NDArray[np.float64],
        colours: NDArray[np.floating] | None,
        intensity: NDArray[np.floating] | None,
    ) -> tuple[NDArray[np.int64], NDArray[np.uint32], dict[str, NDArray[np.float32]]]:
        """One chunk's sorted unique keys (m,), point counts (m,) and per-voxel sums."""
        ijk = self._index(points)
        offsets = points - ijk * self.voxel
        ijk += OFFSET
        keys = (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]
        del ijk
        uniq, inv = np.unique(keys, return_inverse=True)
        del keys
        inv = inv.ravel()
        m = len(uniq)
        counts = np.bincount(inv, minlength=m).astype(np.uint32)
        columns = {"offsets": _sums(inv, offsets, m)}
        if self.colours is not None:
            columns["colours"] = _sums(inv, colours, m)
        if self.intensity is not None:
            columns["intensity"] = np.bincount(inv, weights=intensity, minlength=m).astype(np.float32)
        return uniq, counts, columns

    def _flush(self) -> None:
        """Merge the pooled chunk sums (first into one sorted set of their own) into the running sums."""
        if not self._pool:
            return
        if len(self._pool) == 1:
            keys, counts, columns = self._pool[0]
        else:
            uniq, inv = np.unique(np.concatenate([k for k, _, _ in self._pool]), return_inverse=True)
            inv = inv.ravel()
            m = len(uniq)
            counts = np.bincount(inv, np.concatenate([c for _, c, _ in self._pool]), m).astype(np.uint32)
            columns = {}
            for name in self._pool[0][2]:
                stacked = np.concatenate([cols[name] for _, _, cols in self._pool])
                if stacked.ndim == 1:
                    columns[name] = np.bincount(inv, stacked, m).astype(np.float32)
                else:
                    columns[name] = _sums(inv, stacked, m)
            keys = uniq
        self._pool, self._pooled = [], 0
        self._merge(keys, counts, columns)

    def _merge(
        self, keys: NDArray[np.int64], counts: NDArray[np.uint32], columns: dict[str, NDArray[np.float32]]
    ) -> None:
        """Add one chunk's per-voxel sums (sorted, unique `keys`) into the running sums."""
        pos = np.searchsorted(self.keys, keys)
        seen = pos < len(self.keys)
        seen[seen] = self.keys[pos[seen]] == keys[seen]
        at = pos[seen]
        # `at` holds each position at most once (the chunk's keys are unique), so += is safe
        self.counts[at] += counts[seen]
        for name, sums in columns.items():
            getattr(self, name)[at] += sums[seen]
        new = ~seen
        if not new.any():
            return
        where = pos[new]
        # one array at a time: the copy np.insert makes is the only extra memory of a merge
        self.keys = np.insert(self.keys, where, keys[new])
        self.counts = np.insert(self.counts, where, counts[new])
        for name, sums in columns.items():
            setattr(self, name, np.insert(getattr(self, name), where, sums[new], axis=0))

    def points(self, start: int = 0, stop: int | None = None) -> NDArray[np.float64]:
        """(K, 3) the centroids of voxels [start, stop) in key order (metres)."""
        self._flush()
        keys = self.keys[start:stop]
        ijk = np.column_stack([(keys >> 42) & 0x1FFFFF, (keys >> 21) & 0x1FFFFF, keys & 0x1FFFFF]) - OFFSET
        mean = self.offsets[start:stop].astype(np.float64) / self.counts[start:stop, None]
        return ijk * self.voxel + mean

    def mean_colours(self, start: int = 0, stop: int | None = None) -> NDArray[np.float64] | None:
        """(K, 3) mean colours of voxels [start, stop) in the file's units, or None."""
        self._flush()
        if self.colours is None:
            return None
        return self.colours[start:stop].astype(np.float64) / self.counts[start:stop, None]

    def mean_intensity(self, start: int = 0, stop: int | None = None) -> NDArray[np.float32] | None:
        """(K,) mean intensities of voxels [start, stop) in the file's units, or None."""
        self._flush()
        if self.intensity is None:
            return None
        return (self.intensity[start:stop] / self.counts[start:stop]).astype(np.float32)


def _sums(inv: NDArray[np.intp], values: NDArray[np.floating], m: int) -> NDArray[np.float32]:
    """(m, 3) per-group column sums of (N, 3) values grouped by `inv`, each summed in float64."""
    out = np.empty((m, 3), np.float32)
    for a in range(3):
        out[:, a] = np.bincount(inv, weights=values[:, a], minlength=m)
    return out


class KeepAll:
    """The accumulator's interface without reduction (`cloud_voxel_m` = 0): every point kept, in the order
    read; memory grows with the file."""

    def __init__(self, colour: bool, intensity: bool) -> None:
        self._points: list[NDArray[np.float64]] = []
        self._colours: list[NDArray[np.floating]] | None = [] if colour else None
        self._intensity: list[NDArray[np.floating]] | None = [] if intensity else None
        self._joined: (
            tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float32] | None] | None
        )
        self._joined = None

    def __len__(self) -> int:
        return sum(len(p) for p in self._points)

    def add(
        self,
        points: NDArray[np.float64],
        colours: NDArray[np.floating] | None = None,
        intensity: NDArray[np.floating] | None = None,
    ) -> None:
        """Keep (N, 3) points with their (N, 3) colours and (N,) intensities (when kept)."""
        self._points.append(np.asarray(points, np.float64))
        if self._colours is not None and colours is not None:
            self._colours.append(colours)
        if self._intensity is not None and intensity is not None:
            self._intensity.append(intensity)

    def _join(self) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float32] | None]:
        if self._joined is None:
            points = np.concatenate(self._points) if self._points else np.zeros((0, 3))
            colours = None if self._colours is None else np.concatenate(self._colours).astype(np.float64)
            intensity = (
                None if self._intensity is None else np.concatenate(self._intensity).astype(np.float32)
            )
            self._joined = (points, colours, intensity)
            self._points = [points]
        return self._joined

    def points(self, start: int = 0, stop: int | None = None) -> NDArray[np.float64]:
        """(K, 3) points [start, stop) in the order read."""
        return self._join()[0][start:stop]

    def mean_colours(self, start: int = 0, stop: int | None = None) -> NDArray[np.float64] | None:
        """(K, 3) colours [start, stop) in the file's units, or None."""
        colours = self._join()[1]
        return None if colours is None else colours[start:stop]

    def mean_intensity(self, start: int = 0, stop: int | None = None) -> NDArray[np.float32] | None:
        """(K,) intensities [start, stop) in the file's units, or None."""
        intensity = self._join()[2]
        return None if intensity is None else intensity[start:stop]
