"""Settings of the register stage and of the two methods it runs (sections `register`, `sfm` and `scale` of
the config tree). Standard library only, so that the config tree loads without pycolmap or Open3D."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class RegisterConfig:
    """Settings of the register stage (section `register` of the config tree)."""

    voxel_size_m: float = 0.02
    """Edge of the fusion voxel grid; the room cloud has one point (the mean) per occupied voxel."""
    min_depth_m: float = 0.5
    """Depth readings nearer than this are not fused (Kinect v1 range 0.5-6 m, thesis 3.3)."""
    max_depth_m: float = 6.0
    """Depth readings farther than this are not fused. The noise grows with the square of the range, but
    the far walls are what the walls stage needs: on the synthetic rooms a 4 m cut left 30-40 % of the wall
    length unseen in two of four rooms (6 m: 85-90 %); outliers are the preprocess stage's job."""
    colour_occlusion_tol_m: float = 0.02
    """Colouring: a point counts as hidden from the RGB camera when it lies farther than this plus
    `colour_occlusion_tol_rel` times its depth behind the nearest point projecting into its RGB
    neighbourhood."""
    colour_occlusion_tol_rel: float = 0.02
    """Relative part of the occlusion tolerance (of the point's depth in the RGB camera)."""
    colour_zbuffer_splat_px: int = 3
    """Neighbourhood (odd, pixels) over which each projected point claims the RGB z-buffer, so that
    background points cannot show through the gaps between the projected foreground points."""
    pixel_stride: int = 2
    """Fuse every n-th depth pixel in each direction (1 = all); the voxel grid is coarser anyway."""
    min_points_per_voxel: int = 1
    """Voxels hit by fewer depth points (over all frames) are dropped (outliers are the preprocess stage's
    job; more than 1 thins out far walls of low-resolution sensors)."""
    radial_correction: bool = True
    """Estimate the depth camera's radial error on the capture and take it out before fusing
    (`RadialDepthError`; applied only when significant)."""
    radial_frames: int = 30
    """Frames sampled (evenly over the placed ones) for that estimate."""
    radial_min_frames: int = 5
    """Fewer usable frames than this: no estimate, nothing applied."""
    radial_min_points: int = 500
    """A frame is usable when its dominant plane has at least this many points."""
    radial_plane_tol_inv_m: float = 0.01
    """Plane inlier band in inverse depth (1/m): about 0.4 px of Kinect v1 disparity, 9 cm at 3 m."""
    radial_normal_tol_deg: float = 20.0
    """A plane point's local normal must lie within this of the plane's."""
    radial_min_significance: float = 3.0
    """The estimate is applied when it is at least this many standard errors from zero."""
    icp_refine: bool = False
    """Refine each frame against its predecessor with open3d point-to-plane ICP before fusing."""
    icp_voxel_m: float = 0.05
    """Downsampling of the frames for ICP."""
    icp_max_distance_m: float = 0.10
    """ICP correspondence distance."""
    icp_max_correction_m: float = 0.10
    """An ICP correction moving the frame more than this (or turning it more than 5 degrees) is rejected."""
    sfm_attempts: int = 3
    """SfM runs (seeds random_seed, +1, ...) at most: another is made while the best so far fails a map check
    (its per-frame scales drift along the capture more than `sfm_max_scale_trend`, or a frame's depth
    disagrees with its neighbours', `map_min_agreement`); the one with most frames placed consistently,
    then with the smallest drift, is kept and its inconsistent frames are left unplaced. 3: on survey seed
    812's r1 the first seed registered a frame of a low-texture wall 0.8 m off and lost the next five
    frames, the second mapped all 24 within 5 mm."""
    sfm_max_scale_trend: float = 0.015
    """Change of the per-frame scales (eq 3.16) from the first frame to the last, relative to the scale
    (`ScaleReport.relative_trend`), above which a reconstruction is bent: -5.5 % on a synthetic room mapped
    with an unlucky seed (8 cm ATE; 0.1 % and 0.7 cm with the next seed), 0.1-0.3 % on well-mapped ones.
    Real Kinect v1 frames spread more from depth noise and timing but without a trend (7-Scenes: 1.3 %
    spread, -0.5 % trend with either seed), so they are mapped once; the spread was the old criterion and
    sent every real capture through SfM twice."""
    map_min_agreement: float = 0.75
    """Neighbour depth check (`tasks.register.check`): a placed frame is inconsistent when, in each of its
    informative pairs with the frames placed before and after it, under this share of the points that land
    on the other frame's measured surface agree with it (the others lie in the free space it saw through).
    Tolerance: the scale's inlier threshold (`scale.inlier_threshold_m` + `scale.inlier_threshold_rel` of
    the depth). Synthetic rooms: 0.92-1.0 for well-mapped pairs, 0.47 and 0.10 around a frame placed 0.8 m
    off."""
    map_min_pair_points: int = 200
    """Neighbour depth check: a pair with fewer points landing on the other frame's measured depth (every
    4th pixel each way) tells nothing."""
    fallback_min_registered_fraction: float = 0.5
    """Below this share of frames registered by SfM, the track-based fallback places the frames."""
    floor_angle_tol_deg: float = 45.0
    """Levelling: first tolerance between a point's normal and the vertical for floor candidates (3.2.2.4);
    it is halved on each of the refinement passes."""
    floor_passes: int = 3
    """Levelling: refinement passes (fit the floor plane, tighten the tolerance, drop outliers)."""
    floor_min_points: int = 300
    """Levelling: fewest floor points for a frame's own floor fit (its camera height; else the other frames'
    median height)."""
    level_max_tilt_deg: float = 30.0
    """Levelling by planes (beyond the thesis): a plane within this of the capture's median up counts as
    horizontal, within this of its horizontal as vertical (a hand-held camera's pitch sweeps 10-15 degrees
    about its median); others (a chair's back, a stair) are not used."""
    level_plane_min_points: int = 40
    """Levelling by planes: fewest inliers (of a frame's points thinned to `level_max_points`) for a plane;
    a far end wall or a strip of floor seen at the image's edge is a few dozen."""
    level_max_points: int = 5000
    """Levelling by planes: a frame's points thinned to at most this many for the plane search."""
    level_plane_sd_deg: float = 0.3
    """Levelling by planes: standard deviation added to every plane's fitted normal (a real wall's plumb or a
    floor's level, a depth camera's residual distortion), so that no plane is trusted beyond it."""
    level_plane_tol_deg: float = 2.0
    """Levelling by planes: a plane agrees with an up direction when its misfit is within this or three of its
    standard deviations; the up most planes' points agree with is taken."""
    level_prior_deg: float = 10.0
    """Levelling by planes: standard deviation of a frame's up around the capture's median up, which holds
    only what the frame's planes leave free (one wall: the turn about its normal, which moves its points
    within that wall only)."""
    track_min_step_m: float = 0.2
    """Eq 3.17: the heading points to the first later track position at least this far away."""
    line_cell_m: float = 0.03
    """Plan-line correction: cell of the orthographic projected image (3.2.2.6)."""
    line_min_count: int = 3
    """Plan-line correction: points per cell for a cell to count as wall (binarisation)."""
    line_min_length_m: float = 0.5
    """Plan-line correction: shortest Hough line used."""
    line_max_angle_deg: float = 40.0
    """Plan-line correction, first pass: a line matches a plan wall only within this orientation difference
    (the later passes use a quarter of it). The track's heading (eq 3.17) is off by as much as the surveyor
    turns the sensor away from the walking direction."""
    line_max_distance_m: float = 1.2
    """Plan-line correction, first pass: a line matches a plan wall only when its midpoint is this close to
    the wall's face (the later passes use a quarter of it)."""
    line_fix_offset: bool = True
    """Plan-line correction: after the heading, also shift the frame across the matched walls (beyond the
    thesis, which corrects the heading only); needs wall thickness in `plan_walls` to match wall faces."""
    line_good_fraction: float = 0.6
    """Plan-line correction: a frame whose lines lie on plan walls for less than this share of their length
    after the correction is retried from other start headings (`heading_search_deg`)."""
    heading_search_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    """Plan-line correction: start headings tried on either side of eq 3.17's for poorly fitting frames."""
    drift_penalty_m_per_m: float = 2.0
    """Plan-line correction: a placement's agreement with the plan (metres of wall line) is lowered by this
    much per metre its track drift departs from the median drift of its neighbours in time."""
    track_drift_model: bool = True
    """Plan-line correction, then one drift model per capture (beyond the thesis): the track's drift over the
    capture is fitted (a 2D similarity and a heading drift) to the directions the frames' walls pin (`track_drift`), and
    every frame is placed by it and fitted to the walls once more, within `track_refit_max_shift_m`."""
    track_drift_prior: tuple[float, float] = (0.05, 5.0)
    """Drift model prior: standard deviations of its rotation (radians) and of its shift (m) around the
    track itself; they hold what no frame pins."""
    track_scale_prior: float = 0.02
    """Drift model prior: standard deviation of the track's scale error (fraction of the distance walked).
    A foot-mounted IMU with zero-velocity updates keeps its stride scale within about 1-2 %; a scale far
    from 1 is then only taken where several frames pin it, not from one frame that matched a wrong jamb."""
    track_heading_rate_prior_deg_s: float = 0.05
    """Drift model: standard deviation of its heading drift rate (the gyro z bias of a MEMS IMU, deg/s)."""
    track_drift_sigma_m: float = 0.05
    """Drift model: standard deviation of a frame's plan-fitted position in a pinned direction."""
    track_pin_outlier_z: float = 3.0
    """Drift model: a frame is dropped from the model when the model of the other frames (with the priors)
    puts it more than this many standard deviations from its plan-fitted position."""
    track_drift_rounds: int = 3
    """Drift model: rounds of fitting the model and fitting the frames placed by it to the walls again."""
    track_pin_length_m: float = 1.0
    """Drift model: the wall length (m) a frame must see across a direction for its position to count fully
    in that direction (less counts in proportion)."""
    track_restart_min_shift_m: float = 0.04
    """A poorly fitting frame restarts from a neighbour's track drift when the two drifts differ by at least
    this (closer drifts would reproduce the same placement)."""
    track_refit_max_shift_m: float = 0.3
    """Drift model: a frame fitted to the walls again may move at most this far from the model's placement
    (else the model's placement stands); also the robust scale of the model's residuals."""
    wall_band_m: tuple[float, float] = (0.3, 2.0)
    """Height band above the floor whose points form the projected wall image."""
    track_mutual_check: bool = True
    """After the fallback's placement on the plan walls, each frame checked against the other frames' depth
    (`check_with_neighbours`): a frame whose wall points land on the walls the others saw for less than half
    the capture's typical share (a corner fits the coarse plan as well turned by a quarter) is turned about
    its camera onto the others' points where one placement clearly agrees, and left unplaced where it
    still agrees with under a quarter of that share or where a distinct placement it cannot take agrees
    twice as well."""
    track_mutual_tol_m: float = 0.05
    """Mutual check: a frame's wall point agrees with the other frames when one of theirs lies this close (a
    Kinect's wall noise at 3-4 m and a placement's few centimetres)."""
    track_joint_icp: bool = True
    """After the fallback's placement on the plan walls, one joint ICP of all its frames (`joint_icp`, issue
    #15): every frame moved in x, y and heading so that the walls neighbouring frames share coincide, in the
    directions each pair pins, each frame held near its plan placement by a prior. On since the mutual check
    leaves a frame that a distinct placement refutes unplaced (seeds 811-818 and data/mini, fusion: corridors
    within 2 cm 8/9 -> 9/9, 813's 2.03 -> 1.24 cm; walls within 2 cm from both sides 43/45 -> 44/45, 813's
    5.27 -> 2.23 cm, 815's 3.00 -> 1.22 cm); before that check it lost a wall niche of 814's corridor."""
    track_joint_iterations: int = 10
    """Joint ICP: iterations (each matches the frames again)."""
    track_joint_max_dist_m: tuple[float, float] = (0.15, 0.04)
    """Joint ICP: correspondence distance of the first and the last iteration (geometric steps between):
    the first covers the fallback's placement error between frames, the last a depth camera's noise."""


