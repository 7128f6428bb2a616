"""Register benchmark: the whole register stage (`register_room`: SfM, metric scale or the track fallback,
fusion) on a rendered 640x480 walk through a textured box room, in a child process so that its peak memory
is its own.

    python -m bench.register                      # 300 frames: wall s, CPU s, peak RSS, cloud digest
    python -m bench.register --frames 100 --profile 5 --save-cloud /tmp/cloud.npz
    python -m bench.register --compare /tmp/before.npz /tmp/after.npz
    python -m bench.register --fusion-only --profile 5   # fusion alone, with the walk's true poses

The frames are written as ingest writes frames.parquet (row groups of 16 frames) into `--frames-dir`
(kept, so that reruns time the same input; made when missing). Wall-clock figures depend on what else
runs on the machine: CPU seconds (user + system, every thread of the child) are printed beside them. The
cloud digest (SHA-256 of the fused points and colours) checks that a change leaves the artefact as it was.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import io
import json
import pstats
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def write_walk(folder: Path, n: int) -> Path:
    """frames.parquet (row groups of 16, as ingest writes it), camera_info.json and track.npy of a rendered
    640x480 walk of n frames around a textured 8.5 m x 6.5 m box room; returns frames.parquet's path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from tasks.artefacts import FRAMES_SCHEMA, encode_png
    from tasks.camera import CameraModel
    from tasks.synth.box_views import look_pose, render

    folder.mkdir(parents=True, exist_ok=True)
    f = 520.0
    cam = CameraModel(np.array([[f, 0, 319.5], [0, f, 239.5], [0, 0, 1]]), np.zeros(5), (640, 480))
    box = (np.array([-4.0, -3.0, 0.0]), np.array([4.5, 3.5, 2.8]))
    path = folder / "frames.parquet"
    writer = pq.ParquetWriter(path, FRAMES_SCHEMA, compression="zstd")
    rows: dict[str, list] = {name: [] for name in FRAMES_SCHEMA.names}
    for k in range(n):
        a = 2 * np.pi * k / n
        position = np.array([0.25, 0.25, 1.4]) + 0.6 * np.array([np.cos(a), np.sin(a), 0])
        z, rgb = render(cam, look_pose(position, a + 0.4, -0.45), box)
        mm = np.where(np.isfinite(z), np.round(z * 1000), 0).clip(0, 65534).astype(np.uint16)
        t = int(k * 1e8)
        for name, value in (
            ("frame_id", k),
            ("t_ns", t),
            ("rgb_t_ns", t),
            ("rgb", encode_png(rgb)),
            ("rgb_format", "png"),
            ("depth", encode_png(mm)),
            ("depth_kind", "mm"),
            ("depth_units_per_m", 1000.0),
        ):
            rows[name].append(value)
        if len(rows["frame_id"]) == 16 or k == n - 1:
            writer.write_table(pa.table(rows, schema=FRAMES_SCHEMA))
            rows = {name: [] for name in FRAMES_SCHEMA.names}
    writer.close()
    # the foot track of the walk: frames SfM cannot chain in the synthetic texture are placed by the
    # fallback, so that the figure covers SfM on every frame plus fusing every frame
    a = 2 * np.pi * np.arange(n) / n
    track = np.column_stack([np.arange(n) * 1e8, 0.25 + 0.6 * np.cos(a), 0.25 + 0.6 * np.sin(a)])
    np.save(folder / "track.npy", track)
    d = {"K": cam.K.tolist(), "dist": [0.0] * 5, "size": [640, 480], "source": "camera_info"}
    (folder / "camera_info.json").write_text(json.dumps({"depth": d, "rgb": dict(d)}))
    return path


def digest(points: np.ndarray, colors: np.ndarray | None) -> str:
    h = hashlib.sha256(np.ascontiguousarray(points, dtype="<f8").tobytes())
    if colors is not None:
        h.update(np.ascontiguousarray(colors, dtype=np.uint8).tobytes())
    return h.hexdigest()[:16]


