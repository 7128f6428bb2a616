"""floor.ifc: the fused floor for BIM (ifcopenshell), IFC4.

One IfcProject, IfcSite, IfcBuilding and IfcBuildingStorey (elevation 0: the floor). Each wall is an
IfcWall (PredefinedType STANDARD) placed at its centreline's start with its local x along the
centreline: an 'Axis' representation (IfcPolyline from (0, 0) to (L, 0): the reference line is the
centreline), a 'Body' IfcExtrudedAreaSolid of its L x thickness rectangle up to its height, and an
IfcMaterialLayerSetUsage with one layer of its thickness, LayerSetDirection AXIS2, DirectionSense
POSITIVE and OffsetFromReferenceLine -thickness/2 (the standard-wall convention: the layers start half
the thickness on the negative side of the axis). Pset_WallCommon.Status says EXISTING, DEMOLISH or NEW.
One IfcSpace per room (Name: the room id, LongName: the plan's printed label, Pset IndoorSurvey_Room:
plan room id and area). Each door is an IfcOpeningElement voiding its wall (IfcRelVoidsElement), filled
by an IfcDoor (IfcRelFillsElement); a door no wall holds stands in the storey on its own.

The same floor gives the same bytes: the header's time stamp is the config's, and every GlobalId is
ifcopenshell.guid.compress of a uuid5 of the element's identity.
"""

from __future__ import annotations

import itertools
import uuid
from pathlib import Path
from typing import Any

import ifcopenshell
import ifcopenshell.guid
import numpy as np

from tasks.deliver.floor import Door, Floor, Room, Wall

NAMESPACE = uuid.UUID("5f0c1d8e-6a43-4c1e-9d57-0b1f2a3c4d5e")
"""The uuid5 namespace of the file's GUIDs (fixed: GUIDs depend on the element's identity only)."""
STATUS = {"existing": "EXISTING", "demolished": "DEMOLISH", "added": "NEW"}


def guid(identity: str) -> str:
    """The IFC GlobalId of an element: compressed uuid5 of its identity."""
    return ifcopenshell.guid.compress(uuid.uuid5(NAMESPACE, identity).hex)


