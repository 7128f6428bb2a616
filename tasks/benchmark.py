"""A run's room models against a survey's truth/ (synthetic and benchmark surveys): PIPELINE.md's wall
metrics per room, registration errors, and the figures the thesis reports, written as metrics.json.

Room models of registered captures live in their own levelled room frame; before comparing they are
brought into the plan frame by a best rigid 2D fit: first the estimated camera track onto the true one
(which also gives the trajectory error), then refined on the walls themselves (robust point-to-line
iterations on 1 cm samples within 0.10 m), so that the wall figures measure the model, not the anchor.
Clouds given in the plan frame (TLS rooms) are compared as they are.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.compute as pc
from numpy.typing import NDArray

from tasks.artefacts import read_json, read_segments, read_table
from tasks.cloud import DegenerateInputError
from tasks.evaluate import evaluate_walls
from tasks.register.scale import horn_similarity


@dataclass(frozen=True)
class RoomRun:
    """Where one room's results are (stage output folders) and its truth."""

    room: str
    walls: Path
    """walls.parquet of the room model."""
    levelling: Path | None
    """levelling.json of preprocess (registered rooms: the levelled frame the walls are in)."""
    poses: Path | None
    """poses.parquet of register (None for clouds given in the plan frame)."""


def rigid_2d(
    src: NDArray[np.float64], dst: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares rotation (2, 2) and translation (2,) taking src (N, 2) onto dst (N, 2) (Umeyama, no
    scale)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - ms).T @ (dst - md))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, d]) @ u.T
    return rot, md - rot @ ms


def similarity_scale(est: NDArray[np.float64], true: NDArray[np.float64]) -> float:
    """The scale λ of the least-squares similarity est ≈ λ · R · true + t (the register stage's Horn fit,
    eq 3.16, errors taken in the estimate; (N, 3) points), NaN for fewer than 3 or coincident points: the
    size of an estimated trajectory relative to the true one. Unlike the ratio of path lengths, position
    noise does not lengthen it: one camera 3.6 cm off its neighbour on a 0.22 m step made data/mini r2's
    path 0.2 % long while this scale was 0.02 % off."""
    try:
        return horn_similarity(true, est)[0]
    except DegenerateInputError:
        return float("nan")


def similarity_rmse(est: NDArray[np.float64], true: NDArray[np.float64]) -> float:
    """RMS distance of est (N, 3) to true (N, 3) after the least-squares similarity taking est onto true
    (Horn, eq 3.16): a trajectory's ATE without its frame or scale; NaN for fewer than 3 points."""
    if len(est) < 3:
        return float("nan")
    lam, R, T = horn_similarity(est, true)
    return float(np.sqrt(np.mean(np.sum((lam * est @ R.T + T - true) ** 2, axis=1))))


def move_segments(
    segments: NDArray[np.float64], rot: NDArray[np.float64], shift: NDArray[np.float64]
) -> NDArray[np.float64]:
    ends = np.vstack([segments[:, :2], segments[:, 2:]]) @ rot.T + shift
    return np.column_stack([ends[: len(segments)], ends[len(segments) :]])