def child(folder: Path, threads: int | None, profile: int, save: str, sets: list[str]) -> None:
    from dataclasses import replace

    from tasks.config import load_config
    from tasks.register.config import RegisterConfig
    from tasks.register.room import register_room

    sfm = load_config([], sets).sfm
    info = json.loads((folder / "camera_info.json").read_text())
    track = np.load(folder / "track.npy")
    # CPU time (every thread of the process): a profile of what the stage costs, not of the machine load
    prof = cProfile.Profile(time.process_time) if profile else None
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
        if prof:
            prof.enable()
        res = register_room(
            folder / "frames.parquet",
            info,
            None,
            RegisterConfig(),
            replace(sfm, num_threads=threads) if threads is not None else sfm,
            Path(tmp),
            track=track,
        )
        if prof:
            prof.disable()
        c1 = resource.getrusage(resource.RUSAGE_SELF)
        wall = time.perf_counter() - t0
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    if prof:
        text = io.StringIO()
        pstats.Stats(prof, stream=text).sort_stats("cumulative").print_stats(profile + 12)
        print(text.getvalue(), file=sys.stderr)
    if save:
        np.savez(save, points=res.cloud.points, colors=res.cloud.colors)
    m = res.metrics
    out = {
        "frames": m["frames"],
        "sfm_registered": m["sfm_registered"],
        "methods": m["methods"],
        "cloud_points": m["cloud_points"],
        "seconds": wall,
        "cpu_s": cpu,
        "fuse_s": m.get("fuse_s"),
        "scale_s": m.get("scale_s"),
        "sfm_s": (m.get("sfm") or {}).get("total_s"),
        "sfm_metrics": m.get("sfm") or {},
        "peak_rss_gb": c1.ru_maxrss / 1024**2,
        "cloud_digest": digest(res.cloud.points, res.cloud.colors),
        "ate_mm": walk_ate_mm(res.poses, len(track)),
    }
    print(json.dumps(out))


def walk_poses(n: int) -> dict[int, np.ndarray]:
    """The walk's true poses (frame id -> (4, 4) depth camera -> room), as `write_walk` renders them."""
    from tasks.synth.box_views import look_pose

    poses = {}
    for k in range(n):
        a = 2 * np.pi * k / n
        position = np.array([0.25, 0.25, 1.4]) + 0.6 * np.array([np.cos(a), np.sin(a), 0])
        poses[k] = look_pose(position, a + 0.4, -0.45)
    return poses


def walk_ate_mm(poses: dict[str, np.ndarray], n: int) -> float:
    """RMS distance (mm) of the placed depth-camera centres to the walk's true ones after the best
    similarity (the map's bend, not its frame or scale); NaN with fewer than 3 placed frames."""
    from tasks.benchmark import similarity_rmse

    truth = walk_poses(n)
    ok = np.isfinite(poses["tx"])
    ids = np.asarray(poses["frame_id"])[ok]
    A = np.column_stack([poses[c][ok] for c in ("tx", "ty", "tz")])
    B = np.array([truth[int(i)][:3, 3] for i in ids]).reshape(-1, 3)
    return 1000 * similarity_rmse(A, B)


def fusion_only(folder: Path, n: int, profile: int, save: str) -> None:
    """Only the stage's fusion (`_fuse_placed`: the radial depth error on a sample, then every frame
    streamed into the voxel grid) with the walk's true poses: what fusion costs, without SfM."""
    from tasks.register.config import RegisterConfig
    from tasks.register.room import _fuse_placed, calibration_from_camera_info

    calib = calibration_from_camera_info(json.loads((folder / "camera_info.json").read_text()))
    poses = walk_poses(n)
    prof = cProfile.Profile(time.process_time) if profile else None
    t0, c0 = time.perf_counter(), time.process_time()
    if prof:
        prof.enable()
    cloud, _ = _fuse_placed(folder / "frames.parquet", poses, calib, RegisterConfig(), None)
    if prof:
        prof.disable()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if prof:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(profile + 8)
    if save:
        np.savez(save, points=cloud.points, colors=cloud.colors)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(
        f"fusion of {n} frames: {wall:.1f} s wall, {cpu:.1f} s CPU, peak RSS {peak:.2f} GB, "
        f"{len(cloud):,} cloud points, digest {digest(cloud.points, cloud.colors)}"
    )


