"""The preprocess stage's settings (thesis 5.1, table 6.3): plain data, importable without the stage's
computation."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class PreprocessConfig:
    """Preprocess parameters (thesis 5.1, table 6.3)."""

    outlier_neighbours: int = 20
    """K: nearest neighbours whose mean distance each point is tested on (count; thesis: 20)."""
    outlier_std_ratio: float = 2.0
    """Removed: statistic above μ + this × σ of its values (unitless; eq 5.1: 1σ or 2σ, table 6.3)."""
    outlier_reference: Literal["global", "local"] = "local"
    """"global": eq 5.1 on the mean K-NN distance (PCL); "local": density-aware, the distance against the
    neighbours' and linked to the dense points (far surfaces of a range sensor stay), see
    `statistical_outliers`."""
    voxel_size_m: float = 0.02
    """Voxel grid edge (m); also the height histogram's bin (thesis: 3-5 cm Kinect, 1 cm TLS)."""
    mls_radius_m: float = 0.10
    """MLS search radius, also the Gaussian weight's scale (m; thesis: 10-15 cm for Kinect)."""
    mls_degree: Literal[1, 2] = 1
    """Degree of the MLS local fit: 1 plane (the thesis' choice for Kinect), 2 quadratic (unitless)."""
    mls_edge_ratio: float = 10.0
    """Surface variation above this × its median marks an edge: not moved by MLS, not levelled on (0: off)."""
    level_normals: Literal["horizontal", "vertical", "both"] = "both"
    """Normals the tilt comes from: horizontal surfaces (the thesis), walls, or both (measured best)."""
    level_split_deg: float = 45.0
    """Normals within this angle of the vertical axis are horizontal surfaces, the rest vertical (degrees)."""
    level_max_iterations: int = 10
    """Most levelling iterations (rotate, reclassify, re-estimate) (count)."""
    level_tol_deg: float = 0.005
    """Levelling stops once an iteration's tilt correction is below this (degrees)."""
    peak_min_area_m2: float = 0.25
    """A histogram peak can be floor or ceiling if it rises this much area above its surroundings (m²)."""
    surface_search_m: float = 0.20
    """Floor (ceiling) peak must lie within this of where the walls end, else it is not captured (m)."""
    slice_min_m: float = 1.5
    """Furniture slice lower edge above the floor (m)."""
    slice_max_m: float = 2.5
    """Furniture slice upper edge above the floor (m)."""
    slice_ceiling_margin_m: float = 0.15
    """The slice stops at least this far below the ceiling: lamps, rooms lower than slice_max_m (m)."""
    slice_min_band_m: float = 0.5
    """The slice is at least this tall (m). Where the walls were seen only up to a lower height (a handheld
    scan: no ceiling, walls ending at 1.3 m) the band is the highest one of this height under the top of
    the walls: low furniture (tables, chairs, beds) stays below it or does not reach its top."""
    wall_normal_max_z: float = 0.5
    """Without a captured ceiling, or with the slice lowered under `slice_min_m`, the slice keeps only the
    points of smooth vertical surfaces: normal's vertical component at most this (sin 30°)."""
    min_wall_span_m: float = 0.6
    """The levelled cloud must span at least this height: less holds no wall band (m)."""

    def __post_init__(self) -> None:
        checks = [
            (self.outlier_neighbours >= 1, "outlier_neighbours must be at least 1"),
            (self.outlier_std_ratio > 0, "outlier_std_ratio must be positive"),
            (self.outlier_reference in ("global", "local"), "outlier_reference must be global or local"),
            (self.voxel_size_m > 0, "voxel_size_m must be positive"),
            (self.mls_radius_m > self.voxel_size_m, "mls_radius_m must exceed voxel_size_m"),
            (self.mls_degree in (1, 2), "mls_degree must be 1 or 2"),
            (0 < self.level_split_deg < 90, "level_split_deg must be between 0 and 90"),
            (self.level_max_iterations >= 1, "level_max_iterations must be at least 1"),
            (self.level_tol_deg > 0, "level_tol_deg must be positive"),
            (self.mls_edge_ratio >= 0, "mls_edge_ratio must be >= 0"),
            (self.peak_min_area_m2 > 0, "peak_min_area_m2 must be positive"),
            (self.surface_search_m > 0, "surface_search_m must be positive"),
            (0 <= self.slice_min_m < self.slice_max_m, "slice_min_m must be >= 0 and below slice_max_m"),
            (self.slice_ceiling_margin_m >= 0, "slice_ceiling_margin_m must be >= 0"),
            (self.slice_min_band_m > 0, "slice_min_band_m must be positive"),
            (self.min_wall_span_m > 0, "min_wall_span_m must be positive"),
            (0 < self.wall_normal_max_z <= 1, "wall_normal_max_z must be in (0, 1]"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"preprocess: {message}")
