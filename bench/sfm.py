"""Register benchmark: seconds per frame of SfM and of the metric scale on real 640x480 Kinect frames with
their accuracy, the yardstick (plain pycolmap on the same frames), and the time and peak memory of the whole
register stage on a long capture.

    python -m bench.sfm                          # 100 frames: SfM, scale, yardstick; register 300 frames
    python -m bench.sfm --frames 30 --register-frames 0 --no-yardstick     # a quick check
    python -m bench.sfm --set sfm.max_num_features=2048                     # another SfM setting

Run from the repository root. SfM and scale run on real Kinect v1 frames (7-Scenes redkitchen, every 10th
frame of the recording, ../shared/realdata beside the repository) with the stage's default configuration
(`--set` overrides it): frames registered and the ATE (RMS of the camera centres after the best similarity
onto the given poses) are printed next to the time. The yardstick runs plain pycolmap on the same frames in
the same process: SIFT on the CPU with its default options, sequential matching with overlap 10 and
incremental mapping with multiple models, all threads; then the whole register stage (the frames ingested
first, then the stage as a run computes it: depth correction, SfM, scale, fusion) and prints the ratio of
the two times (target <= 0.6x). The memory figure comes from a child process running `register_room` on a
rendered 640x480 walk through a textured box room with `--register-frames` frames.

Wall-clock figures depend on what else runs on the machine: CPU seconds (all threads of the process) are
printed beside them, and `--json FILE` writes every figure.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from tasks.benchmark import similarity_rmse
from tasks.camera import Calibration, CameraModel, RigidPose
from tasks.register.config import ScaleConfig, SfmConfig
from tasks.register.scale import estimate_scale
from tasks.register.sfm import run_sfm
from tasks.synth.box_views import look_pose, render, write_rendered_frames

REPO = Path(__file__).resolve().parents[1]
REALDATA = REPO.parent / "shared" / "realdata" / "rgbd_7scenes_redkitchen"
KINECT = CameraModel(np.array([[585.0, 0, 320], [0, 585, 240], [0, 0, 1]]), np.zeros(5), (640, 480))
"""7-Scenes' nominal intrinsics (one set for both streams, as its camera-intrinsics.txt gives)."""


def real_frames(n: int) -> list[Path]:
    """The first n colour frames of the 7-Scenes recording."""
    files = sorted(REALDATA.glob("frame-*.color.jpg"))[:n]
    if len(files) < n:
        raise SystemExit(f"{REALDATA}: only {len(files)} colour frames, {n} asked")
    return files


def ate_m(centres: dict[str, np.ndarray], files: list[Path]) -> float:
    """RMS distance of the camera centres (frame name k:06d.png -> (3,)) to the given 7-Scenes camera
    centres after the best similarity mapping the first onto the second; NaN with fewer than 3."""
    names = [(f"{k:06d}.png", f) for k, f in enumerate(files) if f"{k:06d}.png" in centres]
    if len(names) < 3:
        return float("nan")
    A = np.array([centres[n] for n, _ in names])
    B = np.array([np.loadtxt(str(f).replace("color.jpg", "pose.txt"))[:3, 3] for _, f in names])
    return similarity_rmse(A, B)


def _sfm_of(sets: list[str]) -> SfmConfig:
    """The stage's SfM settings with `--set sfm.KEY=VALUE` overrides (parsed as the config tree does)."""
    from tasks.config import load_config

    return load_config([], sets).sfm


def bench_sfm_and_scale(n: int, cfg: SfmConfig) -> dict[str, Any]:
    """SfM and the metric scale on the first n real frames: timings (wall and CPU), frames registered, ATE."""
    import cv2

    files = real_frames(n)
    images = [
        (f"{k:06d}.png", cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)) for k, f in enumerate(files)
    ]
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        sfm = run_sfm(images, KINECT, cfg, Path(tmp))
        sfm_s, sfm_cpu = time.perf_counter() - t0, time.process_time() - c0

    def depths():
        for k, f in enumerate(files):
            d = cv2.imread(str(f).replace("color.jpg", "depth.png"), cv2.IMREAD_UNCHANGED)
            yield f"{k:06d}.png", np.where(d == 65535, 0, d).astype(np.float32) / 1000.0

    calib = Calibration(KINECT, KINECT, RigidPose(np.eye(3), np.zeros(3)))
    t0, c0 = time.perf_counter(), time.process_time()
    report = estimate_scale(sfm, depths(), calib, ScaleConfig())
    scale_s, scale_cpu = time.perf_counter() - t0, time.process_time() - c0
    stages = ("extract_s", "extract_cpu_s", "match_s", "match_cpu_s", "map_s", "map_cpu_s")
    return {
        "frames": n,
        "registered": int(sfm.registered.sum()),
        "ate_cm": 100 * ate_m(sfm.camera_centres(), files),
        "sfm_s": sfm_s,
        "sfm_cpu_s": sfm_cpu,
        "sfm_s_per_frame": sfm_s / n,
        "sfm_cpu_s_per_frame": sfm_cpu / n,
        "sfm_stages_s": {k: sfm.metrics[k] for k in stages},
        "sift_first_octave": sfm.metrics.get("sift_first_octave"),
        "keyframes": sfm.metrics.get("keyframes"),
        "localized": sfm.metrics.get("localized"),
        "scale_s_per_frame": scale_s / n,
        "scale_cpu_s_per_frame": scale_cpu / n,
        "scale_frames_used": len(report.frames_used),
    }