def compare(a: str, b: str) -> None:
    """The largest point difference of two saved clouds (same voxels expected) and whether colours agree."""
    x, y = np.load(a), np.load(b)
    if x["points"].shape != y["points"].shape:
        raise SystemExit(f"{a}: {x['points'].shape} points, {b}: {y['points'].shape}")
    dp = float(np.abs(x["points"] - y["points"]).max()) if len(x["points"]) else 0.0
    same_colors = bool(np.array_equal(x["colors"], y["colors"]))
    print(f"{len(x['points']):,} points; max |difference| {dp:.3g} m; colours identical: {same_colors}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300, help="rendered 640x480 frames")
    ap.add_argument("--frames-dir", default="", help="where the frames are kept (default: /tmp/...-N)")
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="SfM mapper threads (default: the config's, sfm.num_threads)",
    )
    ap.add_argument("--profile", type=int, default=0, help="print the top-N functions by cumulative time")
    ap.add_argument("--save-cloud", default="", help="write the fused cloud to this .npz")
    ap.add_argument("--fusion-only", action="store_true", help="only fusion, with the walk's true poses")
    ap.add_argument("--compare", nargs=2, metavar="NPZ", help="compare two saved clouds and exit")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="sfm.KEY=VALUE")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.compare:
        compare(*args.compare)
        return
    folder = Path(args.frames_dir or Path(tempfile.gettempdir()) / f"bench-register-{args.frames}")
    if args.child:
        child(folder, args.threads, args.profile, args.save_cloud, args.sets)
        return
    if not (folder / "camera_info.json").exists():
        t = time.perf_counter()
        write_walk(folder, args.frames)
        print(f"rendered {args.frames} frames into {folder} in {time.perf_counter() - t:.0f} s")
    if args.fusion_only:
        fusion_only(folder, args.frames, args.profile, args.save_cloud)
        return
    cmd = [sys.executable, "-m", "bench.register", "--child", "--frames", str(args.frames)]
    cmd += ["--frames-dir", str(folder), "--profile", str(args.profile)]
    cmd += ["--threads", str(args.threads)] if args.threads is not None else []
    cmd += ["--save-cloud", args.save_cloud] if args.save_cloud else []
    cmd += [f"--set={s}" for s in args.sets]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if args.profile:
        print(proc.stderr[-12000:] if proc.returncode == 0 else "")
    if proc.returncode:
        raise SystemExit(f"register on {args.frames} rendered frames failed:\n{proc.stderr[-2000:]}")
    m = json.loads(proc.stdout.strip().splitlines()[-1])
    print(
        f"register {m['frames']} frames: {m['seconds']:.1f} s wall, {m['cpu_s']:.1f} s CPU, peak RSS "
        f"{m['peak_rss_gb']:.2f} GB (targets <= 120 s, <= 1 GB); sfm {m['sfm_s']} s, scale {m['scale_s']} s, "
        f"fuse {m['fuse_s']} s; {m['sfm_registered']} registered by SfM, placed {m['methods']}; "
        f"{m['cloud_points']:,} cloud points, digest {m['cloud_digest']}; walk ATE {m['ate_mm']:.1f} mm"
    )
    sm = m["sfm_metrics"]
    print(
        "sfm CPU s: "
        + ", ".join(f"{k} {sm.get(k + '_cpu_s')}" for k in ("extract", "match", "map", "localize"))
        + f"; {sm.get('keyframes')} key frames, {sm.get('localized')} localized"
    )


if __name__ == "__main__":
    main()