class _Writer:
    def __init__(self, cfg_timestamp: str, name: str) -> None:
        self.f = ifcopenshell.file(schema="IFC4")
        self.f.header.file_name.name = name
        self.f.header.file_name.time_stamp = cfg_timestamp
        self.f.header.file_description.description = ("ViewDefinition [DesignTransferView]",)
        c = self.f.create_entity
        self.origin = c("IfcCartesianPoint", Coordinates=(0.0, 0.0, 0.0))
        self.z = c("IfcDirection", DirectionRatios=(0.0, 0.0, 1.0))
        self.x = c("IfcDirection", DirectionRatios=(1.0, 0.0, 0.0))
        world = c("IfcAxis2Placement3D", Location=self.origin, Axis=self.z, RefDirection=self.x)
        self.model = c(
            "IfcGeometricRepresentationContext",
            ContextIdentifier=None,
            ContextType="Model",
            CoordinateSpaceDimension=3,
            Precision=1e-5,
            WorldCoordinateSystem=world,
        )
        self.body = c(
            "IfcGeometricRepresentationSubContext",
            ContextIdentifier="Body",
            ContextType="Model",
            ParentContext=self.model,
            TargetView="MODEL_VIEW",
        )
        self.axis = c(
            "IfcGeometricRepresentationSubContext",
            ContextIdentifier="Axis",
            ContextType="Model",
            ParentContext=self.model,
            TargetView="GRAPH_VIEW",
        )
        units = [
            c("IfcSIUnit", UnitType="LENGTHUNIT", Name="METRE"),
            c("IfcSIUnit", UnitType="AREAUNIT", Name="SQUARE_METRE"),
            c("IfcSIUnit", UnitType="VOLUMEUNIT", Name="CUBIC_METRE"),
            c("IfcSIUnit", UnitType="PLANEANGLEUNIT", Name="RADIAN"),
        ]
        self.units = c("IfcUnitAssignment", Units=units)

    def placement(self, relative_to: Any, xy: np.ndarray, direction: np.ndarray, z: float = 0.0) -> Any:
        c = self.f.create_entity
        loc = c("IfcCartesianPoint", Coordinates=(float(xy[0]), float(xy[1]), float(z)))
        ref = c("IfcDirection", DirectionRatios=(float(direction[0]), float(direction[1]), 0.0))
        axes = c("IfcAxis2Placement3D", Location=loc, Axis=self.z, RefDirection=ref)
        return c("IfcLocalPlacement", PlacementRelTo=relative_to, RelativePlacement=axes)

    def extrusion(self, points: list[tuple[float, float]], depth: float, z0: float = 0.0) -> Any:
        """A Body SweptSolid: a closed polyline profile extruded up by `depth` from z0."""
        c = self.f.create_entity
        pts = [c("IfcCartesianPoint", Coordinates=(float(x), float(y))) for x, y in points]
        profile = c(
            "IfcArbitraryClosedProfileDef",
            ProfileType="AREA",
            OuterCurve=c("IfcPolyline", Points=[*pts, pts[0]]),
        )
        pos = c(
            "IfcAxis2Placement3D",
            Location=c("IfcCartesianPoint", Coordinates=(0.0, 0.0, float(z0))),
        )
        solid = c(
            "IfcExtrudedAreaSolid", SweptArea=profile, Position=pos, ExtrudedDirection=self.z, Depth=depth
        )
        return c(
            "IfcShapeRepresentation",
            ContextOfItems=self.body,
            RepresentationIdentifier="Body",
            RepresentationType="SweptSolid",
            Items=[solid],
        )

    def rel(self, kind: str, identity: str, **attrs: Any) -> Any:
        return self.f.create_entity(kind, GlobalId=guid(identity), **attrs)

    def pset(self, identity: str, obj: Any, name: str, values: dict[str, Any]) -> None:
        c = self.f.create_entity
        props = []
        for key, value in values.items():
            if value is None:
                continue
            if isinstance(value, str):
                nominal = self.f.create_entity("IfcLabel", value)
            elif isinstance(value, bool):
                nominal = self.f.create_entity("IfcBoolean", value)
            else:
                nominal = self.f.create_entity("IfcReal", float(value))
            props.append(c("IfcPropertySingleValue", Name=key, NominalValue=nominal))
        pset = c("IfcPropertySet", GlobalId=guid(f"{identity}:pset:{name}"), Name=name, HasProperties=props)
        self.rel(
            "IfcRelDefinesByProperties",
            f"{identity}:defines:{name}",
            RelatedObjects=[obj],
            RelatingPropertyDefinition=pset,
        )


def _wall(w: _Writer, wall: Wall, storey_place: Any, materials: dict[float, Any]) -> tuple[Any, Any]:
    c = w.f.create_entity
    length, t = wall.length_m, wall.thickness_m
    place = w.placement(storey_place, wall.centreline[:2], wall.axis)
    axis_line = c(
        "IfcPolyline",
        Points=[
            c("IfcCartesianPoint", Coordinates=(0.0, 0.0)),
            c("IfcCartesianPoint", Coordinates=(float(length), 0.0)),
        ],
    )
    axis_rep = c(
        "IfcShapeRepresentation",
        ContextOfItems=w.axis,
        RepresentationIdentifier="Axis",
        RepresentationType="Curve2D",
        Items=[axis_line],
    )
    body = w.extrusion([(0.0, -t / 2), (length, -t / 2), (length, t / 2), (0.0, t / 2)], wall.height_m)
    shape = c("IfcProductDefinitionShape", Representations=[axis_rep, body])
    name = f"Wall {wall.wall_id}" if wall.wall_id is not None else f"Added wall {wall.key.split(':')[1]}"
    ifc_wall = c(
        "IfcWall",
        GlobalId=guid(wall.key),
        Name=name,
        ObjectPlacement=place,
        Representation=shape,
        PredefinedType="STANDARD",
    )
    key = round(t, 4)
    if key not in materials:
        mat = materials.setdefault("material", c("IfcMaterial", Name="Wall (as surveyed)"))
        layer = c("IfcMaterialLayer", Material=mat, LayerThickness=float(t), Name="Core")
        materials[key] = c(
            "IfcMaterialLayerSet", MaterialLayers=[layer], LayerSetName=f"Wall {1000 * t:.0f} mm"
        )
    usage = c(
        "IfcMaterialLayerSetUsage",
        ForLayerSet=materials[key],
        LayerSetDirection="AXIS2",
        DirectionSense="POSITIVE",
        OffsetFromReferenceLine=-float(t) / 2,
    )
    w.rel(
        "IfcRelAssociatesMaterial", f"{wall.key}:material", RelatedObjects=[ifc_wall], RelatingMaterial=usage
    )
    w.pset(
        wall.key,
        ifc_wall,
        "Pset_WallCommon",
        {"Status": STATUS[wall.status], "IsExternal": None in wall.rooms and wall.status != "added"},
    )
    w.pset(
        wall.key,
        ifc_wall,
        "IndoorSurvey_Wall",
        {
            "Origin": wall.origin,
            "RoomLeft": wall.rooms[0],
            "RoomRight": wall.rooms[1],
            "ThicknessM": t,
        },
    )
    return ifc_wall, place


