"""SfM (thesis 3.2.1): orient a room's colour frames with pycolmap, up to scale.

The thesis oriented Kinect colour images with VisualSFM; here COLMAP's incremental mapper does the same job:
SIFT features, sequential matching for video-like captures (with sparse key-frame pairs as loop closures;
exhaustive for small sets), incremental mapping with bundle adjustment. When the RGB camera is calibrated
its intrinsics are held fixed: frames are undistorted with the calibration first and mapped as PINHOLE
views, so every observation comes back as an ideal (distortion-free) pixel.

Conventions
- Poses are COLMAP's cam_from_world (X_cam = R · X_world + t) in SfM's arbitrary frame and unit.
- Observation pixels are OpenCV pixels (pixel centres at integers; COLMAP's own are at +0.5), in the
  undistorted image when a calibrated camera was given.
- Results are keyed by image NAME: pycolmap's image ids do not follow the order of the input list.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks.camera import CameraModel
from tasks.cloud import DegenerateInputError
from tasks.register.config import SfmConfig

log = logging.getLogger(__name__)


@dataclass
class SfmResult:
    """An SfM reconstruction, keyed by frame name. Unregistered frames are listed but have no pose."""

    names: list[str]
    """Every input frame name, in input order."""
    registered: NDArray[np.bool_]
    """(F,) per input frame: has a pose in the kept (largest) model."""
    cam_from_world: dict[str, NDArray[np.float64]]
    """name -> (4, 4) X_cam = T · X_world (SfM frame and unit), registered frames only."""
    reprojection_error_px: dict[str, float]
    """name -> mean reprojection error of the frame's observations (px)."""
    points: NDArray[np.float64]
    """(P, 3) sparse 3D points (SfM frame and unit)."""
    point_ids: NDArray[np.int64]
    """(P,) COLMAP point3D ids of `points`."""
    observations: dict[str, tuple[NDArray[np.intp], NDArray[np.float64]]]
    """name -> ((M,) row indices into `points`, (M, 2) OpenCV pixel u v of the observation)."""
    camera: CameraModel | None
    """Intrinsics the observations refer to: the undistorted calibrated camera (pinhole), or the mapper's
    estimate (with its radial terms) when none was given or `fix_intrinsics` is off."""
    models: int = 1
    """Number of models the mapper produced (the largest is kept)."""
    keyframes: list[str] = field(default_factory=list)
    """The frames given to the mapper (all of them unless key frames were selected); the other registered
    frames were localized against their map."""
    metrics: dict[str, float] = field(default_factory=dict)
    """Timings and counts."""

    @property
    def registered_fraction(self) -> float:
        return float(self.registered.mean()) if len(self.registered) else 0.0

    def ok(self, cfg: SfmConfig) -> bool:
        """Whether enough frames were registered for the reconstruction to be used."""
        return self.registered_fraction >= cfg.min_registered_fraction

    def poses_columns(self) -> dict[str, NDArray]:
        """The SfM poses as table columns: name, qw qx qy qz tx ty tz (cam_from_world, SfM units; NaN when
        unregistered), registered, reprojection_error_px."""
        from scipy.spatial.transform import Rotation

        n = len(self.names)
        q, t = np.full((n, 4), np.nan), np.full((n, 3), np.nan)
        err = np.full(n, np.nan)
        for k, name in enumerate(self.names):
            T = self.cam_from_world.get(name)
            if T is None:
                continue
            x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
            q[k] = (w, x, y, z) if w >= 0 else (-w, -x, -y, -z)
            t[k] = T[:3, 3]
            err[k] = self.reprojection_error_px.get(name, np.nan)
        return {
            "name": np.array(self.names, dtype=object),
            **{c: q[:, i] for i, c in enumerate(("qw", "qx", "qy", "qz"))},
            **{c: t[:, i] for i, c in enumerate(("tx", "ty", "tz"))},
            "registered": self.registered.copy(),
            "reprojection_error_px": err,
        }

    def observation_columns(self) -> dict[str, NDArray]:
        """Every observation of a sparse point as table columns: name, point (row of `points`), u v (px)."""
        names, rows, uvs = [], [], []
        for name in self.names:
            if name in self.observations:
                r, uv = self.observations[name]
                names += [name] * len(r)
                rows.append(r)
                uvs.append(uv)
        rows_a = np.concatenate(rows) if rows else np.zeros(0, np.intp)
        uv_a = np.concatenate(uvs) if uvs else np.zeros((0, 2))
        return {"name": np.array(names, dtype=object), "point": rows_a, "u": uv_a[:, 0], "v": uv_a[:, 1]}

    def camera_centres(self) -> dict[str, NDArray[np.float64]]:
        """name -> (3,) camera centre in the SfM frame."""
        return {n: -T[:3, :3].T @ T[:3, 3] for n, T in self.cam_from_world.items()}


