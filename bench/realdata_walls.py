"""The wall model of a real handheld capture: the 100 real Kinect v1 frames of 7-Scenes "redkitchen",
fused with their given poses into a room cloud, then preprocess and walls (the stages' own functions,
default configuration); then the same cloud subsampled to 4 cm spacing and cut at 1.5 m above the floor,
modelled again and compared.

    python -m bench.realdata_walls ../shared/realdata/rgbd_7scenes_redkitchen --png docs/kitchen_walls.png

Prints the choices the stages made (slice band and why, grid and why, the walls' noise), the walls of both
models in the cloud's frame, and how they agree: the share of each model's wall length within 10 cm of
the other's (`tasks.evaluate.evaluate_walls`, the full cloud's model as the reference) and the mean
distance. The frames' poses are KinectFusion's (camera to world, the first camera's frame: y down); the
cloud is turned so that z is roughly up and the preprocess stage levels it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from bench.walls_survey import walls_of  # noqa: E402
from tasks.camera import Calibration, CameraModel  # noqa: E402
from tasks.cloud import Cloud  # noqa: E402
from tasks.config import PipelineConfig, load_config  # noqa: E402
from tasks.evaluate import evaluate_walls  # noqa: E402
from tasks.preprocess.pipeline import Preprocessed, preprocess  # noqa: E402
from tasks.register.fusion import fuse_capture  # noqa: E402
from tasks.synth.rooms import random_subsample  # noqa: E402
from tasks.walls.model import WallModel  # noqa: E402
from tasks.walls.stage import levelled_to_input, segments_to_input  # noqa: E402

UP_FROM_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""The first camera's frame (x right, y down, z forward) to one with z up (x, z, -y)."""


def seven_scenes_cloud(folder: Path, cfg: PipelineConfig) -> NDArray[np.float64]:
    """(N, 3) the frames of a 7-Scenes folder (frame-XXXXXX.depth.png in mm, 65535 none; .pose.txt camera
    to world; camera-intrinsics.txt) fused with their poses (`fuse_capture`: the register stage's
    fusion, radial depth error estimated and taken out), turned so that z is roughly up."""
    K = np.loadtxt(folder / "camera-intrinsics.txt").reshape(3, 3)
    calib = Calibration(CameraModel(K, np.zeros(5), (640, 480)), source="camera-intrinsics.txt")
    depth_paths = sorted(folder.glob("frame-*.depth.png"))
    if not depth_paths:
        raise FileNotFoundError(f"{folder}: no frame-*.depth.png")
    poses = {
        i: np.loadtxt(p.with_name(p.name.replace(".depth.png", ".pose.txt"))).reshape(4, 4)
        for i, p in enumerate(depth_paths)
    }

    def frames(ids: set[int] | None):
        for i, p in enumerate(depth_paths):
            if ids is not None and i not in ids:
                continue
            d = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.float64)
            d[(d == 65535) | (d == 0)] = np.nan
            yield i, d / 1000.0, None

    fused, _ = fuse_capture(frames, poses, calib, cfg.register)
    return fused.points @ UP_FROM_CAMERA.T


@dataclass
class Modelled:
    pre: Preprocessed
    model: WallModel
    choices: dict[str, Any]
    walls: NDArray[np.float64]
    """(M, 4) the walls in the cloud's own frame (as the walls stage writes them for a given cloud)."""
    cpu_s: float


def model_cloud(points: NDArray[np.float64], cfg: PipelineConfig) -> Modelled:
    """preprocess, then the walls stage's model (`room_model`), walls carried back into the cloud's frame."""
    t = time.process_time()
    pre = preprocess(Cloud(points), cfg.preprocess)
    model, choices = walls_of(pre, cfg.walls)
    back, z = levelled_to_input(
        {"transform": pre.levelling.tolist(), "pivot_m": pre.metrics["levelling_pivot_m"]}
    )
    walls = segments_to_input(model.walls, back, z)
    return Modelled(pre, model, choices, walls, time.process_time() - t)


def walls_in(run: Modelled, frame: Preprocessed) -> NDArray[np.float64]:
    """(M, 4) the run's walls in `frame`'s levelled frame (the full cloud's): each wall's ends taken at mid
    slice height in the run's own levelled frame, carried to the cloud's frame and levelled by `frame`.
    Two runs level the same cloud about different pivots, so their levelled frames differ by a shift."""
    z = 0.5 * (run.pre.metrics["slice_low_z_m"] + run.pre.metrics["slice_high_z_m"])
    ends = run.model.walls.reshape(-1, 2)
    pts = np.column_stack([ends, np.full(len(ends), z)])
    T = frame.levelling @ np.linalg.inv(run.pre.levelling)
    return (pts @ T[:3, :3].T + T[:3, 3])[:, :2].reshape(-1, 4)


def handheld_cut(
    points: NDArray[np.float64], pre: Preprocessed, spacing_m: float, cut_m: float, seed: int = 0
) -> NDArray[np.float64]:
    """The cloud (N, 3) cut at `cut_m` above the floor `pre` found (levelled heights) and randomly
    subsampled to `spacing_m`."""
    T = pre.levelling
    z = (points @ T[:3, :3].T + T[:3, 3])[:, 2]
    return random_subsample(points[z - pre.floor_z_m <= cut_m], spacing_m, np.random.default_rng(seed))


def agreement(reference: NDArray[np.float64], other: NDArray[np.float64]) -> dict[str, float]:
    """How the walls `other` (M, 4) agree with `reference` (K, 4): `evaluate_walls` with the reference as
    the truth (completeness: its length within 10 cm of `other`, correctness the converse, accuracy)."""
    ev = evaluate_walls(other, reference)
    return {k: float(ev[k]) for k in ("completeness", "correctness", "accuracy_mean_m", "angle_error_deg")}