def _door(
    w: _Writer, door: Door, floor: Floor, host: tuple[Any, Any] | None, storey_place: Any, height: float
) -> tuple[Any, Any | None]:
    """(IfcDoor, its IfcOpeningElement or None)."""
    c = w.f.create_entity
    width = door.width_m
    if host is not None and door.wall_id is not None:
        wall = floor.walls[door.wall_id]
        s0, s1 = sorted((wall.along(door.segment[:2]), wall.along(door.segment[2:])))
        depth = wall.thickness_m + 0.1
        opening_place = w.placement(host[1], np.array([s0, 0.0]), np.array([1.0, 0.0]))
        body = w.extrusion(
            [(0.0, -depth / 2), (s1 - s0, -depth / 2), (s1 - s0, depth / 2), (0.0, depth / 2)], height
        )
        opening = c(
            "IfcOpeningElement",
            GlobalId=guid(f"{door.key}:opening"),
            Name=f"Opening {door.key.split(':')[1]}",
            ObjectPlacement=opening_place,
            Representation=c("IfcProductDefinitionShape", Representations=[body]),
            PredefinedType="OPENING",
        )
        w.rel(
            "IfcRelVoidsElement",
            f"{door.key}:voids",
            RelatingBuildingElement=host[0],
            RelatedOpeningElement=opening,
        )
        door_place = w.placement(opening_place, np.zeros(2), np.array([1.0, 0.0]))
        leaf = 0.05
    else:
        opening = None
        a = door.segment[:2]
        u = (door.segment[2:] - a) / max(width, 1e-12)
        door_place = w.placement(storey_place, a, u)
        leaf = 0.05
    body = w.extrusion([(0.0, -leaf / 2), (width, -leaf / 2), (width, leaf / 2), (0.0, leaf / 2)], height)
    ifc_door = c(
        "IfcDoor",
        GlobalId=guid(door.key),
        Name=f"Door {door.key.split(':')[1]}",
        ObjectPlacement=door_place,
        Representation=c("IfcProductDefinitionShape", Representations=[body]),
        OverallHeight=float(height),
        OverallWidth=float(width),
        PredefinedType="DOOR",
    )
    if opening is not None:
        w.rel(
            "IfcRelFillsElement",
            f"{door.key}:fills",
            RelatingOpeningElement=opening,
            RelatedBuildingElement=ifc_door,
        )
    w.pset(door.key, ifc_door, "IndoorSurvey_Door", {"Source": door.source, "SeenBy": " ".join(door.rooms)})
    return ifc_door, opening


def _space(w: _Writer, room: Room, storey_place: Any) -> Any:
    c = w.f.create_entity
    place = w.placement(storey_place, np.zeros(2), np.array([1.0, 0.0]))
    polys = getattr(room.polygon, "geoms", [room.polygon])
    reps = []
    largest = max(polys, key=lambda p: p.area)
    ring = list(largest.exterior.coords)[:-1]
    reps.append(w.extrusion([(x, y) for x, y in ring], room.height_m))
    space = c(
        "IfcSpace",
        GlobalId=guid(f"space:{room.id}"),
        Name=room.id,
        LongName=room.label or room.plan_room,
        ObjectPlacement=place,
        Representation=c("IfcProductDefinitionShape", Representations=reps),
        CompositionType="ELEMENT",
        PredefinedType="INTERNAL",
    )
    w.pset(
        f"space:{room.id}",
        space,
        "IndoorSurvey_Room",
        {
            "RoomId": room.id,
            "PlanRoom": room.plan_room,
            "PlanLabel": room.label,
            "AreaM2": room.area_m2,
            "HeightM": room.height_m,
        },
    )
    return space