def _undistort(image: NDArray[np.uint8], camera: CameraModel) -> NDArray[np.uint8]:
    import cv2

    if not np.any(camera.dist):
        return image
    return cv2.undistort(image, camera.K, camera.dist, None, camera.K)


def _check_names(images: Sequence[tuple[str, NDArray]], cfg: SfmConfig) -> None:
    if len(images) < cfg.min_frames:
        raise DegenerateInputError(f"SfM needs at least {cfg.min_frames} frames, got {len(images)}")
    names = [n for n, _ in images]
    if len(set(names)) != len(names):
        raise DegenerateInputError("SfM frame names are not unique")


def _loop_pairs(names: list[str], cfg: SfmConfig, near: int | None = None) -> list[tuple[str, str]]:
    """Every n-th of `names` with every other n-th farther apart than `near` places in the list (default:
    the sequential overlap), the pairs sequential matching does not make."""
    stride = cfg.loop_keyframe_stride
    if stride <= 0:
        return []
    near = cfg.sequential_overlap if near is None else near
    stride = max(stride, -(-len(names) // max(cfg.loop_max_keyframes, 2)))
    keys = list(range(0, len(names), stride))
    return [(names[i], names[j]) for n, i in enumerate(keys) for j in keys[n + 1 :] if j - i > near]


def select_keyframes(
    n: int, inliers: Callable[[int, int], int], min_tracked: float, min_matches: int, window: int
) -> list[int]:
    """Key frames of n frames in capture order from their verified matches: `inliers(i, j)` is the number
    of inlier matches of frames i < j (0 when the pair was not matched). From each key frame k the segment
    runs while the next frame still keeps at least `min_tracked` of the inliers k shares with k + 1 (and
    `min_matches`) within `window` frames of k; its last frame is the next key frame. Both ends are key
    frames, and so is k + 1 when k's chain to it is broken (fewer than `min_matches` inliers)."""
    if n <= 0:
        return []
    keys, k = [0], 0
    while k < n - 1:
        ref, m = inliers(k, k + 1), k + 1
        if ref >= min_matches:
            need = max(min_tracked * ref, min_matches)
            while m + 1 < n and m + 1 - k <= window and inliers(k, m + 1) >= need:
                m += 1
        keys.append(m)
        k = m
    return keys


def sift_first_octave(camera: CameraModel | None, size: tuple[int, int], cfg: SfmConfig) -> int:
    """SIFT's first octave for frames of `size` (width, height): `cfg.sift_first_octave` when set, else
    -1 (the frame doubled) when the focal length in the pixels SIFT sees (after the `max_image_size_px`
    downscale) is below `cfg.sift_min_focal_px`, 0 otherwise. Without a calibrated camera the focal length
    is COLMAP's own prior for an unknown camera, 1.2 times the longest side."""
    if cfg.sift_first_octave is not None:
        return cfg.sift_first_octave
    longest = max(size)
    focal = float(min(camera.K[0, 0], camera.K[1, 1])) if camera is not None else 1.2 * longest
    if cfg.max_image_size_px > 0 and longest > cfg.max_image_size_px:
        focal *= cfg.max_image_size_px / longest
    return -1 if focal < cfg.sift_min_focal_px else 0


def run_sfm(
    images: Sequence[tuple[str, NDArray[np.uint8]]],
    camera: CameraModel | None,
    cfg: SfmConfig,
    workdir: Path,
) -> SfmResult:
    """Incremental SfM of a room's colour frames (thesis 3.2.1).

    images: (name, (H, W, 3) RGB uint8) in capture order; names must be unique and are used as file names.
    camera: the calibrated RGB camera (intrinsics held fixed) or None (COLMAP estimates one shared camera).
    workdir: an empty scratch folder for pycolmap's database, images and models (the only file I/O).
    Raises DegenerateInputError for too few or blank frames; a mapping that registers nothing returns a
    result with no registered frame (check `ok`)."""
    import pycolmap

    _check_names(images, cfg)
    pycolmap.logging.minloglevel = 2
    workdir = Path(workdir)
    img_dir = workdir / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    names = [str(n) for n, _ in images]
    timings: dict[str, float] = {}
    started, cpu_started = time.perf_counter(), time.process_time()
    _write_images(images, camera, img_dir, cfg)
    timings["write_s"] = time.perf_counter() - started

    db = workdir / "database.db"
    if db.exists():
        db.unlink()
    first = np.asarray(images[0][1])
    octave = sift_first_octave(camera, (first.shape[1], first.shape[0]), cfg)
    t0, c0 = time.perf_counter(), time.process_time()
    _extract_features(db, img_dir, names, camera, cfg, octave)
    timings["extract_s"], timings["extract_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    mode = _match_features(db, workdir, names, cfg)
    keys = list(range(len(names)))
    pairs: _PairMatches | None = None
    if mode == "sequential" and cfg.keyframes:
        pairs = _PairMatches(db, names, cfg.sequential_overlap)
        keys = select_keyframes(
            len(names), pairs.count, cfg.keyframe_min_tracked, cfg.min_num_matches, cfg.sequential_overlap
        )
        _match_keyframes(db, workdir, names, keys, cfg)
    timings["match_s"], timings["match_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    mapped = [names[k] for k in keys] if len(keys) < len(names) else None
    recs = _map(db, img_dir, workdir, camera, cfg, mapped)
    timings["map_s"], timings["map_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    # the frames were undistorted: their camera is the pinhole part of the calibrated one, unless the
    # mapper refined it (then the refined one is read back from the model)
    pinhole = None
    if camera is not None and cfg.fix_intrinsics:
        pinhole = CameraModel(camera.K, np.zeros(5), camera.size)
    t0, c0 = time.perf_counter(), time.process_time()
    localized: dict[str, tuple[Any, NDArray[np.float64], NDArray[np.int64]]] = {}
    rec = _largest(recs)
    if pairs is not None and rec is not None:
        localized = _localize(rec, pairs, names, camera is not None and cfg.fix_intrinsics, cfg)
        pairs.close()
    timings["localize_s"], timings["localize_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    timings["total_s"] = time.perf_counter() - started
    timings["total_cpu_s"] = time.process_time() - cpu_started
    result = _result_from_models(names, recs, pinhole, localized)
    result.keyframes = [names[k] for k in keys]
    result.metrics.update({k: round(v, 3) for k, v in timings.items()})
    result.metrics.update(
        keyframes=len(keys),
        keyframe_min_tracked=cfg.keyframe_min_tracked if pairs is not None else 0.0,
        localized=len(localized),
    )
    result.metrics.update(
        frames=len(names),
        registered=int(result.registered.sum()),
        points=len(result.points),
        models=result.models,
        matching=mode,
        sift_first_octave=octave,
    )
    log.info(
        "sfm: %d of %d frames registered, %d points, %.1f s",
        result.registered.sum(),
        len(names),
        len(result.points),
        timings["total_s"],
    )
    return result


def _write_images(
    images: Sequence[tuple[str, NDArray[np.uint8]]], camera: CameraModel | None, img_dir: Path, cfg: SfmConfig
) -> None:
    """Each frame as img_dir/<name> (PNG), undistorted with the calibrated camera when there is one; each
    frame is read once (frames may be encoded images decoded on reading). Raises DegenerateInputError
    when fewer than `cfg.min_frames` frames have any image content."""
    import cv2

    usable = 0
    for name, img in images:
        arr = np.asarray(img)
        if arr.ndim not in (2, 3):
            raise DegenerateInputError(f"SfM frames must be (H, W) or (H, W, 3), got shape {arr.shape}")
        usable += float(arr.std()) > 2.0
        if arr.ndim == 2:
            arr = np.repeat(arr[:, :, None], 3, axis=2)
        if camera is not None:
            if (arr.shape[1], arr.shape[0]) != camera.size:
                raise DegenerateInputError(
                    f"frame {name} is {arr.shape[1]}x{arr.shape[0]} but the RGB camera is "
                    f"{camera.size[0]}x{camera.size[1]}"
                )
            arr = _undistort(arr, camera)
        # PNG keeps the (already lossy) colour as it is; the file name is the frame's name
        cv2.imwrite(str(img_dir / name), cv2.cvtColor(arr[:, :, :3], cv2.COLOR_RGB2BGR))
    if usable < cfg.min_frames:
        raise DegenerateInputError(
            f"only {usable} of {len(images)} frames have any image content (blank or all-black frames)"
        )


def _extract_features(
    db: Path, img_dir: Path, names: list[str], camera: CameraModel | None, cfg: SfmConfig, octave: int
) -> None:
    """SIFT features (scale space from `octave`) of every frame into the database, one shared camera (the
    calibrated pinhole one, or `uncalibrated_camera_model` for COLMAP to estimate)."""
    import pycolmap

    if camera is not None:
        K = camera.K
        # COLMAP puts pixel centres at +0.5, OpenCV at integers
        params = f"{K[0, 0]},{K[1, 1]},{K[0, 2] + 0.5},{K[1, 2] + 0.5}"
        reader = pycolmap.ImageReaderOptions(camera_model="PINHOLE", camera_params=params)
    else:
        reader = pycolmap.ImageReaderOptions(camera_model=cfg.uncalibrated_camera_model)
    extraction = pycolmap.FeatureExtractionOptions(
        num_threads=cfg.extraction_threads, max_image_size=cfg.max_image_size_px
    )
    bucketed = min(cfg.feature_grid) > 0
    extraction.sift.max_num_features = cfg.max_num_features * (4 if bucketed else 1)
    extraction.sift.first_octave = octave
    # the frames enter the database in capture order first: the extractor numbers the images it adds in
    # the order its threads finish them, and the mapper's choices follow the image ids
    pycolmap.Database.open(db).close()
    pycolmap.import_images(
        db, img_dir, camera_mode=pycolmap.CameraMode.SINGLE, image_names=names, options=reader
    )
    pycolmap.extract_features(
        db,
        img_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    if bucketed:
        _bucket_features(db, cfg)


def grid_bucket(
    xy: NDArray[np.float64],
    scale: NDArray[np.float64],
    size: tuple[int, int],
    grid: tuple[int, int],
    keep: int,
) -> NDArray[np.intp]:
    """Indices of `keep` features spread over a (columns, rows) grid of an image of `size` (width, height):
    each cell's features are ranked by scale (largest first) and the features are taken rank by rank over
    all cells (within a rank, larger scale first), so every cell that has features gives its best ones
    before any cell gives more. Returned in their input order; all of them when there are at most `keep`."""
    n = len(xy)
    if n <= keep:
        return np.arange(n)
    cols, rows = grid
    cx = np.clip((xy[:, 0] * cols / size[0]).astype(np.intp), 0, cols - 1)
    cy = np.clip((xy[:, 1] * rows / size[1]).astype(np.intp), 0, rows - 1)
    cell = cy * cols + cx
    # within each cell, the rank of each feature by descending scale (ties by input order)
    order = np.lexsort((np.arange(n), -scale, cell))
    sorted_cell = cell[order]
    starts = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.empty(n, np.intp)
    rank[order] = np.arange(n) - starts
    chosen = np.lexsort((np.arange(n), -scale, rank))[:keep]
    return np.sort(chosen)


def _bucket_features(db: Path, cfg: SfmConfig) -> None:
    """Replace every frame's SIFT features in the database by `cfg.max_num_features` of them spread over
    `cfg.feature_grid` (`grid_bucket`)."""
    import pycolmap

    database = pycolmap.Database.open(db)
    try:
        cameras = {c.camera_id: (int(c.width), int(c.height)) for c in database.read_all_cameras()}
        kept = {}
        for image in database.read_all_images():
            kp = np.asarray(database.read_keypoints(image.image_id), dtype=np.float32)
            desc = database.read_descriptors(image.image_id)
            data = np.asarray(desc.data)
            # keypoint rows: x y a11 a12 a21 a22 (affine shape); its scale is sqrt |det|
            scale = np.sqrt(np.abs(kp[:, 2] * kp[:, 5] - kp[:, 3] * kp[:, 4])).astype(np.float64)
            idx = grid_bucket(
                kp[:, :2].astype(np.float64),
                scale,
                cameras[image.camera_id],
                cfg.feature_grid,
                cfg.max_num_features,
            )
            kept[image.image_id] = (
                kp[idx],
                pycolmap.FeatureDescriptors(desc.type, np.ascontiguousarray(data[idx])),
            )
        database.clear_keypoints()
        database.clear_descriptors()
        for image_id, (kp, desc) in kept.items():
            database.write_keypoints(image_id, kp)
            database.write_descriptors(image_id, desc)
    finally:
        database.close()


def _match_features(db: Path, workdir: Path, names: list[str], cfg: SfmConfig) -> str:
    """Verified matches of the frame pairs `cfg.matching` chooses (sequential ones with loop key frames, or
    all pairs); returns the matching used ("sequential" or "exhaustive")."""
    import pycolmap

    # pairs are matched and verified one by one (each RANSAC seeded), so the thread count does not change
    # the verified matches once the image ids are fixed (checked on 30 real frames: same matches with
    # one thread and with two)
    matching = pycolmap.FeatureMatchingOptions(num_threads=cfg.matching_threads)
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = cfg.random_seed
    mode = cfg.matching
    if mode == "auto":
        mode = "exhaustive" if len(names) <= cfg.exhaustive_max_frames else "sequential"
    if mode == "exhaustive":
        pycolmap.match_exhaustive(
            db, matching_options=matching, verification_options=verification, device=pycolmap.Device.cpu
        )
    else:
        pycolmap.match_sequential(
            db,
            matching_options=matching,
            pairing_options=pycolmap.SequentialPairingOptions(
                overlap=cfg.sequential_overlap, quadratic_overlap=False, num_threads=cfg.matching_threads
            ),
            verification_options=verification,
            device=pycolmap.Device.cpu,
        )
        loops = [] if cfg.keyframes else _loop_pairs(names, cfg)
        if loops:
            pairs_file = workdir / "loop_pairs.txt"
            pairs_file.write_text("".join(f"{a} {b}\n" for a, b in loops))
            pycolmap.match_image_pairs(
                db,
                matching_options=matching,
                pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_file),
                verification_options=verification,
                device=pycolmap.Device.cpu,
            )
    return mode


class _PairMatches:
    """The verified (inlier) matches of the sequential pairs, read from the database once: frames by index
    in capture order, feature indices as COLMAP's point2D indices."""

    def __init__(self, db: Path, names: list[str], window: int) -> None:
        import pycolmap

        self.database = pycolmap.Database.open(db)
        ids = {im.name: im.image_id for im in self.database.read_all_images()}
        self.ids = [ids[n] for n in names]
        self.window = window
        self._matches: dict[tuple[int, int], NDArray[np.int64]] = {}
        for i in range(len(names)):
            for j in range(i + 1, min(i + window + 1, len(names))):
                m = np.zeros((0, 2), np.int64)
                if self.database.exists_two_view_geometry(self.ids[i], self.ids[j]):
                    tvg = self.database.read_two_view_geometry(self.ids[i], self.ids[j])
                    m = np.asarray(tvg.inlier_matches, dtype=np.int64).reshape(-1, 2)
                self._matches[(i, j)] = m

    def count(self, i: int, j: int) -> int:
        return len(self._matches.get((min(i, j), max(i, j)), ()))

    def matches(self, i: int, j: int) -> NDArray[np.int64]:
        """(M, 2) inlier matches (feature of i, feature of j)."""
        m = self._matches.get((min(i, j), max(i, j)), np.zeros((0, 2), np.int64))
        return m if i < j else m[:, ::-1]

    def keypoints(self, i: int) -> NDArray[np.float64]:
        """(N, 2) COLMAP pixel positions (centres at +0.5) of frame i's features."""
        return np.asarray(self.database.read_keypoints(self.ids[i]), dtype=np.float64)[:, :2]

    def close(self) -> None:
        self.database.close()


def _match_keyframes(db: Path, workdir: Path, names: list[str], keys: list[int], cfg: SfmConfig) -> None:
    """Each key frame matched with its next `keyframe_overlap` key frames and the loop pairs among the key
    frames, but for the pairs sequential matching already made."""
    import pycolmap

    keynames = [names[k] for k in keys]
    near = [
        (a, b) for a in range(len(keys)) for b in range(a + 1, min(a + cfg.keyframe_overlap + 1, len(keys)))
    ]
    index = {n: k for k, n in zip(keys, keynames, strict=True)}
    pairs = [
        (x, y)
        for x, y in [(keynames[a], keynames[b]) for a, b in near]
        + _loop_pairs(keynames, cfg, near=cfg.keyframe_overlap)
        if index[y] - index[x] > cfg.sequential_overlap
    ]
    if not pairs:
        return
    pairs_file = workdir / "keyframe_pairs.txt"
    pairs_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = cfg.random_seed
    pycolmap.match_image_pairs(
        db,
        matching_options=pycolmap.FeatureMatchingOptions(num_threads=cfg.matching_threads),
        pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_file),
        verification_options=verification,
        device=pycolmap.Device.cpu,
    )


def _largest(recs: dict) -> Any:
    if not recs:
        return None
    return max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))


def _localize(
    rec: Any, pairs: _PairMatches, names: list[str], fixed: bool, cfg: SfmConfig
) -> dict[str, tuple[Any, NDArray[np.float64], NDArray[np.int64]]]:
    """Every frame the model does not hold, posed against it: its verified matches with the model's frames
    within the sequential window (nearest first) give 2D-3D correspondences, and LO-RANSAC (seeded) with
    refinement gives the pose (intrinsics held when `fixed`). name -> (cam_from_world Rigid3d, (M, 2)
    COLMAP pixels of the inlier observations, (M,) their point3D ids); frames with fewer than
    `localize_min_inliers` inliers stay out."""
    import pycolmap

    by_name = {im.name: im for im in rec.images.values() if im.has_pose}
    est = pycolmap.AbsolutePoseEstimationOptions()
    est.ransac.max_error = cfg.localize_max_error_px
    est.ransac.random_seed = cfg.random_seed
    est.estimate_focal_length = False
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.refine_focal_length = not fixed
    ref.refine_extra_params = not fixed
    camera = rec.cameras[next(iter(rec.cameras))]
    out = {}
    for j, name in enumerate(names):
        if name in by_name:
            continue
        near = sorted(
            (i for i in range(j - pairs.window, j + pairs.window + 1) if 0 <= i < len(names) and i != j),
            key=lambda i: (abs(i - j), i),
        )
        point_of: dict[int, int] = {}
        for i in near:
            image = by_name.get(names[i])
            if image is None:
                continue
            for fj, fi in pairs.matches(j, i):
                p2d = image.points2D[int(fi)]
                if int(fj) not in point_of and p2d.has_point3D():
                    point_of[int(fj)] = int(p2d.point3D_id)
        if len(point_of) < cfg.localize_min_inliers:
            continue
        feats = np.array(sorted(point_of), dtype=np.int64)
        p3 = np.array([point_of[int(f)] for f in feats], dtype=np.int64)
        xy = pairs.keypoints(j)[feats]
        xyz = np.array([rec.points3D[int(p)].xyz for p in p3], dtype=np.float64)
        answer = pycolmap.estimate_and_refine_absolute_pose(xy, xyz, camera, est, ref)
        if answer is None:
            continue
        mask = np.asarray(answer["inlier_mask"], dtype=bool)
        if mask.sum() < cfg.localize_min_inliers:
            continue
        out[name] = (answer["cam_from_world"], xy[mask], p3[mask])
    return out


def _map(
    db: Path,
    img_dir: Path,
    workdir: Path,
    camera: CameraModel | None,
    cfg: SfmConfig,
    image_names: list[str] | None = None,
) -> dict[int, Any]:
    """COLMAP's incremental mapper (bundle adjustment with the given intrinsics held fixed when
    `fix_intrinsics`) on `image_names` (all frames when None): model id -> reconstruction, several when
    the frames do not chain."""
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions(
        num_threads=cfg.num_threads,
        random_seed=cfg.random_seed,
        # with a single model, mapping on real Kinect frames stopped after a spurious 3-image first model
        multiple_models=True,
        min_num_matches=cfg.min_num_matches,
        extract_colors=False,
        ba_global_frames_ratio=cfg.ba_global_frames_ratio,
        ba_global_points_ratio=cfg.ba_global_points_ratio,
        ba_global_max_refinements=cfg.ba_global_max_refinements,
        ba_local_max_refinements=cfg.ba_local_max_refinements,
    )
    if camera is not None and cfg.fix_intrinsics:
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        opts.mapper.abs_pose_refine_focal_length = False
        opts.mapper.abs_pose_refine_extra_params = False
    if image_names is not None:
        opts.image_names = list(image_names)
    out_dir = workdir / "models"
    out_dir.mkdir(exist_ok=True)
    return pycolmap.incremental_mapping(db, img_dir, out_dir, options=opts)


def _result_from_models(
    names: list[str], recs: dict, camera: CameraModel | None, localized: dict | None = None
) -> SfmResult:
    if not recs:
        return SfmResult(
            names,
            np.zeros(len(names), bool),
            {},
            {},
            np.zeros((0, 3)),
            np.zeros(0, np.int64),
            {},
            camera,
            models=0,
        )
    rec = _largest(recs)
    point_ids = np.array(sorted(rec.point3D_ids()), dtype=np.int64)
    points = np.array([rec.points3D[int(i)].xyz for i in point_ids], dtype=np.float64).reshape(-1, 3)
    row_of = {int(pid): k for k, pid in enumerate(point_ids)}
    poses, errors, obs = {}, {}, {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        T = np.eye(4)
        pose = image.cam_from_world()
        T[:3, :3] = pose.rotation.matrix()
        T[:3, 3] = pose.translation
        poses[image.name] = T
        rows, uv = [], []
        for p2d in image.points2D:
            if p2d.has_point3D():
                rows.append(row_of[int(p2d.point3D_id)])
                uv.append(np.asarray(p2d.xy) - 0.5)
        rows_a = np.asarray(rows, dtype=np.intp)
        uv_a = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        obs[image.name] = (rows_a, uv_a)
        if len(rows_a):
            proj = _project(points[rows_a], T, rec.cameras[image.camera_id])
            errors[image.name] = float(np.mean(np.linalg.norm(proj - uv_a, axis=1)))
        else:
            errors[image.name] = float("nan")
    cam = rec.cameras[next(iter(rec.cameras))]
    for name, (pose, xy, p3) in (localized or {}).items():
        T = np.eye(4)
        T[:3, :3] = pose.rotation.matrix()
        T[:3, 3] = pose.translation
        poses[name] = T
        rows_a = np.array([row_of[int(p)] for p in p3], dtype=np.intp)
        uv_a = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - 0.5
        obs[name] = (rows_a, uv_a)
        proj = _project(points[rows_a], T, cam)
        errors[name] = float(np.mean(np.linalg.norm(proj - uv_a, axis=1)))
    if camera is None:
        camera = _pinhole_of(cam)
    registered = np.array([n in poses for n in names])
    return SfmResult(names, registered, poses, errors, points, point_ids, obs, camera, models=len(recs))


def _pinhole_of(cam) -> CameraModel:
    """A COLMAP camera as an OpenCV-convention CameraModel (radial terms k1 (k2) kept)."""
    p = np.asarray(cam.params, dtype=np.float64)
    model = str(cam.model.name) if hasattr(cam.model, "name") else str(cam.model)
    if model.startswith("SIMPLE"):
        f, cx, cy = p[0], p[1], p[2]
        fx = fy = f
        extra = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        extra = p[4:]
    dist = np.zeros(5)
    if model in ("SIMPLE_RADIAL", "RADIAL"):
        dist[: len(extra)] = extra[:2]
    elif model in ("OPENCV", "FULL_OPENCV"):
        dist[:4] = extra[:4]
    K = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]])
    return CameraModel(K, dist, (int(cam.width), int(cam.height)))


def _project(points: NDArray[np.float64], cam_from_world: NDArray[np.float64], cam) -> NDArray[np.float64]:
    pc = points @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    uv = np.asarray(cam.img_from_cam(pc), dtype=np.float64)
    return uv.reshape(-1, 2) - 0.5
