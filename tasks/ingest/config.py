"""The ingest stage's settings: computation-free (standard library only), so that the pipeline's config
loads without the readers' libraries."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class IngestConfig:
    """Reading captures. Topic names default to the sensor profile's (configs/sensors/*.yaml)."""

    rgb_topic: str = ""
    """Colour topic (Image or CompressedImage); empty = the profile's `rgb_compressed`, then `rgb`."""
    depth_topic: str = ""
    """Depth topic (Image 16UC1 mm or 32FC1 m); empty = the profile's `depth`."""
    disparity_topic: str = ""
    """Raw Kinect v1 disparity topic, used when there is no depth topic; empty = the profile's."""
    imu_topic: str = ""
    """IMU topic (optional); empty = the profile's."""
    pose_topic: str = ""
    """Device pose topic, PoseStamped (optional); empty = the profile's."""
    max_sync_gap_ms: float = 20.0
    """A depth frame is paired with the nearest colour image within this time; farther = no colour."""
    frame_stride: int = 1
    """Keep every n-th depth frame (1 = all)."""
    max_frames: int = 0
    """Stop after this many frames (0 = all)."""
    tum_depth_units_per_m: float = 5000.0
    """TUM RGB-D depth PNG units per metre."""
    intrinsics_px: tuple[float, float, float, float] | None = None
    """Pinhole intrinsics fx, fy, cx, cy (pixels, no distortion) for both streams, replacing what the
    capture or the sensor profile gives (camera_info.json then says `source: config`)."""
    max_cloud_extent_m: float = 300.0
    """A registered cloud spreading wider than this (1st to 99th percentile, x or y) is not in metres."""
    max_cloud_height_m: float = 30.0
    """...or higher than this (z roughly up: a room, a storey or a stairwell)."""
    cloud_voxel_m: float = 0.01
    """E57, LAS and LAZ clouds are reduced while they are read to one point per voxel of this edge (the
    centroid, colour and intensity averaged), so memory follows the room's surface, not the file's point
    count (about 40 bytes a kept voxel). Half the preprocess voxel (0.02 m): each preprocess voxel is then
    the union of 8 of these, and the walls differ from those of the unreduced cloud by about a millimetre,
    the wall stage's own repeatability. 0 keeps every point (memory then grows with the file). PLY and PCD
    clouds are read as they are."""
    local_origin_beyond_m: float = 1000.0
    """An E57, LAS or LAZ cloud whose first point lies farther than this from zero along an axis
    (projected national-grid coordinates) is moved along that axis to a local origin, the first point
    rounded down to whole metres; georef.json records the shift so that outputs can be put back."""

    def __post_init__(self) -> None:
        if not self.cloud_voxel_m >= 0:
            raise ValueError("ingest.cloud_voxel_m must be 0 (keep every point) or positive")
        if not self.local_origin_beyond_m >= 0:
            raise ValueError("ingest.local_origin_beyond_m must be >= 0")
        if self.frame_stride < 1:
            raise ValueError(
                f"ingest.frame_stride must be 1 or more (every n-th frame), got {self.frame_stride}"
            )
        if self.max_frames < 0:
            raise ValueError(f"ingest.max_frames must be 0 (all frames) or more, got {self.max_frames}")
        if not 0 <= self.max_sync_gap_ms < math.inf:
            raise ValueError(f"ingest.max_sync_gap_ms must be a time >= 0, got {self.max_sync_gap_ms}")
        if not 0 < self.tum_depth_units_per_m < math.inf:
            raise ValueError(
                f"ingest.tum_depth_units_per_m must be positive, got {self.tum_depth_units_per_m}"
            )
        for name in ("max_cloud_extent_m", "max_cloud_height_m"):
            if not 0 < getattr(self, name) < math.inf:
                raise ValueError(f"ingest.{name} must be positive, got {getattr(self, name)}")
        if self.intrinsics_px is not None:
            fx, fy, cx, cy = self.intrinsics_px
            if not (0 < fx < math.inf and 0 < fy < math.inf and math.isfinite(cx) and math.isfinite(cy)):
                raise ValueError(
                    f"ingest.intrinsics_px must be fx, fy > 0 and finite cx, cy (pixels), got {list(self.intrinsics_px)}"
                )
