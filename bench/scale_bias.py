"""Scale bias on known poses: the metric scale step (eq 3.16) on the survey generator's rooms without SfM.

    python -m bench.scale_bias                       # seed 0, rooms r1 r2
    python -m bench.scale_bias --seeds 0 5 --rooms r1 r3 hall

Run from the repository root. For each room the capture's walk (`tasks.synth.survey`'s own random
streams, so seed 0 walks as data/mini does) gives the TRUE depth-camera poses; a canned SfM is made from
them: `--features` random colour pixels per frame, ray cast into the building for their 3D points, in an
SfM frame of K SfM units per metre, observed at their exact pixels. The depth is rendered through the
synthetic Kinect v1 chain one error at a time:

- true: the exact z (float), no device;
- quant: 1/8 px disparity and 1 mm steps only;
- noise: plus the Gaussian disparity noise (eq 6.2);
- radial: quantization and the radial disparity pattern (thesis 6.1.2) without the noise;
- full: everything, what the generator's captures hold.

`estimate_scale` runs on each with the radial error estimated on the frames and taken out (as the register
stage does) and without (radial_k = 0). Printed: the scale error (estimate · K − 1) in percent per room and
variant, and the mean over the rooms. The truth is exact, so what remains is the estimator's bias (and
the few hundred points' noise: about ±0.02 %).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from tasks.camera import Calibration, profile_calibration
from tasks.config import load_sensor_profile
from tasks.register.config import RegisterConfig, ScaleConfig
from tasks.register.fusion import estimate_radial_depth_error
from tasks.register.scale import estimate_scale
from tasks.register.sfm import SfmResult
from tasks.synth import sensor
from tasks.synth.building import generate_building
from tasks.synth.survey import SurveyConfig, _n_frames, _room_index, _walk

K_SFM = 0.45
"""SfM units per metre of the canned reconstruction (the true scale is 1 / K_SFM)."""

VARIANTS = ("true", "quant", "noise", "radial", "full")


def known_pose_room(
    seed: int, room_id: str, features: int, size: str = "mini"
) -> tuple[dict, SfmResult, list[tuple[str, NDArray[np.float64]]], Calibration]:
    """(sensor profile, canned SfM, (frame name, true IR z-depth) per frame, true calibration) of a room."""
    profile = load_sensor_profile("kinect_v1")
    building = generate_building(seed)
    room = next(r for r in building.rooms if r.id == room_id)
    cfg = SurveyConfig()
    poses, _ = _walk(room, _n_frames(room, size, cfg), seed, _room_index(building, room_id), cfg)
    ir = sensor.camera_model(profile, "ir", size)
    rgb = sensor.camera_model(profile, "rgb", size)
    rng = np.random.default_rng(seed + 1)
    names, world, obs, cam_from_world, truth = [], [], {}, {}, []
    count = 0
    for k, pose in enumerate(poses):
        name = f"{k:06d}.png"
        pose_rgb = sensor.rgb_pose(pose, profile)
        z_rgb = sensor.render_depth_z(building.mesh, pose_rgb, rgb).ravel()
        ok = np.flatnonzero(np.isfinite(z_rgb) & (z_rgb > 0.5) & (z_rgb < 6.0))
        pick = rng.choice(ok, min(features, len(ok)), replace=False)
        cam_pts = sensor.pixel_rays(rgb)[pick] * z_rgb[pick, None]
        world.append(cam_pts @ pose_rgb[:3, :3].T + pose_rgb[:3, 3])
        uv = np.column_stack([pick % rgb.width, pick // rgb.width]).astype(np.float64)
        obs[name] = (np.arange(count, count + len(pick)), uv)
        count += len(pick)
        inv = np.linalg.inv(pose_rgb)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = inv[:3, :3], K_SFM * inv[:3, 3]
        cam_from_world[name] = T
        names.append(name)
        truth.append((name, sensor.render_depth_z(building.mesh, pose, ir)))
    full = profile_calibration(profile)
    calib = replace(
        full, ir=full.ir.scaled((ir.width, ir.height)), rgb=full.rgb.scaled((rgb.width, rgb.height))
    )
    pts = K_SFM * np.concatenate(world)
    sfm = SfmResult(
        names,
        np.ones(len(names), bool),
        cam_from_world,
        {n: 0.0 for n in names},
        pts,
        np.arange(len(pts), dtype=np.int64),
        obs,
        calib.rgb,
    )
    return profile, sfm, truth, calib


def sensor_depth(profile: dict, z: NDArray[np.float64], variant: str, rng: np.random.Generator) -> NDArray:
    """Depth in metres (NaN = none) of true z-depths through the chosen part of the Kinect v1 chain."""
    if variant == "true":
        return z
    depth = profile["depth"]
    weight = sensor._radial_weight(sensor.camera_model(profile, "ir", "mini"))
    noisy = rng if variant in ("noise", "full") else None
    radial_px = sensor.SensorConfig().radial_error_px if variant in ("radial", "full") else 0.0
    d_k = sensor.kinect_raw_disparity(z.ravel(), depth, noisy, weight, radial_px)
    zq = sensor.depth_from_raw_disparity(d_k, depth)
    return (np.where(np.isfinite(zq), np.rint(zq * 1000.0), np.nan) / 1000.0).reshape(z.shape)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--rooms", nargs="+", default=["r1", "r2"])
    ap.add_argument("--features", type=int, default=400, help="SfM points per frame")
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        for room in args.rooms:
            profile, sfm, truth, calib = known_pose_room(seed, room, args.features)
            row: dict = {"seed": seed, "room": room}
            for variant in VARIANTS:
                rng = np.random.default_rng(7)
                frames = [(n, sensor_depth(profile, z, variant, rng)) for n, z in truth]
                radial = estimate_radial_depth_error(
                    ((i, d, None) for i, (_n, d) in enumerate(frames)), calib, RegisterConfig()
                )
                for label, k in (("", radial.k_inv_m), ("/no radial", 0.0)):
                    report = estimate_scale(sfm, iter(frames), calib, ScaleConfig(), k)
                    row[variant + label] = round(100.0 * (report.scale * K_SFM - 1.0), 3)
                row[f"{variant}/radial k"] = round(radial.k_inv_m, 5)
            rows.append(row)
            print(json.dumps(row), flush=True)
    keys = [k for k in rows[0] if k not in ("seed", "room") and not k.endswith("radial k")]
    print("mean scale error (%) over rooms:")
    for k in keys:
        print(f"  {k:20s} {np.mean([r[k] for r in rows]):+.3f}")
    bc = float(load_sensor_profile("kinect_v1")["depth"]["disparity_bc_m_px"])
    print(f"  (the sensor's radial k = {sensor.SensorConfig().radial_error_px / bc:.5f} 1/m at the corners)")


if __name__ == "__main__":
    main()