def plain_pycolmap(n: int) -> dict[str, Any]:
    """The yardstick: pycolmap as its documentation runs it on the first n real frames (the JPEG files as
    they are): SIFT on the CPU with default options, one shared camera of COLMAP's default model, sequential
    matching with overlap 10, incremental mapping with multiple models; every thread."""
    import pycolmap

    pycolmap.logging.minloglevel = 2
    files = real_frames(n)
    with tempfile.TemporaryDirectory() as tmp:
        img_dir = Path(tmp) / "images"
        img_dir.mkdir()
        for k, f in enumerate(files):
            os.symlink(f, img_dir / f"{k:06d}.png")
        db, out = Path(tmp) / "database.db", Path(tmp) / "sparse"
        out.mkdir()
        t0, c0 = time.perf_counter(), time.process_time()
        pycolmap.extract_features(
            db, img_dir, camera_mode=pycolmap.CameraMode.SINGLE, device=pycolmap.Device.cpu
        )
        pycolmap.match_sequential(
            db, pairing_options=pycolmap.SequentialPairingOptions(overlap=10), device=pycolmap.Device.cpu
        )
        recs = pycolmap.incremental_mapping(db, img_dir, out)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    centres: dict[str, np.ndarray] = {}
    if recs:
        rec = max(recs.values(), key=lambda r: r.num_reg_images())
        for image in rec.images.values():
            if image.has_pose:
                centres[image.name] = np.asarray(image.projection_center())
    return {"seconds": wall, "cpu_s": cpu, "registered": len(centres), "ate_cm": 100 * ate_m(centres, files)}


def register_stage(n: int, sets: list[str]) -> dict[str, Any]:
    """The whole register stage on the first n real frames, as a run computes it: the frames are ingested
    first (not timed), then the register stage runs through load-or-compute (depth correction, SfM, scale,
    fusion, writing its artefacts)."""
    from flows import planning
    from tasks import config as cfgmod

    files = real_frames(n)
    with tempfile.TemporaryDirectory() as tmp:
        capture = Path(tmp) / "capture"
        capture.mkdir()
        shutil.copy(REALDATA / "camera-intrinsics.txt", capture)
        for f in files:
            for suffix in ("color.jpg", "depth.png", "pose.txt"):
                src = Path(str(f).replace("color.jpg", suffix))
                os.symlink(src, capture / src.name)
        cfg = cfgmod.load_config(
            [], ["ingest.intrinsics_px=[585, 585, 320, 240]", "ingest.tum_depth_units_per_m=1000", *sets]
        )
        profile = cfgmod.load_sensor_profile("kinect_v1")
        room = cfgmod.RoomSpec("room", capture)
        work = Path(tmp) / "work"
        planning.run_chain(work, cfg, profile, ["ingest"], room)
        t0, c0 = time.perf_counter(), time.process_time()
        results = planning.run_chain(work, cfg, profile, ["ingest", "register"], room)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        metrics = results["register"].manifest.get("metrics", {})
        digest = hashlib.sha256()
        for name in ("poses.parquet", "cloud.ply", "scale.json"):
            digest.update(results["register"].file(name).read_bytes())
    return {
        "seconds": wall,
        "cpu_s": cpu,
        "registered": metrics.get("sfm_registered"),
        "digest": digest.hexdigest()[:16],
    }


def write_walk(path: Path, n: int) -> dict:
    """A rendered 640x480 walk (n frames) around a textured box room as ingest's frames.parquet."""
    f = 520.0
    cam = CameraModel(np.array([[f, 0, 319.5], [0, f, 239.5], [0, 0, 1]]), np.zeros(5), (640, 480))

    # a 8.5 m x 6.5 m room, the camera tilted down enough to see the floor (the fallback levels by it)
    box = (np.array([-4.0, -3.0, 0.0]), np.array([4.5, 3.5, 2.8]))

    def frames():
        for k in range(n):
            a = 2 * np.pi * k / n
            position = np.array([0.25, 0.25, 1.4]) + 0.6 * np.array([np.cos(a), np.sin(a), 0])
            z, rgb = render(cam, look_pose(position, a + 0.4, -0.45), box)
            yield int(k * 1e8), z, rgb

    write_rendered_frames(path, list(frames()))
    # the foot track of the walk, so that frames SfM cannot chain in the synthetic texture still get placed
    # (by the fallback) and fused: the memory figure covers SfM on every frame plus fusing every frame
    a = 2 * np.pi * np.arange(n) / n
    track = np.column_stack([np.arange(n) * 1e8, 0.25 + 0.6 * np.cos(a), 0.25 + 0.6 * np.sin(a)])
    np.save(path.with_name("track.npy"), track)
    d = {"K": cam.K.tolist(), "dist": [0.0] * 5, "size": [640, 480], "source": "camera_info"}
    return {"depth": d, "rgb": dict(d)}


