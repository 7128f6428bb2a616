"""One room registered (thesis 3.2): SfM → metric scale → fused cloud, the SfM made again with another seed
while the map fails a check from the data (its per-frame scales drift along the capture, or a frame's
depth disagrees with its neighbours': `tasks.register.check`; a map broken in two between neighbour frames
is reported), or the track-based fallback when SfM places too few frames (consistently).

Frames: SfM placements are in a room frame anchored at the first registered depth camera (x right, y
forward, z up); track placements are in the track's (plan) frame with z up from the floor.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from tasks.camera import Calibration, CameraModel, RigidPose, profile_calibration
from tasks.cloud import DegenerateInputError
from tasks.register.check import DepthConsistency, neighbour_depth_consistency
from tasks.register.config import RegisterConfig, ScaleConfig, SfmConfig
from tasks.register.fusion import (
    FrameData,
    FusedCloud,
    RadialDepthError,
    estimate_radial_depth_error,
    fuse_capture,
)
from tasks.register.scale import ScaleReport, apply_scale, estimate_scale
from tasks.register.sfm import SfmResult, run_sfm
from tasks.register.track_fallback import place_by_track

METHODS = ("sfm", "track", "none")
"""How a frame was placed."""


# ------------------------------------------------------------------------------------ calibration


def calibration_from_camera_info(
    camera_info: dict[str, Any], profile: dict[str, Any] | None = None
) -> Calibration:
    """A Calibration from ingest's camera_info.json: the depth stream as the IR camera, the colour stream as
    the RGB camera. The IR→RGB pose is camera_info's `ir_to_rgb` when given; else the sensor profile's
    when the intrinsics came from a sensor (camera_info messages or the profile); else identity (e.g.
    7-Scenes, whose folder gives one intrinsics file for both streams and no extrinsics)."""
    if "depth" not in camera_info:
        raise DegenerateInputError("camera_info has no depth camera intrinsics")

    def cam(d: dict[str, Any]) -> CameraModel:
        return CameraModel(
            np.array(d["K"], dtype=np.float64), np.array(d.get("dist", [0.0] * 5)), tuple(d["size"])
        )

    ir = cam(camera_info["depth"])
    rgb = cam(camera_info["rgb"]) if "rgb" in camera_info else None
    pose = None
    if rgb is not None:
        given = camera_info.get("ir_to_rgb")
        if given is not None:
            pose = RigidPose(np.array(given["R"]), np.array(given["t_m"]))
        elif profile is not None and {
            camera_info["rgb"].get("source"),
            camera_info["depth"].get("source"),
        } <= {
            "profile",
            "camera_info",
        }:
            try:
                pose = profile_calibration(profile).ir_to_rgb
            except ValueError:
                pose = None
        if pose is None:
            pose = RigidPose(np.eye(3), np.zeros(3))
    return Calibration(ir, rgb, pose, source="profile")


# ------------------------------------------------------------------------------------ the stage


@dataclass
class RegisterResult:
    """A registered room."""

    poses: dict[str, NDArray]
    """poses.parquet columns: frame_id, t_ns, qw qx qy qz tx ty tz (depth camera → room, metres; NaN when
    unplaced), method (sfm / track / none)."""
    cloud: FusedCloud
    scale: dict[str, Any]
    """scale.json: scale (metres per SfM unit; 1.0 for track placements), spread, frames used."""
    metrics: dict[str, Any] = field(default_factory=dict)
    frame: str = "room"
    """"room" (anchored at the first SfM frame) or "plan" (the track's frame)."""


def _decode_depth(row: dict[str, Any], units_override: float | None) -> NDArray[np.float32]:
    import cv2

    if row["depth_kind"] == "disparity":
        raise DegenerateInputError("raw disparity frames need the calibration's disparity model")
    raw = cv2.imdecode(np.frombuffer(row["depth"], np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DegenerateInputError(f"frame {row.get('frame_id')}: depth is not a readable PNG")
    units = float(units_override or row["depth_units_per_m"])
    depth = raw.astype(np.float32) / np.float32(units)
    if row["depth_kind"] == "mm":
        depth[raw >= 65535] = 0
    return depth


def _pose_columns(
    frame_ids: list[int], t_ns: list[int], poses: dict[int, NDArray[np.float64]], methods: dict[int, str]
) -> dict[str, NDArray]:
    n = len(frame_ids)
    q = np.full((n, 4), np.nan)
    t = np.full((n, 3), np.nan)
    for k, fid in enumerate(frame_ids):
        T = poses.get(fid)
        if T is None:
            continue
        xyzw = Rotation.from_matrix(T[:3, :3]).as_quat()
        if xyzw[3] < 0:
            xyzw = -xyzw
        q[k] = [xyzw[3], xyzw[0], xyzw[1], xyzw[2]]
        t[k] = T[:3, 3]
    return {
        "frame_id": np.asarray(frame_ids, dtype=np.int32),
        "t_ns": np.asarray(t_ns, dtype=np.int64),
        "qw": q[:, 0],
        "qx": q[:, 1],
        "qy": q[:, 2],
        "qz": q[:, 3],
        "tx": t[:, 0],
        "ty": t[:, 1],
        "tz": t[:, 2],
        "method": np.array([methods.get(f, "none") for f in frame_ids], dtype=object),
    }


def register_room(
    frames_path: Path,
    camera_info: dict[str, Any],
    calibration: Calibration | None,
    cfg: RegisterConfig,
    sfm_cfg: SfmConfig,
    workdir: Path,
    track: NDArray[np.float64] | None = None,
    plan_walls: NDArray[np.float64] | None = None,
    progress: Callable[[str], None] | None = None,
    scale_cfg: ScaleConfig | None = None,
    profile: dict[str, Any] | None = None,
    depth_units_per_m: float | None = None,
) -> RegisterResult:
    """The register stage on one room: sfm → scale → fuse, or the track-based fallback when SfM registers
    under `cfg.fallback_min_registered_fraction` of the frames (or fails outright) and a track is given.

    frames_path: ingest's frames.parquet (read row group by row group); camera_info: its camera_info.json;
    calibration: the survey's (None: from camera_info, with the sensor `profile`'s IR→RGB pose);
    workdir: scratch folder for pycolmap; track: (K, 3) t_ns x y foot-mounted IMU positions (plan frame);
    plan_walls: (M, 4) or (M, 5 with thickness) coarse plan walls for the fallback's heading correction.
    Raises DegenerateInputError (one line) when neither SfM nor the fallback can place the frames."""
    from tasks.ingest.frames import iter_frames

    started = time.perf_counter()
    say = progress or (lambda _msg: None)
    scale_cfg = scale_cfg or ScaleConfig()
    calib = calibration or calibration_from_camera_info(camera_info, profile)
    frames_path = Path(frames_path)
    meta = list(iter_frames(frames_path, ["frame_id", "t_ns", "rgb_format"]))
    frame_ids = [int(r["frame_id"]) for r in meta]
    t_of = {int(r["frame_id"]): int(r["t_ns"]) for r in meta}
    if not frame_ids:
        raise DegenerateInputError(f"{frames_path.name}: no frames")

    def depth_frames() -> Iterator[tuple[str, NDArray[np.float32]]]:
        return (
            (_frame_name(int(r["frame_id"])), _decode_depth(r, depth_units_per_m))
            for r in _depth_rows(frames_path)
        )

    metrics: dict[str, Any] = {"frames": len(frame_ids)}
    # the depth camera's radial error, estimated once on the capture's depth alone: the scale and the
    # fused cloud both take it out (left in the depth, it made every metric scale short)
    radial = _radial_error(frames_path, frame_ids, calib, cfg, depth_units_per_m)
    images = _colour_images(frames_path)
    say(f"sfm on {len(images)} colour frames")
    radial_k = 0.0 if radial is None else radial.k_inv_m
    sfm, report, sfm_error, tried, dropped = _sfm_with_retry(
        images, len(frame_ids), depth_frames, calib, cfg, sfm_cfg, scale_cfg, workdir, metrics, say, radial_k
    )
    del images
    registered = 0 if sfm is None else int(sfm.registered.sum())
    fraction = registered / len(frame_ids)
    metrics.update(sfm_registered=registered, sfm_registered_fraction=round(fraction, 4), sfm_attempts=tried)
    if sfm is not None:
        metrics["sfm"] = sfm.metrics
    frame = "room"
    if report is not None and sfm is not None:
        poses, methods, scale_json = _sfm_placement(sfm, report, calib, frame_ids, dropped)
    elif track is not None:
        why = sfm_error or f"SfM registered {registered} of {len(frame_ids)} frames"
        say(f"track-based fallback ({why})")
        if "map_check" in metrics:
            metrics["map_check"]["used"] = "IMU track fallback"
        poses, methods, scale_json = _track_placement(
            frames_path, track, calib, cfg, plan_walls, why, depth_units_per_m, metrics, radial_k
        )
        frame = "plan"
    else:
        why = sfm_error or (
            f"SfM registered {registered} of {len(frame_ids)} frames "
            f"(< {cfg.fallback_min_registered_fraction:.0%})"
        )
        raise DegenerateInputError(
            f"cannot register the room: {why} and no IMU track was given for the fallback"
        )

    say(f"fusing {len(poses)} placed frames")
    t0 = time.perf_counter()
    cloud, radial = _fuse_placed(frames_path, poses, calib, cfg, depth_units_per_m, radial)
    metrics["fuse_s"] = round(time.perf_counter() - t0, 3)
    if radial is not None:
        metrics["radial_depth_error"] = asdict(radial)
    metrics.update(
        placed=len(poses),
        methods={m: sum(1 for f in frame_ids if methods.get(f, "none") == m) for m in METHODS},
        cloud_points=len(cloud),
        coloured_fraction=round(
            float(cloud.coloured.mean()) if cloud.coloured is not None and len(cloud) else 0.0, 4
        ),
        seconds=round(time.perf_counter() - started, 3),
    )
    columns = _pose_columns(frame_ids, [t_of[f] for f in frame_ids], poses, methods)
    return RegisterResult(columns, cloud, scale_json, metrics, frame)


def _frame_name(fid: int) -> str:
    """The frame's image name in SfM (and in scale.json's frame names)."""
    return f"{fid:06d}.png"


def _depth_rows(frames_path: Path) -> Iterator[dict[str, Any]]:
    """frames.parquet's rows with the depth image, streamed row group by row group."""
    from tasks.ingest.frames import iter_frames

    yield from iter_frames(frames_path, ["frame_id", "t_ns", "depth", "depth_kind", "depth_units_per_m"])


class EncodedImage:
    """A colour frame kept as its encoded bytes (PNG or JPEG) and decoded where it is read as an array
    (`np.asarray`): the frames SfM is given stay a few tens of kB each in memory instead of 0.9 MB, and
    only the one being read is ever decoded."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def decode(self) -> NDArray[np.uint8] | None:
        """(H, W, 3) RGB, or None when the bytes are not a readable image."""
        import cv2

        img = cv2.imdecode(np.frombuffer(self.data, np.uint8), cv2.IMREAD_COLOR)
        return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def __array__(self, dtype: Any = None, copy: Any = None) -> NDArray[np.uint8]:
        img = self.decode()
        if img is None:
            raise DegenerateInputError("a colour frame is not a readable image")
        return img if dtype is None else img.astype(dtype)


def _colour_images(frames_path: Path) -> list[tuple[str, EncodedImage]]:
    """(name, the encoded RGB image) of every frame that has a readable colour image, in frame order;
    each is decoded once here to check it, and dropped."""
    from tasks.ingest.frames import iter_frames

    images = []
    for row in iter_frames(frames_path, ["frame_id", "rgb"]):
        if row["rgb"]:
            image = EncodedImage(row["rgb"])
            if image.decode() is not None:
                images.append((_frame_name(int(row["frame_id"])), image))
    return images


def _sfm_with_retry(
    images: list[tuple[str, EncodedImage]],
    frame_count: int,
    depth_frames: Callable[[], Iterator[tuple[str, NDArray[np.float32]]]],
    calib: Calibration,
    cfg: RegisterConfig,
    sfm_cfg: SfmConfig,
    scale_cfg: ScaleConfig,
    workdir: Path,
    metrics: dict[str, Any],
    say: Callable[[str], None],
    radial_k: float = 0.0,
) -> tuple[SfmResult | None, ScaleReport | None, str, list[dict[str, Any]], set[str]]:
    """SfM and its metric scale, made again with the next seed (up to `cfg.sfm_attempts` runs) while the
    map fails a check: its per-frame scales drift along the capture, or a frame's depth disagrees with
    its neighbours' (`map_check`; where the map breaks between two neighbour frames is reported). The
    run placing most frames consistently, then the straightest, is kept. Returns
    (the kept reconstruction or the last one registering too few frames, its scale report (None: not
    usable), why SfM failed ("" when it did not), one record per scaled attempt, the kept
    run's inconsistent frames, left unplaced). Adds the scale and check timings and `map_check` (the
    verdict on the kept run) to `metrics`. radial_k: the depth camera's radial error taken out of the
    depth (`estimate_scale`)."""
    sfm: SfmResult | None = None
    sfm_error = ""
    report = None
    tried: list[dict[str, Any]] = []
    dropped: set[str] = set()
    kept_check: DepthConsistency | None = None
    kept_seed = sfm_cfg.random_seed
    for attempt in range(max(cfg.sfm_attempts, 1)):
        # RANSAC in the mapper now and then bends a reconstruction (seen on a synthetic room: 8 cm ATE
        # with one seed, 0.3 cm with the next two); the bend shows as per-frame scales that drift along
        # the capture, so a reconstruction whose scales drift is made again with another seed and the
        # straightest one is kept
        seeded = replace(sfm_cfg, random_seed=sfm_cfg.random_seed + attempt)
        try:
            if len(images) < sfm_cfg.min_frames:
                raise DegenerateInputError(
                    f"SfM needs at least {sfm_cfg.min_frames} colour frames, got {len(images)}"
                )
            attempt_dir = Path(workdir) / f"attempt-{attempt}"
            attempt_dir.mkdir(parents=True, exist_ok=True)
            candidate = run_sfm(images, calib.rgb, seeded, attempt_dir)
        except DegenerateInputError as exc:
            sfm_error = str(exc)
            break
        n_reg = int(candidate.registered.sum())
        if n_reg / frame_count < cfg.fallback_min_registered_fraction:
            if sfm is None:
                sfm = candidate
            break
        say(f"scale from depth ({n_reg} registered frames)")
        t0 = time.perf_counter()
        try:
            candidate_report = estimate_scale(
                candidate,
                depth_frames(),
                calib,
                scale_cfg,
                radial_k,
            )
        except DegenerateInputError as exc:
            sfm_error = f"no metric scale for the SfM poses ({exc})"
            if sfm is None:
                sfm = candidate
            break
        metrics["scale_s"] = round(metrics.get("scale_s", 0.0) + time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        check = map_check(candidate, candidate_report, depth_frames, calib, cfg, scale_cfg)
        metrics["check_s"] = round(metrics.get("check_s", 0.0) + time.perf_counter() - t0, 3)
        consistent = n_reg - len(check.inconsistent)
        straight = abs(candidate_report.relative_trend) <= cfg.sfm_max_scale_trend
        tried.append(
            {
                "seed": seeded.random_seed,
                "registered": n_reg,
                "relative_spread": candidate_report.relative_spread,
                "relative_trend": round(candidate_report.relative_trend, 5),
                **check.to_json(),
            }
        )
        better = report is None or (consistent, -abs(candidate_report.relative_trend)) > (
            int(sfm.registered.sum()) - len(dropped),
            -abs(report.relative_trend),
        )
        if better:
            sfm, report, sfm_error = candidate, candidate_report, ""
            dropped, kept_check, kept_seed = set(check.inconsistent), check, seeded.random_seed
        # a map broken in two is reported, not made again: on survey 731 r4 all three seeds broke it
        # between the same two frames, and on 824 r2 the next seed's pair passed at 0.754 with the same
        # trajectory error (1.4 cm) and scale (-0.12 %)
        if straight and not check.inconsistent:
            break
    if report is not None and sfm is not None and kept_check is not None:
        kept = int(sfm.registered.sum()) - len(dropped)
        verdict = "consistent"
        if dropped:
            verdict = "inconsistent frames left unplaced"
        if abs(report.relative_trend) > cfg.sfm_max_scale_trend:
            verdict = "scales drift (bent map) in every attempt; the straightest kept"
        if kept_check.broken_links:
            verdict = "the map breaks between two frames (see broken_links); kept"
        failed = [_attempt_failure(a, cfg) for a in tried]
        why = "; ".join(f"seed {a['seed']}: {f}" for a, f in zip(tried, failed, strict=True) if f)
        metrics["map_check"] = {
            "verdict": verdict,
            "used": f"sfm seed {kept_seed}" + (f" without {len(dropped)} frames" if dropped else ""),
            "why": why or "the first map passed the checks",
            "seed": kept_seed,
            "attempts": len(tried),
            "unplaced_frames": sorted(dropped),
            "relative_trend": round(report.relative_trend, 5),
            **{k: v for k, v in kept_check.to_json().items() if k != "inconsistent_frames"},
        }
        if kept / frame_count < cfg.fallback_min_registered_fraction:
            sfm_error = (
                f"SfM placed {kept} of {frame_count} frames consistently with their depth "
                f"({len(dropped)} inconsistent)"
            )
            report = None
    return sfm, report, sfm_error, tried, dropped


def _attempt_failure(attempt: dict[str, Any], cfg: RegisterConfig) -> str:
    """What an SfM attempt's record says is wrong with its map ("" when nothing)."""
    out = []
    if abs(attempt["relative_trend"]) > cfg.sfm_max_scale_trend:
        out.append(f"per-frame scales drift {attempt['relative_trend']:+.1%} along the capture")
    for link in attempt.get("broken_links", []):
        out.append(f"the map breaks between {link.replace('-', ' and ')} (their depth disagrees)")
    if attempt["inconsistent_frames"]:
        out.append(
            f"{', '.join(attempt['inconsistent_frames'])} disagree with their neighbours' depth "
            f"(lowest pair agreement {attempt['min_pair_agreement']})"
        )
    return " and ".join(out)


def map_check(
    sfm: SfmResult,
    report: ScaleReport,
    depth_frames: Callable[[], Iterator[tuple[str, NDArray[np.float32]]]],
    calib: Calibration,
    cfg: RegisterConfig,
    scale_cfg: ScaleConfig,
) -> DepthConsistency:
    """The neighbour depth check (`tasks.register.check`) of an SfM map made metric by its scale: the
    frames whose depth disagrees with their neighbours' are checked once more without them (their
    neighbours then meet), and the frames found on either pass are inconsistent. The figures are the
    first pass's."""
    metric = apply_scale(sfm, report.scale, calib)
    names = [n for n in sfm.names if n in metric]
    left_out: list[str] = []
    first = check = None
    for _ in range(2):
        poses = {n: metric[n] for n in names if n not in left_out}
        check = neighbour_depth_consistency(
            depth_frames(),
            poses,
            calib.ir,
            scale_cfg.inlier_threshold_m,
            scale_cfg.inlier_threshold_rel,
            cfg.map_min_agreement,
            cfg.map_min_pair_points,
            min_depth_m=cfg.min_depth_m,
            max_depth_m=cfg.max_depth_m,
        )
        first = first or check
        if not check.inconsistent:
            break
        left_out += check.inconsistent
    assert first is not None and check is not None
    # the figures of the first pass (the evidence), the frames of both; the links broken with the
    # inconsistent frames left out
    first.inconsistent = sorted(set(left_out) | set(check.inconsistent))
    first.broken_links = [
        (a, b) for a, b in check.broken_links if a not in first.inconsistent and b not in first.inconsistent
    ]
    return first


def _sfm_placement(
    sfm: SfmResult,
    report: ScaleReport,
    calib: Calibration,
    frame_ids: list[int],
    dropped: set[str] | None = None,
) -> tuple[dict[int, NDArray[np.float64]], dict[int, str], dict[str, Any]]:
    """The SfM poses made metric (frame id -> (4, 4) depth camera → room), their method, and scale.json;
    the `dropped` frames (names) are left unplaced."""
    poses: dict[int, NDArray[np.float64]] = {}
    methods: dict[int, str] = {}
    by_name = apply_scale(sfm, report.scale, calib)
    for fid in frame_ids:
        if _frame_name(fid) in by_name and _frame_name(fid) not in (dropped or set()):
            poses[fid] = by_name[_frame_name(fid)]
            methods[fid] = "sfm"
    scale_json = {"method": "sfm", **report.to_json()}
    return poses, methods, scale_json


def _track_placement(
    frames_path: Path,
    track: NDArray[np.float64],
    calib: Calibration,
    cfg: RegisterConfig,
    plan_walls: NDArray[np.float64] | None,
    why: str,
    depth_units_per_m: float | None,
    metrics: dict[str, Any],
    radial_k: float = 0.0,
) -> tuple[dict[int, NDArray[np.float64]], dict[int, str], dict[str, Any]]:
    """The track-based fallback's poses (frame id -> (4, 4) depth camera → plan), their method, and
    scale.json saying why; adds the fallback's metrics to `metrics`. `radial_k`: the capture's radial
    depth error (1/m at the image corner), taken out of the points the joint ICP aligns."""
    poses, fb_metrics = place_by_track(
        (
            (int(r["frame_id"]), int(r["t_ns"]), _decode_depth(r, depth_units_per_m))
            for r in _depth_rows(frames_path)
        ),
        track,
        calib,
        cfg,
        plan_walls,
        radial_k,
    )
    methods = {fid: "track" for fid in poses}
    metrics["fallback"] = fb_metrics
    metrics["fallback_reason"] = why
    scale_json = {
        "method": "track",
        "scale": 1.0,
        "spread_mad": None,
        "spread_iqr": None,
        "frames_used": 0,
        "note": f"frames placed by the IMU track: {why}",
    }
    return poses, methods, scale_json


def _radial_error(
    frames_path: Path,
    frame_ids: list[int],
    calib: Calibration,
    cfg: RegisterConfig,
    depth_units_per_m: float | None,
) -> RadialDepthError | None:
    """The depth camera's radial error (`estimate_radial_depth_error`) on every n-th frame of the capture
    (`cfg.radial_frames` of them); None when `cfg.radial_correction` is off."""
    if not cfg.radial_correction:
        return None
    step = max(1, len(frame_ids) // max(cfg.radial_frames, 1))
    sample = set(sorted(frame_ids)[::step])
    stream = (
        (int(r["frame_id"]), _decode_depth(r, depth_units_per_m), None)
        for r in _depth_rows(frames_path)
        if int(r["frame_id"]) in sample
    )
    return estimate_radial_depth_error(stream, calib, cfg)


def _fuse_placed(
    frames_path: Path,
    poses: dict[int, NDArray[np.float64]],
    calib: Calibration,
    cfg: RegisterConfig,
    depth_units_per_m: float | None,
    radial: RadialDepthError | None = None,
) -> tuple[FusedCloud, RadialDepthError | None]:
    """The placed frames fused (`fuse_capture`, with the capture's `radial` error when given); `poses`
    takes the poses used (ICP-refined ones)."""
    from tasks.ingest.frames import iter_frames

    used_poses: dict[int, NDArray[np.float64]] = {}

    def fuse_stream(only: set[int] | None) -> Iterator[FrameData]:
        from tasks.ingest.frames import decode_rgb

        for r in iter_frames(frames_path, ["frame_id", "depth", "depth_kind", "depth_units_per_m", "rgb"]):
            fid = int(r["frame_id"])
            if fid not in poses or (only is not None and fid not in only):
                continue
            yield fid, _decode_depth(r, depth_units_per_m), decode_rgb(r)

    cloud, radial = fuse_capture(fuse_stream, poses, calib, cfg, used_poses, radial)
    poses.update(used_poses)
    return cloud, radial
