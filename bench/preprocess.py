"""Benchmark of the preprocess stage on a synthetic furnished room (`tasks.synth.rooms.tilted_box_room`, the
preprocess tests' room, scaled up).

    python -m bench.preprocess                      # 5 M points: points/s per step and overall, peak memory
    python -m bench.preprocess --points 1000000 --order-study --level-study --voxel-study
    python -m bench.preprocess --profile 25          # and the stage's top 25 functions by cumulative time
    python -m bench.preprocess --threads-check       # and again on one thread: the same bytes?

Run from the repository root. Wall-clock figures depend on what else runs on the machine: CPU seconds are
printed beside them.
"""

from __future__ import annotations

import argparse
import cProfile
import math
import os
import pstats
import threading
import time
from dataclasses import replace

import numpy as np

from tasks.cloud import Cloud
from tasks.preprocess import filters
from tasks.preprocess.config import PreprocessConfig
from tasks.preprocess.filters import mls_smooth, statistical_outliers, voxel_grid
from tasks.preprocess.levelling import level_by_normals
from tasks.preprocess.pipeline import preprocess
from tasks.synth.rooms import (
    FAR_M,
    residual_tilt_deg,
    surface_distance,
    tilted_box_room,
    to_room_frame,
)

ROOM = (6.0, 5.0, 2.70)


class PeakRSS:
    """Samples the process's resident memory every 20 ms while active."""

    def __init__(self) -> None:
        self.base = self.peak = self._rss()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def _rss() -> int:
        with open(f"/proc/{os.getpid()}/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
        return 0

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            self.peak = max(self.peak, self._rss())

    def __enter__(self) -> PeakRSS:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._rss())


def whole_stage(n_points: int, cfg: PreprocessConfig, profile: int = 0, threads_check: bool = False) -> None:
    t = time.perf_counter()
    cloud, truth = tilted_box_room(n_points, seed=11, size=ROOM)
    print(
        f"room {ROOM[0]} x {ROOM[1]} x {ROOM[2]} m, {len(cloud):,} points "
        f"({int(truth.outliers.sum()):,} outliers), generated in {time.perf_counter() - t:.1f} s"
    )
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.1f}")
    prof = cProfile.Profile() if profile else None
    cpu = time.process_time()
    with PeakRSS() as memory:
        if prof:
            prof.enable()
        result = preprocess(cloud, cfg)
        if prof:
            prof.disable()
    cpu = time.process_time() - cpu
    if prof:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(profile)
    m = result.metrics
    timings, cpu_timings = m["timings_s"], m["cpu_timings_s"]
    step_inputs = {
        "check": m["points_in"],
        "voxel": m["points_in"],
        "outliers": m["points_after_voxel"],
        "mls": m["points_after_outliers"],
        "level": m["points_after_outliers"],
        "histogram": m["points_out"],
        "slice": m["points_out"],
        "render": m["points_out"],
    }
    print(f"\n{'step':<10} {'points in':>11} {'seconds':>8} {'CPU s':>7} {'points/s':>12} {'per CPU s':>12}")
    for step, points in [*step_inputs.items(), ("total", m["points_in"])]:
        seconds, cpu_s = timings[step], cpu_timings[step]
        print(
            f"{step:<10} {points:>11,} {seconds:>8.2f} {cpu_s:>7.2f} {points / max(seconds, 1e-9):>12,.0f} "
            f"{points / max(cpu_s, 1e-9):>12,.0f}"
        )
    print(f"\nCPU time {cpu:.1f} s (both cores); load average after: {os.getloadavg()[0]:.1f}")
    print(
        f"peak RSS {memory.peak / 2**30:.2f} GiB; above the input cloud and its generator: "
        f"{(memory.peak - memory.base) / 2**30:.2f} GiB"
    )
    distance = surface_distance(to_room_frame(result.cloud.points, result.levelling, truth), truth.boxes)
    print(
        f"\nheight {result.height_m:.4f} m (truth {truth.height_m:.2f}), residual tilt "
        f"{residual_tilt_deg(result.levelling, truth):.3f}°, points > {FAR_M} m from the true surfaces "
        f"{int((distance > FAR_M).sum())} (input: {int(truth.far_outliers.sum()):,} far outliers); "
        f"distance to truth median {1000 * np.median(distance):.2f} mm, "
        f"p99 {1000 * np.percentile(distance, 99):.1f} mm"
    )
    if threads_check:
        # the same bytes with the work on one thread: the chunks are fixed, whatever shares them
        default_threads = filters._THREADS
        filters._THREADS = 1
        try:
            single = preprocess(cloud, cfg)
        finally:
            filters._THREADS = default_threads
        same = all(
            np.array_equal(a, b)
            for a, b in (
                (single.cloud.points, result.cloud.points),
                (single.cloud.colors, result.cloud.colors),
                (single.slice.points, result.slice.points),
                (single.levelling, result.levelling),
            )
        )
        print(f"one thread against {default_threads}: {'the same bytes' if same else 'DIFFERENT output'}")
    print(
        f"points: in {m['points_in']:,}, voxels {m['points_after_voxel']:,}, after outliers "
        f"{m['points_after_outliers']:,}, slice {m['slice_points']:,}; "
        f"MLS edge points {m['mls_edge_points']:,}, capped fits {m['mls_capped_fraction']:.1%}; "
        f"warnings {m['warnings']}"
    )