def child_register(frames_path: str, info_path: str, sets: list[str]) -> None:
    from tasks.register.config import RegisterConfig
    from tasks.register.room import register_room

    info = json.loads(Path(info_path).read_text())
    track = np.load(Path(frames_path).with_name("track.npy"))
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        res = register_room(
            Path(frames_path), info, None, RegisterConfig(), _sfm_of(sets), Path(tmp), track=track
        )
    out = {k: res.metrics[k] for k in ("frames", "sfm_registered", "cloud_points", "methods")}
    out["seconds"] = time.perf_counter() - t0
    out["cpu_s"] = time.process_time() - c0
    print(json.dumps(out))


def bench_register_memory(n: int, sets: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        frames = Path(tmp) / "frames.parquet"
        info = write_walk(frames, n)
        (Path(tmp) / "camera_info.json").write_text(json.dumps(info))
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "bench.sfm",
                "--child",
                str(frames),
                str(Path(tmp) / "camera_info.json"),
                json.dumps(sets),
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
        )
        if proc.returncode:
            raise SystemExit(f"register on {n} rendered frames failed:\n{proc.stderr[-2000:]}")
    peak_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024**2
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "peak_memory_gb": peak_gb}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        child_register(argv[1], argv[2], json.loads(argv[3]))
        return 0
    ap = argparse.ArgumentParser(prog="python -m bench.sfm", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--frames", type=int, default=100, help="real 640x480 frames for SfM, scale and yardstick (0 = skip)"
    )
    ap.add_argument(
        "--register-frames",
        type=int,
        default=300,
        help="rendered frames for the register time and memory (0 = skip)",
    )
    ap.add_argument("--no-yardstick", action="store_true", help="skip plain pycolmap and the register stage")
    ap.add_argument(
        "--set", dest="sets", action="append", default=[], metavar="sfm.KEY=VALUE", help="config override"
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the figures to this file")
    args = ap.parse_args(argv)
    cfg = _sfm_of(args.sets)
    figures: dict[str, Any] = {"load_before": os.getloadavg()[0]}
    print(f"{os.cpu_count()} cores, load average {figures['load_before']:.1f}", flush=True)
    if args.frames:
        r = bench_sfm_and_scale(args.frames, cfg)
        figures["sfm"] = r
        st = r["sfm_stages_s"]
        print(
            f"SfM   {r['sfm_s_per_frame']:.3f} s/frame wall, {r['sfm_cpu_s_per_frame']:.3f} s/frame CPU at 640x480 "
            f"({r['registered']}/{r['frames']} registered, ATE {r['ate_cm']:.2f} cm; extract "
            f"{st['extract_s']:.1f} s / {st['extract_cpu_s']:.1f} s CPU, match {st['match_s']:.1f} / "
            f"{st['match_cpu_s']:.1f}, map {st['map_s']:.1f} / {st['map_cpu_s']:.1f}; SIFT first octave "
            f"{r['sift_first_octave']}; {r['keyframes']} key frames mapped, {r['localized']} localized)",
            flush=True,
        )
        print(
            f"scale {r['scale_s_per_frame']:.3f} s/frame wall, {r['scale_cpu_s_per_frame']:.3f} s/frame CPU "
            f"({r['scale_frames_used']} frames used)",
            flush=True,
        )
        if not args.no_yardstick:
            plain = plain_pycolmap(args.frames)
            stage = register_stage(args.frames, args.sets)
            figures["yardstick"] = {"plain_pycolmap": plain, "register_stage": stage}
            figures["yardstick"]["ratio"] = stage["seconds"] / plain["seconds"]
            figures["yardstick"]["cpu_ratio"] = stage["cpu_s"] / plain["cpu_s"]
            print(
                f"yardstick, {args.frames} frames: plain pycolmap {plain['seconds']:.1f} s ({plain['cpu_s']:.1f} s CPU; "
                f"{plain['registered']} registered, ATE {plain['ate_cm']:.2f} cm), whole register stage "
                f"{stage['seconds']:.1f} s ({stage['cpu_s']:.1f} s CPU; {stage['registered']} registered by SfM; artefacts "
                f"{stage['digest']}): "
                f"ratio {figures['yardstick']['ratio']:.2f}x wall, {figures['yardstick']['cpu_ratio']:.2f}x CPU "
                f"(target <= 0.6x)",
                flush=True,
            )
    if args.register_frames:
        m = bench_register_memory(args.register_frames, args.sets)
        figures["register"] = m
        print(
            f"register {m['frames']} rendered frames: {m['seconds']:.0f} s ({m['cpu_s']:.0f} s CPU), peak memory "
            f"{m['peak_memory_gb']:.2f} GB, {m['sfm_registered']} registered by SfM, placed {m['methods']}, "
            f"{m['cloud_points']} cloud points",
            flush=True,
        )
    figures["load_after"] = os.getloadavg()[0]
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