def picture(frame: Preprocessed, runs: list[tuple[str, Modelled]], grid_m: float = 0.02) -> NDArray[np.uint8]:
    """Panels side by side, north up: each run's levelled cloud in plan (grey, darker where more points
    stand above a cell) and its walls over it (blue), in `frame`'s levelled frame (the full cloud's),
    framed by `tasks.preview`."""
    from tasks.preview import Key, View, frame_picture

    points = frame.cloud.points
    lo = points[:, :2].min(axis=0) - 0.1
    hi = points[:, :2].max(axis=0) + 0.1
    shape = (int(np.ceil((hi[1] - lo[1]) / grid_m)), int(np.ceil((hi[0] - lo[0]) / grid_m)))
    scale = max(1, int(np.ceil(520 / max(shape))))
    panels = []
    for title, run in runs:
        T = frame.levelling @ np.linalg.inv(run.pre.levelling)
        pts = run.pre.cloud.points @ T[:3, :3].T + T[:3, 3]
        ij = np.floor((pts[:, :2] - lo) / grid_m).astype(np.int64)
        ok = (ij >= 0).all(axis=1) & (ij[:, 0] < shape[1]) & (ij[:, 1] < shape[0])
        counts = np.bincount(ij[ok, 1] * shape[1] + ij[ok, 0], minlength=shape[0] * shape[1]).reshape(shape)
        grey = (
            255 - 160 * np.sqrt(counts / max(np.quantile(counts[counts > 0], 0.99), 1)).clip(0, 1)
        ).astype(np.uint8)
        img = np.repeat(grey[::-1, :, None], 3, axis=2)
        img = np.ascontiguousarray(cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST))
        m_px = grid_m / scale
        top = lo[1] + shape[0] * grid_m

        def at(p: NDArray, m_px: float = m_px, top: float = top) -> tuple[int, int]:
            return round((p[0] - lo[0]) / m_px * 16), round((top - p[1]) / m_px * 16)

        for w in walls_in(run, frame):
            cv2.line(img, at(w[:2]), at(w[2:]), (25, 60, 170), 3, cv2.LINE_AA, 4)
            for p in (w[:2], w[2:]):
                cv2.circle(img, at(p), 4 << 4, (210, 30, 30), -1, cv2.LINE_AA, 4)
        legend = [
            Key("points (darker: more)", (150, 150, 150), "box"),
            Key("wall", (25, 60, 170)),
            Key("wall end", (210, 30, 30), "dot"),
        ]
        panels.append(
            frame_picture(
                img,
                View(float(lo[0]), float(top), m_px),
                title,
                legend,
                "metres, levelled frame of the full cloud",
            )
        )
    h = max(p.shape[0] for p in panels)
    padded = [np.pad(p, ((0, h - p.shape[0]), (0, 0), (0, 0)), constant_values=255) for p in panels]
    return np.concatenate(padded, axis=1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "folder", type=Path, help="a 7-Scenes folder (frame-*.depth.png, .pose.txt, camera-intrinsics.txt)"
    )
    ap.add_argument("--spacing", type=float, default=0.04, help="handheld spacing (m)")
    ap.add_argument("--cut", type=float, default=1.5, help="cut above the floor (m)")
    ap.add_argument("--png", type=Path, help="write the picture here")
    args = ap.parse_args()
    cfg = load_config([], [])
    t = time.process_time()
    points = seven_scenes_cloud(args.folder, cfg)
    print(f"fused {len(points)} points ({time.process_time() - t:.1f} s CPU)")
    full = model_cloud(points, cfg)
    cut = handheld_cut(points, full.pre, args.spacing, args.cut)
    degraded = model_cloud(cut, cfg)
    for name, run in (("full", full), (f"{100 * args.spacing:.0f} cm, cut {args.cut} m", degraded)):
        m, mm = run.pre.metrics, run.model.metrics
        print(f"\n{name}: {len(run.pre.cloud)} points after preprocess, {run.cpu_s:.1f} s CPU")
        print(
            f"  slice {m['slice_low_z_m'] - m['floor_z_m']:.2f}-{m['slice_high_z_m'] - m['floor_z_m']:.2f} m above the floor: {m['slice_reason']}"
        )
        print(
            f"  grid {mm['grid_size_m']} m ({mm['grid_reason']}); walls' noise {run.choices['wall_noise_m']} m, grid from noise: {run.choices['grid_from_noise']}"
        )
        print(f"  alpha {mm['alpha']}: {mm['alpha_reason']}")
        print(
            f"  {len(run.walls)} walls, closed {run.model.closed}, total {np.hypot(*(run.walls[:, 2:] - run.walls[:, :2]).T).sum():.2f} m"
        )
        for w in run.walls:
            print(
                f"    ({w[0]:6.3f}, {w[1]:6.3f}) - ({w[2]:6.3f}, {w[3]:6.3f})  {np.hypot(*(w[2:] - w[:2])):.2f} m"
            )
    same = agreement(walls_in(full, full.pre), walls_in(degraded, full.pre))
    print(
        f"\nagreement of the {args.spacing} m / {args.cut} m model with the full cloud's (its levelled frame): {same}"
    )
    if args.png:
        img = picture(
            full.pre,
            [
                ("7-Scenes redkitchen: walls on the fused cloud", full),
                (f"subsampled to {100 * args.spacing:.0f} cm, cut at {args.cut} m", degraded),
            ],
        )
        cv2.imwrite(str(args.png), img[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
        print(f"wrote {args.png} ({args.png.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
