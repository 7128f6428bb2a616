"""Register benchmark: seconds per frame of SfM and of the metric scale at 640x480 on 2 cores, and the peak
memory of the whole register stage for a long capture.

    python -m bench.sfm [--frames 30] [--register-frames 300] [--threads 2]

SfM and scale run on real Kinect v1 frames (7-Scenes redkitchen, ../shared/realdata). The memory figure
comes from a child process running `register_room` (ingest's frames.parquet in, room cloud out) on a
rendered 640x480 walk through a textured box room with `--register-frames` frames (target: <= 3 GB for 300).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tasks.camera import Calibration, CameraModel, RigidPose
from tasks.register.config import ScaleConfig, SfmConfig
from tasks.register.scale import estimate_scale
from tasks.register.sfm import run_sfm
from tasks.synth.box_views import look_pose, render, write_rendered_frames

REPO = Path(__file__).resolve().parents[1]
REALDATA = REPO.parent / "shared" / "realdata" / "rgbd_7scenes_redkitchen"


def bench_sfm_and_scale(n: int, threads: int) -> dict:
    import cv2

    files = sorted(REALDATA.glob("frame-*.color.jpg"))[:n]
    if len(files) < n:
        raise SystemExit(f"{REALDATA}: only {len(files)} colour frames")
    images = [
        (f"{k:06d}.png", cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)) for k, f in enumerate(files)
    ]
    cam = CameraModel(np.array([[585.0, 0, 320], [0, 585, 240], [0, 0, 1]]), np.zeros(5), (640, 480))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        sfm = run_sfm(images, cam, SfmConfig(num_threads=threads), Path(tmp))
        sfm_s = time.perf_counter() - t0

    def depths():
        for k, f in enumerate(files):
            d = cv2.imread(str(f).replace("color.jpg", "depth.png"), cv2.IMREAD_UNCHANGED)
            yield f"{k:06d}.png", np.where(d == 65535, 0, d).astype(np.float32) / 1000.0

    calib = Calibration(cam, cam, RigidPose(np.eye(3), np.zeros(3)))
    t0 = time.perf_counter()
    report = estimate_scale(sfm, depths(), calib, ScaleConfig())
    scale_s = time.perf_counter() - t0
    return {
        "frames": n,
        "registered": int(sfm.registered.sum()),
        "sfm_s_per_frame": sfm_s / n,
        "sfm_stages_s": {k: sfm.metrics[k] for k in ("extract_s", "match_s", "map_s")},
        "scale_s_per_frame": scale_s / n,
        "scale_frames_used": len(report.frames_used),
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


def child_register(frames_path: str, info_path: str, threads: int) -> None:
    from tasks.register.config import RegisterConfig
    from tasks.register.room import register_room

    info = json.loads(Path(info_path).read_text())
    track = np.load(Path(frames_path).with_name("track.npy"))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = register_room(
            Path(frames_path),
            info,
            None,
            RegisterConfig(),
            SfmConfig(num_threads=threads),
            Path(tmp),
            track=track,
        )
    out = {k: res.metrics[k] for k in ("frames", "sfm_registered", "cloud_points", "methods")}
    out["seconds"] = time.perf_counter() - t0
    print(json.dumps(out))


def bench_register_memory(n: int, threads: int) -> dict:
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
                str(threads),
            ],
            cwd=REPO,
            capture_output=True,
            text=True,
        )
        if proc.returncode:
            raise SystemExit(f"register on {n} rendered frames failed:\n{proc.stderr[-2000:]}")
    peak_gb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024**2
    return {**json.loads(proc.stdout.strip().splitlines()[-1]), "peak_memory_gb": peak_gb}


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child_register(sys.argv[2], sys.argv[3], int(sys.argv[4]))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--frames", type=int, default=30, help="real 640x480 frames for the SfM and scale timings"
    )
    ap.add_argument(
        "--register-frames", type=int, default=300, help="rendered frames for the memory figure (0 = skip)"
    )
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    r = bench_sfm_and_scale(args.frames, args.threads)
    print(
        f"SfM   {r['sfm_s_per_frame']:.2f} s/frame at 640x480 on {args.threads} threads "
        f"({r['registered']}/{r['frames']} registered; {r['sfm_stages_s']})"
    )
    print(f"scale {r['scale_s_per_frame']:.3f} s/frame ({r['scale_frames_used']} frames used)")
    if args.register_frames:
        m = bench_register_memory(args.register_frames, args.threads)
        print(
            f"register {m['frames']} frames: peak memory {m['peak_memory_gb']:.2f} GB (target <= 3 GB), "
            f"{m['seconds']:.0f} s, {m['sfm_registered']} registered by SfM, placed {m['methods']}, "
            f"{m['cloud_points']} cloud points"
        )


if __name__ == "__main__":
    main()
