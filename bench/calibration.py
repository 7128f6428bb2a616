"""Calibrate-stage benchmark: target detection, the joint stereo adjustment, and depth → points → colour per
frame, on the real data in ../shared/realdata.

    python -m bench.calibration [--repeat 5]

Prints CPU and wall seconds; the per-frame figures are what the register stage pays for every frame.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from tasks.calibrate.config import CalibrateConfig
from tasks.calibrate.files import calibrate_images, read_gray
from tasks.calibrate.targets import detect_targets
from tasks.camera import colour_points, depth_to_points, profile_calibration

REPO = Path(__file__).resolve().parents[1]
REALDATA = REPO.parent / "shared" / "realdata"


def timed(fn, repeat: int = 1):
    """(result of the last call, CPU s per call, wall s per call)."""
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return out, (time.process_time() - c0) / repeat, (time.perf_counter() - w0) / repeat


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="repetitions of the per-frame timings")
    args = ap.parse_args()

    stereo = REALDATA / "calib_stereo_opencv"
    left = [(p.name, read_gray(p)) for p in sorted(stereo.glob("left*.jpg"))]
    right = [(p.name, read_gray(p)) for p in sorted(stereo.glob("right*.jpg"))]
    _, cpu, wall = timed(lambda: detect_targets(left, "chessboard:9x6:0.025"))
    print(
        f"detect 9x6 chessboard, 640x480:   {cpu / len(left) * 1000:7.1f} ms CPU per image ({wall / len(left) * 1000:.1f} wall)"
    )
    for solver in ("bundle", "opencv"):
        calib, cpu, wall = timed(
            lambda s=solver: calibrate_images(left, right, CalibrateConfig(stereo_solver=s))
        )
        print(
            f"calibrate 13 stereo pairs ({solver:6s}): {cpu:7.2f} s CPU ({wall:.2f} wall); left fx {calib.ir.fx:.2f}, "
            f"RMS {calib.ir.rms_px:.3f}/{calib.rgb.rms_px:.3f}/{calib.stereo_rms_px:.3f} px, baseline {calib.baseline_mm:.1f} mm"
        )

    frames = REALDATA / "rgbd_single_frames"
    colour = cv2.cvtColor(cv2.imread(str(frames / "TUM_color.png")), cv2.COLOR_BGR2RGB)
    depth = cv2.imread(str(frames / "TUM_depth.png"), cv2.IMREAD_UNCHANGED)
    cam = {
        "fx": 517.3,
        "fy": 516.5,
        "cx": 318.6,
        "cy": 255.3,
        "size": [640, 480],
        "dist": [0.2624, -0.9531, -0.0054, 0.0026, 1.1633],
    }
    registered = profile_calibration({"name": "tum_fr1", "registered": True, "ir": cam, "rgb": cam})
    depth_to_points(
        depth, "tum5000", registered.ir
    )  # warm the ray cache, as a stage does after its first frame
    (pts, _), cpu, wall = timed(lambda: depth_to_points(depth, "tum5000", registered.ir), args.repeat)
    print(
        f"depth → points, 640x480 TUM:      {cpu * 1000:7.1f} ms CPU per frame ({wall * 1000:.1f} wall), {len(pts)} points"
    )
    (_, valid), cpu, wall = timed(lambda: colour_points(pts, colour, registered), args.repeat)
    print(
        f"colour points (registered):       {cpu * 1000:7.1f} ms CPU per frame ({wall * 1000:.1f} wall), {valid.mean() * 100:.1f} % coloured"
    )

    # a Kinect v1 with its IR→RGB offset (the sensor profile): points move 24 mm and are z-buffered in RGB
    import yaml

    kinect = profile_calibration(
        yaml.safe_load((REPO / "configs" / "sensors" / "kinect_v1.yaml").read_text())
    )
    raw = kinect.depth_model.raw_from_depth(depth.astype(np.float64) / 5000.0)
    (pts, _), cpu, wall = timed(
        lambda: depth_to_points(raw, "disparity", kinect.ir, kinect.depth_model), args.repeat
    )
    print(
        f"raw disparity → points:           {cpu * 1000:7.1f} ms CPU per frame ({wall * 1000:.1f} wall), {len(pts)} points"
    )
    (_, valid), cpu, wall = timed(lambda: colour_points(pts, colour, kinect), args.repeat)
    print(
        f"colour points (IR→RGB, Kinect v1): {cpu * 1000:6.1f} ms CPU per frame ({wall * 1000:.1f} wall), {valid.mean() * 100:.1f} % coloured"
    )


if __name__ == "__main__":
    main()