def _samples(segments: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    out = []
    for x0, y0, x1, y1 in segments:
        n = max(2, int(np.hypot(x1 - x0, y1 - y0) / step) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        out.append(np.hstack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(out) if out else np.zeros((0, 2))


def _closest_on_segments(points: NDArray[np.float64], segments: NDArray[np.float64]) -> NDArray[np.float64]:
    a, b = segments[:, :2], segments[:, 2:]
    ab = b - a
    t = np.clip(
        np.einsum("nkd,kd->nk", points[:, None, :] - a[None], ab) / np.maximum((ab**2).sum(1), 1e-12), 0, 1
    )
    foot = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(points[:, None, :] - foot, axis=2)
    return foot[np.arange(len(points)), d.argmin(axis=1)]


def refine_on_walls(
    pred: NDArray[np.float64], truth: NDArray[np.float64], max_dist_m: float = 0.10, iterations: int = 20
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rigid 2D transform improving the fit of predicted walls onto truth walls (ICP, point-to-line by
    the closest point, pairs within `max_dist_m`)."""
    rot, shift = np.eye(2), np.zeros(2)
    samples = _samples(pred, 0.01)
    for _ in range(iterations):
        moved = samples @ rot.T + shift
        target = _closest_on_segments(moved, truth)
        near = np.linalg.norm(target - moved, axis=1) <= max_dist_m
        if near.sum() < 10:
            break
        r, s = rigid_2d(moved[near], target[near])
        rot, shift = r @ rot, r @ shift + s
        if np.linalg.norm(s) < 1e-5 and abs(np.arctan2(r[1, 0], r[0, 0])) < 1e-6:
            break
    return rot, shift


def _track(poses_path: Path, levelling_path: Path | None) -> dict[int, NDArray[np.float64]]:
    table = read_table(poses_path).to_pydict()
    xyz = np.column_stack([table["tx"], table["ty"], table["tz"]]).astype(np.float64)
    if levelling_path is not None:
        transform = np.asarray(read_json(levelling_path)["transform"], dtype=np.float64)
        xyz = xyz @ transform[:3, :3].T + transform[:3, 3]
    return {int(t): p for t, p in zip(table["t_ns"], xyz, strict=True) if np.isfinite(p).all()}


def evaluate_room(run: RoomRun, truth_dir: Path) -> dict[str, Any]:
    """Wall metrics of one room model in the plan frame, and its registration figures."""
    truth_table = read_table(truth_dir / "walls.parquet")
    mine = truth_table.filter(pc.equal(truth_table["room_id"], run.room))
    truth = np.column_stack([mine[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
    pred, _ = read_segments(run.walls)
    out: dict[str, Any] = {"room": run.room}
    if len(truth) == 0:
        return {**out, "skipped": "no truth walls for this room"}
    if len(pred) == 0:
        return {**out, "walls_pred": 0, "completeness": 0.0, "correctness": 0.0}
    truth_poses = truth_dir / "poses" / f"{run.room}.parquet"
    if run.poses is not None and truth_poses.is_file():
        est = _track(run.poses, run.levelling)
        true = _track(truth_poses, None)
        common = sorted(set(est) & set(true))
        if len(common) >= 3:
            src = np.array([est[t][:2] for t in common])
            dst = np.array([true[t][:2] for t in common])
            rot, shift = rigid_2d(src, dst)
            residual = src @ rot.T + shift - dst
            out["ate_2d_rmse_m"] = float(np.sqrt((residual**2).sum(axis=1).mean()))
            est_len = float(np.linalg.norm(np.diff(np.array([est[t] for t in common]), axis=0), axis=1).sum())
            true_len = float(
                np.linalg.norm(np.diff(np.array([true[t] for t in common]), axis=0), axis=1).sum()
            )
            # the scale error is that of the best similarity of the camera positions (README); the path
            # length ratio, which every misplaced camera lengthens, is kept beside it
            scale = similarity_scale(np.array([est[t] for t in common]), np.array([true[t] for t in common]))
            out["scale_error_pct"] = 100.0 * (scale - 1.0)
            out["path_length_error_pct"] = (
                100.0 * (est_len / true_len - 1.0) if true_len > 0 else float("nan")
            )
            out["frames_compared"] = len(common)
            pred = move_segments(pred, rot, shift)
        refine_rot, refine_shift = refine_on_walls(pred, truth)
        out["wall_fit_shift_m"] = float(np.linalg.norm(refine_shift))
        out["wall_fit_rotation_deg"] = float(np.degrees(np.arctan2(refine_rot[1, 0], refine_rot[0, 0])))
        pred = move_segments(pred, refine_rot, refine_shift)
    out.update(evaluate_walls(pred, truth))
    return out


def evaluate_runs(runs: list[RoomRun], truth_dir: Path) -> dict[str, Any]:
    """metrics.json: per room, and the length-weighted means over rooms."""
    rooms = [evaluate_room(run, truth_dir) for run in runs]
    scored = [r for r in rooms if "completeness" in r]
    summary: dict[str, Any] = {"rooms": len(rooms)}
    for key in ("completeness", "correctness", "accuracy_mean_m", "accuracy_median_m", "corner_f1"):
        values = [r[key] for r in scored if np.isfinite(r.get(key, np.nan))]
        summary[f"mean_{key}"] = float(np.mean(values)) if values else None
    ate = [r["ate_2d_rmse_m"] for r in rooms if "ate_2d_rmse_m" in r]
    summary["mean_ate_2d_rmse_m"] = float(np.mean(ate)) if ate else None
    return {"summary": summary, "rooms": rooms}