def _level(voxels: Cloud, counts: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """The stage's MLS + levelling on an already filtered voxel cloud: the 4x4 levelling rotation."""
    surfaces = mls_smooth(voxels.points, cfg.mls_radius_m, cfg.mls_degree, cfg.mls_edge_ratio, counts)
    levelling = np.eye(4)
    levelling[:3, :3], _ = level_by_normals(surfaces.normals[~surfaces.edge], cfg)
    return levelling


def order_study(n_points: int, cfg: PreprocessConfig) -> None:
    """Outlier filter before or after the voxel grid: time, far voxels left, surface voxels kept, tilt."""
    print(f"\n--- order study: {n_points:,} points, voxel {cfg.voxel_size_m} m")
    cloud, truth = tilted_box_room(n_points, seed=5, size=ROOM)

    def far_and_near(points: np.ndarray) -> tuple[int, int]:
        d = surface_distance((points - truth.room_to_input[:3, 3]) @ truth.room_to_input[:3, :3], truth.boxes)
        return int((d > FAR_M).sum()), int((d <= 0.02).sum())

    t = time.perf_counter()
    keep, _ = statistical_outliers(cloud.points, cfg.outlier_neighbours, cfg.outlier_std_ratio)
    t_filter = time.perf_counter() - t
    raw_first = voxel_grid(cloud.subset(keep), cfg.voxel_size_m)
    t_raw = time.perf_counter() - t
    t = time.perf_counter()
    voxels, counts = voxel_grid(cloud, cfg.voxel_size_m)
    keep_v, _ = statistical_outliers(voxels.points, cfg.outlier_neighbours, cfg.outlier_std_ratio)
    voxel_first = (voxels.subset(keep_v), counts[keep_v])
    t_voxel = time.perf_counter() - t
    far_in, near_in = far_and_near(voxels.points)
    for name, seconds, (clean, clean_counts) in (
        (f"raw first ({t_filter:.1f} s filter)", t_raw, raw_first),
        ("voxel first (the stage)", t_voxel, voxel_first),
    ):
        far, near = far_and_near(clean.points)
        tilt = residual_tilt_deg(_level(clean, clean_counts, cfg), truth)
        print(
            f"{name:<30} {seconds:6.2f} s  far voxels left {far:>5} of {far_in:,}; "
            f"surface voxels kept {near / near_in:.1%}; residual tilt after MLS + levelling {tilt:.3f}°"
        )


def level_study(n_points: int, cfg: PreprocessConfig) -> None:
    """Residual tilt of each normal set when floor and ceiling are partly or not captured."""
    print(f"\n--- levelling study: {n_points:,} points, residual tilt in degrees")
    scenarios = [
        ("full floor + ceiling", {}),
        ("30 % floor, 30 % ceiling", {"floor_fraction": 0.3, "ceiling_fraction": 0.3}),
        ("10 % floor, no ceiling", {"floor_fraction": 0.1, "ceiling_fraction": 0.0}),
        ("full, noise x4", {"noise_scale": 4.0}),
        (
            "10 % floor, no ceiling, noise x4",
            {"floor_fraction": 0.1, "ceiling_fraction": 0.0, "noise_scale": 4.0},
        ),
    ]
    modes = ("horizontal", "vertical", "both")
    print(f"{'scenario':<34}" + "".join(f"{mode:>12}" for mode in modes))
    for name, kwargs in scenarios:
        cloud, truth = tilted_box_room(n_points, seed=9, size=ROOM, **kwargs)
        voxels, counts = voxel_grid(cloud, cfg.voxel_size_m)
        keep, _ = statistical_outliers(voxels.points, cfg.outlier_neighbours, cfg.outlier_std_ratio)
        clean, clean_counts = voxels.subset(keep), counts[keep]
        tilts = [
            residual_tilt_deg(_level(clean, clean_counts, replace(cfg, level_normals=m)), truth)
            for m in modes
        ]
        print(f"{name:<34}" + "".join(f"{t:12.3f}" for t in tilts))


def voxel_study(n_points: int, cfg: PreprocessConfig) -> None:
    """The whole stage at several voxel sizes: time, height, tilt, distance of the output to the truth."""
    print(f"\n--- voxel size study: {n_points:,} points")
    cloud, truth = tilted_box_room(n_points, seed=13, size=ROOM)
    print(
        f"{'voxel m':>8} {'seconds':>8} {'cpu s':>7} {'points out':>11} {'height err mm':>14} "
        f"{'tilt °':>7} {'median mm':>10} {'p99 mm':>7}"
    )
    for size in (0.01, 0.015, 0.02, 0.03):
        cpu = time.process_time()
        result = preprocess(cloud, replace(cfg, voxel_size_m=size))
        cpu = time.process_time() - cpu
        d = surface_distance(to_room_frame(result.cloud.points, result.levelling, truth), truth.boxes)
        print(
            f"{size:>8} {result.metrics['timings_s']['total']:>8.1f} {cpu:>7.1f} {len(result.cloud):>11,} "
            f"{1000 * (result.height_m - truth.height_m):>14.1f} "
            f"{residual_tilt_deg(result.levelling, truth):>7.3f} "
            f"{1000 * np.median(d):>10.2f} {1000 * np.percentile(d, 99):>7.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--points", type=int, default=5_000_000, help="points in the benchmark room")
    parser.add_argument("--study-points", type=int, default=1_000_000, help="points in the study rooms")
    parser.add_argument(
        "--order-study", action="store_true", help="outlier filter before/after the voxel grid"
    )
    parser.add_argument("--level-study", action="store_true", help="horizontal / vertical / both normals")
    parser.add_argument("--voxel-study", action="store_true", help="the stage at voxel sizes 1-3 cm")
    parser.add_argument("--skip-main", action="store_true", help="only the studies")
    parser.add_argument("--profile", type=int, default=0, help="print the stage's top-N functions (cProfile)")
    parser.add_argument(
        "--threads-check", action="store_true", help="run the stage again on one thread: the same bytes?"
    )
    args = parser.parse_args()
    cfg = PreprocessConfig()
    if not args.skip_main:
        whole_stage(args.points, cfg, args.profile, args.threads_check)
    if args.order_study:
        order_study(args.study_points, cfg)
    if args.level_study:
        level_study(math.ceil(args.study_points / 2), cfg)
    if args.voxel_study:
        voxel_study(args.study_points, cfg)


if __name__ == "__main__":
    main()
