"""Scene types shared by the synthetic building generator and the synthetic sensors.

The BUILDING half (``building.py``) produces a :class:`SceneMesh`; the SENSOR half renders it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Material:
    """Surface appearance of a group of triangles (procedural texture, no image files)."""

    kind: str
    """"paint" | "poster" | "floor" | "ceiling" | "wood" | "glass" | "dark" | "plant" | "metal"."""
    base_rgb: tuple[int, int, int]
    """Mean colour, 0-255."""
    seed: int
    """Procedural texture seed."""
    origin: tuple[float, float, float]
    """Texture frame: a point on the surface (m)."""
    u_axis: tuple[float, float, float]
    """Unit in-plane axis for texture coordinate u."""
    v_axis: tuple[float, float, float]
    """Unit in-plane axis for texture coordinate v."""
    texture_scale_m: float
    """Feature size of the procedural pattern (m)."""


@dataclass(frozen=True)
class SceneMesh:
    """Triangle mesh of a building in the PLAN FRAME (x right, y up as on the plan), z up, floor at z = 0."""

    vertices: NDArray[np.float64]
    """(V, 3) metres."""
    triangles: NDArray[np.int32]
    """(T, 3) vertex indices."""
    material: NDArray[np.int32]
    """(T,) index into ``materials``."""
    materials: tuple[Material, ...]
    """Materials referenced by ``material``."""
