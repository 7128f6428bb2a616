"""Whole calibrations from images, files and a survey's calibration/ folder: target detection, the camera and
stereo adjustment and the disparity fit in order."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from tasks.calibrate.bundle import (
    CameraFit,
    calibrate_camera,
    calibrate_stereo,
    check_same_size,
    list_names,
    pair_names,
    redetect_outliers,
)
from tasks.calibrate.config import CalibrateConfig
from tasks.calibrate.disparity import fit_disparity_model
from tasks.calibrate.targets import detect_targets, parse_pattern, to_gray8
from tasks.camera import Calibration, Redetection, Reject, ViewResidual

log = logging.getLogger(__name__)


def calibrate_images(
    ir_images: Sequence[tuple[str, NDArray]],
    rgb_images: Sequence[tuple[str, NDArray]] | None = None,
    cfg: CalibrateConfig | None = None,
    *,
    flat_frames: Sequence[tuple[str, NDArray]] | None = None,
    known_distances: Sequence[float | NDArray] | None = None,
) -> Calibration:
    """The calibrate stage as a pure function of images: IR (and RGB) target views, optionally flat-target
    raw disparity frames with their known distances. Raises ValueError naming the files for images without a
    target (unless `missing_target="reject"`), mixed sizes, unpaired images or too few views."""
    cfg = cfg or CalibrateConfig()
    pat = parse_pattern(cfg.pattern)
    cams = [("ir", ir_images)] + ([("rgb", rgb_images)] if rgb_images is not None else [])
    pairs = (
        pair_names([n for n, _ in ir_images], [n for n, _ in rgb_images]) if rgb_images is not None else []
    )
    if flat_frames and known_distances is None:
        raise ValueError(
            f"flat-target frames need their known distances: {list_names([n for n, _ in flat_frames])}"
        )
    fits: dict[str, CameraFit] = {}
    rejects: list[Reject] = []
    redetected: list[Redetection] = []
    for cam, images in cams:
        check_same_size([(n, (im.shape[1], im.shape[0])) for n, im in images], cam)
        dets, rej = detect_targets(images, pat, cfg, camera=cam)
        none = [r for r in rej if r.kind == "no_target"]
        if none and cfg.missing_target == "error":
            raise ValueError(
                f"no {pat.describe()} found in {len(none)} of {len(images)} {cam.upper()} calibration images: "
                f"{list_names([r.file for r in none])}"
            )
        fit = calibrate_camera(dets, pat, cfg, camera=cam, prior_rejects=rej)
        grays = {n: to_gray8(im) for n, im in images} if pat.kind == "chessboard" else {}
        for _round in range(3):  # a corner found again moves the calibration, which may show another
            dets, found = redetect_outliers(fit.camera, dets, grays, pat, cfg, cam)
            if not found:
                break
            redetected += found
            fit = calibrate_camera(dets, pat, cfg, camera=cam, prior_rejects=rej)
        fits[cam] = fit
        rejects += rej + list(fit.rejects)
    ir_fit = fits["ir"]
    if rgb_images is None:
        views = tuple(
            ViewResidual(d.name, e) for d, e in zip(ir_fit.detections, ir_fit.view_rms_px, strict=True)
        )
        ir, rgb, pose, stereo_rms = ir_fit.camera, None, None, None
    else:
        st = calibrate_stereo(ir_fit, fits["rgb"], pairs, pat, cfg)
        ir, rgb, pose, stereo_rms, views = st.ir, st.rgb, st.ir_to_rgb, st.stereo_rms_px, st.views
    for label, cam in (("ir", ir), ("rgb", rgb)):
        if cam is not None:
            w, h = cam.size
            border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, 0], [0, h / 2]], float)
            if np.isnan(cam.undistort_pixels(border)).any():
                log.warning(
                    "%s distortion model folds back inside the image: its border pixels have no ray (the views "
                    "do not reach the image corners); those pixels give no points",
                    label.upper(),
                )
    depth_model = None
    if flat_frames and known_distances is not None:
        native = cfg.disparity_native_width_px / ir.size[0]
        depth_model = fit_disparity_model(
            [f for _, f in flat_frames],
            known_distances,
            focal_px=ir.fx * native,
            names=[n for n, _ in flat_frames],
            cfg=cfg,
            shift_x_px=cfg.depth_shift_x_px / native,
        )
    return Calibration(
        ir,
        rgb,
        pose,
        stereo_rms,
        depth_model,
        source="targets",
        rejects=tuple(rejects),
        views=views,
        pattern=str(pat),
        coverage=tuple((cam, fit.coverage) for cam, fit in fits.items()),
        redetected=tuple(redetected),
    )


def read_gray(path: str | Path) -> NDArray:
    """A calibration image as stored (8- or 16-bit grey; colour converted to grey); ValueError if unreadable."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"cannot read calibration image {path}")
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY) if img.shape[2] >= 3 else img[:, :, 0]
    return img