@dataclass(frozen=True)
class SfmConfig:
    """Settings of the sfm stage (section `sfm` of the config tree)."""

    matching: Literal["auto", "sequential", "exhaustive"] = "auto"
    """Pairing: sequential (video-like captures), exhaustive, or auto = exhaustive up to
    `exhaustive_max_frames` frames, sequential beyond."""
    exhaustive_max_frames: int = 40
    """Largest frame count matched exhaustively by `matching="auto"`."""
    sequential_overlap: int = 5
    """Sequential matching: each frame is matched with this many following frames. On 100 real 7-Scenes
    frames (every 10th of the recording, loop pairs as below) 5 instead of 10: with SIFT at the frames' own
    resolution matching CPU 8.5 -> 5.6 s of 32 (SfM 0.323 -> 0.291 CPU s/frame), ATE 4.29 -> 4.26 cm, all
    registered (doubled frames: 11.1 -> 8.0 s of 96, ATE 4.29 -> 4.26 cm). Captures up to
    `exhaustive_max_frames` frames are matched exhaustively and do not use it."""
    loop_keyframe_stride: int = 5
    """Loop closures (sequential matching): every n-th frame is also matched with every other n-th frame
    farther apart than the overlap (0 = off). Stands in for vocabulary-tree loop detection, whose tree
    would have to be downloaded. They pay on 100 real 7-Scenes frames: without them ATE 5.06 cm instead
    of 4.14 cm for 12 % less SfM CPU; 15 key frames instead of 30 saved 1 %."""
    keyframes: bool = True
    """Sequential matching: only key frames are mapped (`select_keyframes` on the verified matches); every
    other frame is then posed against their map (absolute pose from its matches with the mapped frames in
    its sequential window) and its inlier observations join the result's like a mapped frame's. The loop
    pairs are made among the key frames. Exhaustive matching (small sets) maps every frame. Measured (one
    thread): the 300-frame rendered walk 61 key frames, mapping 12 CPU s instead of ~511, walk ATE 2.0 mm
    instead of 205 mm (the full map bent), register stage 163-171 CPU s instead of 509; 100 real 7-Scenes
    frames 58 key frames, SfM 0.250 -> 0.182 CPU s/frame, ATE 4.26 -> 4.25 cm, 100/100 registered."""
    keyframe_min_tracked: float = 0.7
    """A frame stays in its key frame's segment while it keeps at least this share of the inlier matches
    the key frame has with the frame after it (segments end at the sequential window at the latest). 0.5
    gave 36 key frames of 100 on 7-Scenes (0.160 CPU s/frame, ATE 4.08 cm) but on its every-20th 50 frames
    the per-frame scales drifted -2.4 % along the capture (a second SfM attempt); 0.7 drifts 0.65 %."""
    keyframe_overlap: int = 3
    """Each key frame is also matched with this many following key frames."""
    localize_max_error_px: float = 4.0
    """RANSAC threshold (px) of a localized frame's absolute pose (the mapper filters at 4 px)."""
    localize_min_inliers: int = 30
    """Fewest inlier 2D-3D correspondences for a localized frame (the mapper's own minimum)."""
    loop_max_keyframes: int = 30
    """At most this many loop key frames (the stride grows for long captures: pairs grow with its square)."""
    max_image_size_px: int = 1024
    """Frames larger than this (longest side) are downscaled for feature extraction."""
    max_num_features: int = 4096
    """SIFT features per frame."""
    feature_grid: tuple[int, int] = (0, 0)
    """Grid-bucketed features: SIFT is extracted with up to 4x `max_num_features` and each frame keeps
    `max_num_features` of them spread over this many (columns, rows) cells: the largest-scale features of
    every cell first, then the next of every cell, so that no part of the frame is left out while
    another holds hundreds. (0, 0) keeps SIFT's own choice (the largest scales of the whole frame)."""
    sift_first_octave: int | None = None
    """SIFT's first octave: -1 doubles the frame before the scale space (COLMAP's default: more, smaller
    features), 0 starts at the frame's own resolution, None chooses from the camera (`sift_min_focal_px`)."""
    sift_min_focal_px: float = 500.0
    """With `sift_first_octave` None, the frame is doubled only when its focal length (in the pixels SIFT
    sees, after `max_image_size_px`) is below this, so that SIFT's finest scale (1.6 px) always spans at
    most about 3 mrad: what the map's accuracy follows. Rendered views of the test room, camera centres
    after Sim(3): 320x240 (f 260 px) 12.7 mm at octave 0, 1.8 mm doubled; 640x480 (f 520 px) 0.9 mm either
    way. On 100 real 7-Scenes frames (f 585 px) octave 0 instead of -1: SfM 0.750 -> 0.323 CPU s/frame
    (extraction 25.7 -> 8.1 s, matching 23.6 -> 8.5, mapping 24.1 -> 14.2) at ATE 4.23 -> 4.29 cm, all
    registered; every synthetic survey (320x240, f 261 px) is still doubled, so maps the same bytes. The
    choice is in the metrics (`sfm.sift_first_octave`)."""
    extraction_threads: int = 2
    """Threads for SIFT extraction. Each frame's features are its own whatever the thread count, and the
    frames enter the database in capture order first, so the image ids do not depend on it either (60
    rendered frames, one thread and three runs with two: the same keypoints and descriptors)."""
    matching_threads: int = 1
    """Threads for matching and verification. One: with two, a 300-frame register stage once gave a
    different cloud from run to run (308,748 and 309,307 points), which a cache key cannot allow (COLMAP's
    CPU matcher searches an approximate nearest-neighbour index whose result may depend on how its work
    is split). The mapper's are `num_threads`."""
    ba_global_frames_ratio: float = 1.1
    """Incremental mapping: a global bundle adjustment is run when the registered frames have grown by
    this factor since the last one (COLMAP's default 1.1; more means fewer global adjustments). 1.4 with
    the points ratio 1.4 and one local refinement: on 100 real 7-Scenes frames mapping CPU 19.0 -> 11.8 s
    at ATE 4.26 -> 4.25 cm, but (with two feature threads) data/mini's r1 came out at ATE 2.3 cm instead
    of 0.3, scale -0.37 % instead of -0.10 %, corner F1 0.71 instead of 1.00; so COLMAP's defaults stay.
    Again with one thread and SIFT at the frames' own resolution: 7-Scenes mapping 16.2 -> 9.5 CPU s (SfM
    0.25 CPU s/frame) at ATE 4.25 cm, and data/mini's r1 ATE 0.32 -> 2.15 cm, corner F1 0.77: the bundle
    adjustments, not the threads, cost r1 its accuracy."""
    ba_global_points_ratio: float = 1.1
    """Incremental mapping: likewise for the number of 3D points."""
    ba_global_max_refinements: int = 5
    """Incremental mapping: rounds of global bundle adjustment with retriangulation and filtering."""
    ba_local_max_refinements: int = 2
    """Incremental mapping: rounds of local bundle adjustment after each registered frame."""
    min_num_matches: int = 15
    """Fewest verified matches for an image pair to count in mapping."""
    fix_intrinsics: bool = True
    """Hold the given RGB intrinsics fixed in bundle adjustment; False starts from them and refines focal
    length and principal point (for intrinsics that are only nominal). A calibrated focal length's error
    passes into the metric scale one to one (survey 731, both focal lengths drawn +0.21 %: its r1 +0.21 %
    with the calibration, -0.005 % with the true one), but refining it per room from 24 frames is
    noisier than the calibration: over 25 SfM rooms of the dev surveys the scale error's RMS went 0.143
    -> 0.142 %, 731 r1 +0.204 -> -0.002 %, but without 731 0.099 -> 0.149 % (733 r3 -0.083 -> -0.376 %);
    so it stays held."""
    uncalibrated_camera_model: str = "SIMPLE_RADIAL"
    """COLMAP camera model estimated when no calibrated camera is given."""
    num_threads: int = 1
    """Threads of the mapper (extraction and matching: `extraction_threads`, `matching_threads`). 1 makes runs repeatable (a
    cache key must mean one result; with 2 threads one CI run in a few mapped a room wrongly); the
    building flow already runs rooms in parallel."""
    random_seed: int = 0
    """Seed of COLMAP's RANSAC and mapper."""
    min_registered_fraction: float = 0.5
    """Below this share of registered frames the reconstruction counts as failed (`SfmResult.ok`)."""
    min_frames: int = 3
    """Fewer frames than this is an error: no reconstruction can be made."""


