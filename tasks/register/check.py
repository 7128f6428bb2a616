"""Is an SfM map consistent with the depth? Checks from the data alone (no truth), beyond the thesis.

The mapper now and then registers a frame wrongly (seen on a synthetic room: a frame of a low-texture wall
registered on 49 points, 0.8 m from where it stood, which broke the chain so that the next five frames were
not registered at all) or bends the whole map. Two checks tell such a map from a good one:

- **neighbour depth**: every placed frame's depth, moved by the metric poses into the frames placed just
  before and after it in the capture, must lie on the surfaces those frames' depth sees, not in the free
  space in front of them. A point of frame a that lands in frame b nearer than what b measures there (by
  more than the depth noise) sits where b looked through: one of the two poses is wrong. A frame none of
  whose neighbour pairs agree is inconsistent. A pair that disagrees while both its frames agree with
  their other neighbours is a broken link: the map is split into two parts, each consistent on its own,
  placed apart (seen on synthetic rooms 731 r4 and 824 r2: 0.63 and 0.73 agreement at one pair, 8 cm and
  more trajectory error, +1.1 % and -0.3 % path-length scale error; every well-mapped pair of 40 rooms
  0.88 or more);
- **scale trend** (`ScaleReport.relative_trend`): a bent map drifts in scale along the capture.

Frames are the depth camera's, poses depth camera -> room (metres), as `apply_scale` gives them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.camera import CameraModel, strided_depth_points


@dataclass
class PairAgreement:
    """Depth agreement of two frames placed one after the other (both directions pooled)."""

    a: str
    b: str
    agree: int
    """Points of one frame landing within the tolerance of the other's measured surface."""
    in_front: int
    """Points of one frame landing in the other's free space (nearer than its surface beyond tolerance)."""

    @property
    def checked(self) -> int:
        return self.agree + self.in_front

    @property
    def share(self) -> float:
        """agree / (agree + in_front); NaN when the two frames see nothing in common."""
        return self.agree / self.checked if self.checked else float("nan")


@dataclass
class DepthConsistency:
    """The neighbour depth check over a capture."""

    pairs: list[PairAgreement]
    inconsistent: list[str]
    """Frames whose every informative neighbour pair disagrees."""
    min_share: float
    """Lowest share over the informative pairs (NaN: none)."""
    median_share: float
    tolerance: tuple[float, float]
    """(m, fraction of the depth) used."""
    frames: dict[str, float] = field(default_factory=dict)
    """Frame name -> its best informative pair's share (NaN when it has none)."""
    broken_links: list[tuple[str, str]] = field(default_factory=list)
    """Informative pairs agreeing on less than the minimum share whose frames are both consistent: the map
    breaks between them."""

    def to_json(self) -> dict[str, Any]:
        return {
            "pairs": len(self.pairs),
            "informative_pairs": sum(1 for p in self.pairs if np.isfinite(p.share)),
            "min_pair_agreement": _round(self.min_share),
            "median_pair_agreement": _round(self.median_share),
            "inconsistent_frames": list(self.inconsistent),
            "broken_links": [f"{a}-{b}" for a, b in self.broken_links],
            "tolerance_m": self.tolerance[0],
            "tolerance_rel": self.tolerance[1],
        }


def _round(x: float) -> float | None:
    return round(float(x), 4) if np.isfinite(x) else None


def _project_into(
    pts_a: NDArray[np.float64],
    b_from_a: NDArray[np.float64],
    depth_b: NDArray[np.floating],
    camera: CameraModel,
    tol_m: float,
    tol_rel: float,
    min_depth_m: float,
    max_depth_m: float,
) -> tuple[int, int]:
    """(agree, in_front) of frame a's points seen from frame b."""
    p = pts_a @ b_from_a[:3, :3].T + b_from_a[:3, 3]
    ui, vi, z = camera.pixels(p)
    zb = np.asarray(depth_b, dtype=np.float64)[vi, ui]
    measured = np.isfinite(zb) & (zb >= min_depth_m) & (zb <= max_depth_m)
    zb, z = zb[measured], z[measured]
    tol = tol_m + tol_rel * zb
    agree = np.abs(z - zb) <= tol
    in_front = z < zb - tol
    return int(agree.sum()), int(in_front.sum())