def read_disparity(path: str | Path) -> NDArray:
    """A raw disparity frame: 16-bit PNG/PGM or .npy."""
    p = Path(path)
    if p.suffix == ".npy":
        return np.load(p)
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 2:
        raise ValueError(f"cannot read disparity frame {path} as a single-channel image")
    return img


def calibrate_files(
    ir_paths: Sequence[str | Path],
    rgb_paths: Sequence[str | Path] | None = None,
    cfg: CalibrateConfig | None = None,
    *,
    flat_paths: Sequence[str | Path] | None = None,
    known_distances: Sequence[float] | None = None,
) -> Calibration:
    """`calibrate_images` on files (names reported by file name). Use it for a survey's calibration/ folder."""
    ir = [(Path(p).name, read_gray(p)) for p in ir_paths]
    rgb = None if rgb_paths is None else [(Path(p).name, read_gray(p)) for p in rgb_paths]
    flats = None if flat_paths is None else [(Path(p).name, read_disparity(p)) for p in flat_paths]
    return calibrate_images(ir, rgb, cfg, flat_frames=flats, known_distances=known_distances)


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".tif", ".tiff", ".bmp")


def calibrate_folder(folder: str | Path, cfg: CalibrateConfig | None = None) -> Calibration:
    """A survey's `calibration/` folder: `ir/` (and `rgb/`) target images, paired by the numbers in their names;
    optionally `flat/` raw disparity frames with `flat.yaml` ({distances_m: [...], files: [...]} in file order);
    optionally `target.yaml` ({pattern: "chessboard:9x6:0.04"}) overriding cfg.pattern."""
    import yaml

    folder = Path(folder)
    cfg = cfg or CalibrateConfig()
    target = folder / "target.yaml"
    if target.is_file():
        meta = yaml.safe_load(target.read_text()) or {}
        if "pattern" in meta:
            cfg = replace(cfg, pattern=str(parse_pattern(str(meta["pattern"]))))

    def images(sub: str) -> list[Path]:
        return sorted(p for p in (folder / sub).glob("*") if p.suffix.lower() in _IMAGE_SUFFIXES)

    ir = images("ir")
    if not ir:
        raise ValueError(f"calibration folder {folder} has no ir/ target images")
    rgb = images("rgb") or None
    flats, distances = None, None
    if (folder / "flat.yaml").is_file():
        meta = yaml.safe_load((folder / "flat.yaml").read_text()) or {}
        distances = [float(x) for x in meta.get("distances_m", [])]
        files = meta.get("files") or [p.name for p in images("flat")]
        flats = [folder / "flat" / f for f in files]
        if len(flats) != len(distances):
            raise ValueError(
                f"{folder / 'flat.yaml'}: {len(files)} flat-target files but {len(distances)} distances_m"
            )
    return calibrate_files(ir, rgb, cfg, flat_paths=flats, known_distances=distances)