@dataclass(frozen=True)
class ScaleConfig:
    """Settings of the scale stage (section `scale` of the config tree)."""

    ransac_iterations: int = 200
    """RANSAC draws of 3 correspondences per frame."""
    inlier_threshold_m: float = 0.03
    """A correspondence is an inlier when its residual after the similarity is below this plus
    `inlier_threshold_rel` times its depth."""
    inlier_threshold_rel: float = 0.02
    """Depth-proportional part of the inlier threshold (Kinect range noise grows with distance)."""
    min_points_per_frame: int = 8
    """Fewest SfM points with a depth measurement for a frame to estimate a scale."""
    min_inlier_fraction: float = 0.5
    """A frame whose best similarity explains fewer of its correspondences is not used."""
    depth_window_px: int = 1
    """Half size of the window around an observation in which the depth (projected into RGB) is read."""
    depth_stride: int = 0
    """Back-project every n-th depth pixel in each direction (0 = about 320 columns: 2 at 640x480); the
    window above still catches a projected point at the RGB pixels."""
    max_depth_step_m: float = 0.05
    """Observations whose depth window spans more than this (a depth edge) are skipped."""
    step_noise_factor: float = 3.0
    """The edge and same-surface tests allow at least this many times the depth image's own 3x3 spread at
    the range (`tasks.register.scale.depth_noise_coefficient`, measured on each frame and reported as
    `depth_noise_m_at_1m`): with `max_depth_step_m` alone, a Kinect's windows on walls 3 m and more away
    were dropped whenever their noise spread passed 5 cm, which kept the nearer-reading ones and made the
    depth at the SfM points 0.08 % short (synthetic survey 812, room r2)."""
    min_depth_m: float = 0.3
    """Nearer depth readings are ignored."""
    max_depth_m: float = 6.0
    """Farther depth readings are ignored."""
    scale_from: Literal["range", "helmert"] = "range"
    """A frame's scale: "helmert" = λ of its eq 3.16 fit; "range" = the median ratio, over the correspondences
    that fit agrees with, of the depth measured along the ray to the SfM depth of the point in that frame.
    The similarity's λ also follows the lateral extent of the points, which inherits any error of the
    colour intrinsics and of the depth/colour registration (on 7-Scenes, whose colour intrinsics are only
    nominal, "helmert" was 1.9 % off the given poses and "range" 0.3 %)."""
    scale_formula: Literal["asymmetric", "symmetric"] = "asymmetric"
    """Horn's scale formula (see `horn_similarity`): asymmetric = errors in the depth points."""
    combine: Literal["median", "trimmed_mean"] = "median"
    """How the per-frame scales are combined."""
    trim_fraction: float = 0.2
    """Share cut from each end for `combine="trimmed_mean"`."""
    min_frames: int = 1
    """Fewest frames with a scale; fewer is an error."""
    random_seed: int = 0
    """Seed of the RANSAC draws."""