def neighbour_depth_consistency(
    frames: Iterable[tuple[str, NDArray[np.floating]]],
    poses: dict[str, NDArray[np.float64]],
    camera: CameraModel,
    tol_m: float,
    tol_rel: float,
    min_share: float,
    min_points: int = 200,
    stride: int = 4,
    min_depth_m: float = 0.5,
    max_depth_m: float = 6.0,
) -> DepthConsistency:
    """The neighbour depth check (module doc) over a capture.

    frames: (frame name, (H, W) depth in metres of `camera`, 0/NaN = none) in capture order, streamed (only
    the previous placed frame is held); poses: frame name -> (4, 4) depth camera -> room of the placed frames
    (others are skipped). Each placed frame is compared with the previous placed one, both ways, on every
    `stride`-th depth pixel; a pair with fewer than `min_points` points landing on the other's measured
    depth is uninformative. A frame is inconsistent when it has an informative pair and all its
    informative pairs agree on less than `min_share` of their points."""
    pairs: list[PairAgreement] = []
    prev: tuple[str, NDArray[np.float64], NDArray[np.float64]] | None = None
    for fid, depth in frames:
        if fid not in poses:
            continue
        d = np.asarray(depth, dtype=np.float64)
        d = np.where(np.isfinite(d), d, 0.0)
        pts = strided_depth_points(d, camera, stride)
        if prev is not None:
            pid, pdepth, ppts = prev
            b_from_a = np.linalg.inv(poses[fid]) @ poses[pid]
            ag1, fr1 = _project_into(ppts, b_from_a, d, camera, tol_m, tol_rel, min_depth_m, max_depth_m)
            ag2, fr2 = _project_into(
                pts, np.linalg.inv(b_from_a), pdepth, camera, tol_m, tol_rel, min_depth_m, max_depth_m
            )
            pairs.append(PairAgreement(pid, fid, ag1 + ag2, fr1 + fr2))
        prev = (fid, d, pts)
    return judge_pairs(pairs, min_share, min_points, (tol_m, tol_rel))


def judge_pairs(
    pairs: list[PairAgreement],
    min_share: float,
    min_points: int,
    tolerance: tuple[float, float] = (0.0, 0.0),
) -> DepthConsistency:
    """The inconsistent frames of a chain of neighbour pairs (`neighbour_depth_consistency`): a frame whose
    informative pairs (at least `min_points` checked) all agree on less than `min_share`. A wrong frame
    spoils both its pairs, while its neighbours keep their other, good pair; a neighbour whose only
    informative pair is the one with a frame spoiling two is not blamed."""
    informative = [p for p in pairs if p.checked >= min_points]
    best: dict[str, float] = {}
    for p in pairs:
        for f in (p.a, p.b):
            best.setdefault(f, float("nan"))
    for p in informative:
        for f in (p.a, p.b):
            best[f] = p.share if not np.isfinite(best[f]) else max(best[f], p.share)
    suspects = {f for f, s in best.items() if np.isfinite(s) and s < min_share}
    bad_pairs = {f: [p for p in informative if f in (p.a, p.b)] for f in suspects}
    # a frame whose one informative pair is with a suspect that disagrees with more frames is cleared:
    # the other one is to blame (its own other neighbours are checked once it is left out)
    inconsistent = sorted(
        f
        for f in suspects
        if not (
            len(bad_pairs[f]) == 1
            and (other := bad_pairs[f][0].b if bad_pairs[f][0].a == f else bad_pairs[f][0].a) in suspects
            and len(bad_pairs[other]) > 1
        )
    )
    shares = np.array([p.share for p in informative])
    return DepthConsistency(
        pairs,
        inconsistent,
        float(shares.min()) if len(shares) else float("nan"),
        float(np.median(shares)) if len(shares) else float("nan"),
        tolerance,
        best,
        broken_links(informative, min_share, set(inconsistent)),
    )


def broken_links(
    pairs: list[PairAgreement], min_share: float, inconsistent: set[str]
) -> list[tuple[str, str]]:
    """(a, b) of the informative `pairs` agreeing on less than `min_share` where neither frame is
    `inconsistent`: both frames agree with their other neighbours, so the map, not a frame, is wrong
    between them (a pair with a wrong frame is that frame's fault and is not listed)."""
    return [
        (p.a, p.b)
        for p in pairs
        if p.share < min_share and p.a not in inconsistent and p.b not in inconsistent
    ]
