"""Settings of the calibrate stage (section `calibrate` of the config tree). Standard library only, so that
the config tree loads without OpenCV."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class CalibrateConfig:
    """Settings of the calibrate stage (section `calibrate` of the config tree)."""

    pattern: str = "chessboard:9x6:0.025"
    """Target: `chessboard:COLSxROWS:SQUARE_M` (inner corners) or `circles:COLSxROWS:SPACING_M` (asymmetric grid)."""
    detector: Literal["classic", "sb"] = "classic"
    """Chessboard detector: OpenCV's classic one refined by cornerSubPix, or the sector-based (SB) one."""
    subpix_window_px: int = 7
    """Half size of the cornerSubPix search window (classic chessboard detector), capped at 0.3 of the square
    size in the image: larger windows reach the neighbouring corners (OpenCV's sample uses 11, which costs
    its reference left02 view of the real stereo set 1.2 px RMS)."""
    max_edge_rise_px: float = 5.0
    """Blur rejection: a view whose median 10-90 % edge rise around the target points exceeds this is rejected
    (sharp Kinect/webcam views measure 2-3.5 px; a Gaussian blur of sigma 2 px gives about 5.7 px)."""
    min_border_px: float = 4.0
    """A detection with a point closer than this to the image border is rejected as partial."""
    redetect_sigma: float = 6.0
    """A chessboard corner whose residual after the first calibration exceeds this many times the robust
    per-axis noise of all corners is refined again from where the calibration puts it (see
    `tasks.calibrate.bundle.redetect_outliers`)."""
    min_views: int = 6
    """Fewest usable views per camera for a calibration (and complete pairs for the "opencv" stereo solver);
    fewer is an error naming the files."""
    max_view_rms_px: float = 2.0
    """A view whose reprojection RMS after the first adjustment exceeds this is rejected and the camera
    re-adjusted without it."""
    min_coverage: float = 0.6
    """Below this share of image cells holding target points the stage warns that the distortion near the
    borders is extrapolated (reported as `coverage` in the residuals file either way)."""
    missing_target: Literal["error", "reject"] = "error"
    """Images in which no target is found at all: an error naming them, or a reject that is reported."""
    fix_k3: bool = False
    """Hold k3 at zero (for sets too small or too central to determine it)."""
    stereo_solver: Literal["bundle", "opencv"] = "bundle"
    """Joint adjustment: "bundle" adjusts both cameras, the relative pose and every board pose over all valid
    views of either camera (a view whose partner image was rejected still counts, as in the thesis' bundle
    adjustment); "opencv" is cv2.stereoCalibrate on the complete pairs only."""
    min_stereo_pairs: int = 4
    """Fewest views with the target found in both cameras for the relative pose."""
    stereo_refine_intrinsics: bool = True
    """Re-estimate both cameras' intrinsics together with the relative pose (the thesis' joint adjustment);
    False keeps the mono intrinsics and estimates the relative pose only."""
    depth_shift_x_px: float = 4.0
    """Shift of the Kinect v1 disparity image against the IR image, in native disparity pixels: IR column =
    disparity column + shift (scaled to the IR image when that is binned, e.g. 2 px at 320x240)."""
    disparity_native_width_px: int = 640
    """Width at which the device computes disparity: raw d_k are in these pixels whatever the delivered image
    size, so b·c splits into the baseline with the IR focal length scaled to this width."""
    flat_roi_fraction: float = 0.6
    """Central part (fraction of width and height) of flat-target disparity frames used for the model fit."""
