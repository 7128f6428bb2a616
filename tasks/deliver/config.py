"""The deliver stage's configuration (computation-free: stdlib imports only)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DeliverConfig:
    """The deliverables of the fused floor: floor.dxf, floor.ifc, floor.ply, floor.prj, room clouds."""

    cloud_voxel_m: float = 0.02
    """Room clouds are reduced to one point (the mean, its mean colour) per voxel of this size; 0 keeps
    every point."""
    default_height_m: float = 2.5
    """Wall height where no room either side has a measured height."""
    door_height_m: float = 2.0
    """Height of a door opening (IFC opening, the mesh's lintel starts there)."""
    added_thickness_m: float = 0.10
    """Thickness of an added wall seen from one side only (no second face within pair_gap_m)."""
    pair_gap_m: float = 0.35
    """Two parallel, overlapping added faces this close are the two faces of one added wall."""
    slab_thickness_m: float = 0.10
    """Floor slab under each room in floor.ply (from -this to z = 0)."""
    timestamp: str = "2000-01-01T00:00:00"
    """Written as the IFC header's time stamp, so the same inputs give the same bytes."""