def build(
    floor: Floor, timestamp: str, name: str = "floor.ifc", door_height_m: float = 2.0
) -> ifcopenshell.file:
    """The IFC model of the floor (module doc)."""
    w = _Writer(timestamp, name)
    c = w.f.create_entity
    project = c(
        "IfcProject",
        GlobalId=guid("project"),
        Name="indoor-survey floor",
        RepresentationContexts=[w.model],
        UnitsInContext=w.units,
    )
    # the spatial chain project > site > building > storey, each placed at its parent's origin
    chain: list[tuple[str, Any, Any]] = [("project", project, None)]
    for key, entity, label, extra in (
        ("site", "IfcSite", "Site", {}),
        ("building", "IfcBuilding", "Building", {}),
        ("storey", "IfcBuildingStorey", "Surveyed floor", {"Elevation": 0.0}),
    ):
        place = w.placement(chain[-1][2], np.zeros(2), np.array([1.0, 0.0]))
        element = c(
            entity, GlobalId=guid(key), Name=label, ObjectPlacement=place, CompositionType="ELEMENT", **extra
        )
        chain.append((key, element, place))
    for (whole_key, whole, _), (key, part, _) in itertools.pairwise(chain):
        w.rel("IfcRelAggregates", f"{whole_key}:{key}", RelatingObject=whole, RelatedObjects=[part])
    _, storey, storey_place = chain[-1]
    materials: dict[Any, Any] = {}
    hosts: dict[int, tuple[Any, Any]] = {}
    contained = []
    for wall in floor.walls:
        hosts[wall.wall_id] = _wall(w, wall, storey_place, materials)
        contained.append(hosts[wall.wall_id][0])
    for wall in floor.added:
        contained.append(_wall(w, wall, storey_place, materials)[0])
    for door in floor.doors:
        host = hosts.get(door.wall_id) if door.wall_id is not None else None
        height = door_height_m
        if door.wall_id is not None:
            height = min(height, floor.walls[door.wall_id].height_m)
        ifc_door, _ = _door(w, door, floor, host, storey_place, height)
        contained.append(ifc_door)
    if contained:
        w.rel(
            "IfcRelContainedInSpatialStructure",
            "storey:contains",
            RelatingStructure=storey,
            RelatedElements=contained,
        )
    spaces = [_space(w, room, storey_place) for room in floor.rooms]
    if spaces:
        w.rel("IfcRelAggregates", "storey:spaces", RelatingObject=storey, RelatedObjects=spaces)
    return w.f


def write(floor: Floor, path: Path, timestamp: str, door_height_m: float) -> dict[str, int]:
    """Write floor.ifc; returns its counts of walls, spaces, doors and openings."""
    f = build(floor, timestamp, "floor.ifc", door_height_m)
    path.write_text(f.to_string())
    return {k: len(f.by_type(f"Ifc{k}")) for k in ("Wall", "Space", "Door", "OpeningElement")}


def validate(path: Path, express_rules: bool = True) -> list[str]:
    """ifcopenshell.validate's errors on a file (schema types, attributes, inverses, where rules)."""
    import ifcopenshell.validate

    logger = ifcopenshell.validate.json_logger()
    ifcopenshell.validate.validate(str(path), logger, express_rules=express_rules)
    return [f"{s.get('instance', '')}: {s.get('message', '')}" for s in logger.statements]


def wall_thicknesses(path: Path) -> dict[str, float]:
    """GlobalId -> the layer thickness of every IfcWall's IfcMaterialLayerSetUsage, read back."""
    f = ifcopenshell.open(str(path))
    out = {}
    for rel in f.by_type("IfcRelAssociatesMaterial"):
        usage = rel.RelatingMaterial
        if not usage.is_a("IfcMaterialLayerSetUsage"):
            continue
        t = sum(layer.LayerThickness for layer in usage.ForLayerSet.MaterialLayers)
        for obj in rel.RelatedObjects:
            if obj.is_a("IfcWall"):
                out[obj.GlobalId] = float(t)
    return out
