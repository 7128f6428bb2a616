"""The deliver stage: floor.dxf, floor.ifc, floor.ply, floor.prj and the room clouds, on small synthetic
floors with known answers and on data/mini."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import ezdxf
import ifcopenshell
import numpy as np
import pytest
import shapely

from tasks import artefacts as art
from tasks.deliver import clouds, dxf, ifc, mesh
from tasks.deliver.config import DeliverConfig
from tasks.deliver.floor import ChangeMark, Door, Floor, Room, Wall, pair_added, read_floor, subtract
from tasks.fuse.floor import floor_doors, host_wall
from tasks.fuse.stage import PLAN_CRS_WKT

CFG = DeliverConfig()


def two_rooms() -> Floor:
    """Rooms A [0,4]x[0,3] and B [4,8]x[0,3]: an outer shell 0.2 m thick, a 0.1 m partition at x = 4 with
    a 0.9 m door, a removed metre of the top wall over B, an added 8 cm partition in A (two faces) and a
    wall stretch nobody saw."""
    segs = [(0, 0, 8, 0), (0, 3, 8, 3), (0, 0, 0, 3), (8, 0, 8, 3), (4, 0, 4, 3)]
    thick = [0.2, 0.2, 0.2, 0.2, 0.1]
    walls = [
        Wall(f"wall:{i}", np.array(s, dtype=float), t, 2.5, "existing", "plan", ("A", None), i)
        for i, (s, t) in enumerate(zip(segs, thick, strict=True))
    ]
    door = Door("door:0", np.array([4.0, 1.0, 4.0, 1.9]), 4, "observed", ("A", "B"))
    changes = [
        ChangeMark(np.array([5.0, 3.0, 6.0, 3.0]), "removed", "B", 1),
        ChangeMark(np.array([1.0, 1.50, 2.0, 1.50]), "added", "A"),
        ChangeMark(np.array([2.0, 1.58, 1.0, 1.58]), "added", "A"),
        ChangeMark(np.array([8.0, 0.5, 8.0, 1.5]), "unknown", "B", 3),
    ]
    added = [
        Wall(f"added:{k}", seg, t, 2.5, "added", "observed")
        for k, (seg, t) in enumerate(
            pair_added(
                np.array([c.segment for c in changes if c.kind == "added"]),
                ["A", "A"],
                {},
                np.array(segs, dtype=float),
                np.array(thick),
                CFG,
            )
        )
    ]
    rooms = [
        Room("A", "R1", "101", shapely.box(0.1, 0.1, 3.95, 2.9), 2.5),
        Room("B", "R2", None, shapely.box(4.05, 0.1, 7.9, 2.9), 2.4),
    ]
    return Floor(
        walls,
        added,
        [door],
        rooms,
        changes,
        np.array(segs, dtype=float),
        np.array(thick),
        np.array([[4.0, 1.0, 4.0, 1.9]]),
    )


# ---------------------------------------------------------------------------------------------- geometry


def test_subtract_cuts_an_interval_into_its_pieces():
    assert subtract((0.0, 8.0), [(5.0, 6.0)]) == [(0.0, 5.0), (6.0, 8.0)]
    assert subtract((0.0, 3.0), [(1.9, 1.0), (-1.0, 0.2)]) == [(0.2, 1.0), (1.9, 3.0)]
    assert subtract((0.0, 1.0), [(-1.0, 2.0)]) == []


def test_two_faces_of_an_added_partition_make_one_wall_between_them():
    floor = two_rooms()
    assert len(floor.added) == 1
    wall = floor.added[0]
    assert wall.thickness_m == pytest.approx(0.08)
    assert wall.centreline[[1, 3]] == pytest.approx([1.54, 1.54])
    assert sorted(wall.centreline[[0, 2]]) == pytest.approx([1.0, 2.0])


def test_a_lone_added_face_in_a_door_gap_takes_the_plan_walls_line_and_thickness():
    centrelines = np.array([[0.0, 0.0, 3.0, 0.0], [4.0, 0.0, 8.0, 0.0]])
    face = np.array([[3.0, 0.09, 4.0, 0.09]])  # the closed door's face, seen from the room above
    (seg, t), = pair_added(face, ["A"], {}, centrelines, np.array([0.18, 0.18]), CFG)  # fmt: skip
    assert t == pytest.approx(0.18)
    assert seg == pytest.approx([3.0, 0.0, 4.0, 0.0])


def test_a_lone_added_face_gets_the_default_thickness_behind_it():
    face = np.array([[1.0, 1.5, 2.0, 1.5]])  # normal (0, 1); the room lies on that side
    (seg, t), = pair_added(face, ["A"], {"A": shapely.box(0, 1.5, 4, 3)}, np.zeros((0, 4)), np.zeros(0), CFG)  # fmt: skip
    assert t == pytest.approx(CFG.added_thickness_m)
    assert seg[[1, 3]] == pytest.approx([1.45, 1.45])  # behind the face, away from the room


def test_doors_seen_from_both_sides_are_one_door_on_the_walls_centreline():
    centrelines = np.array([[0.0, 0.0, 4.0, 0.0], [5.0, 0.0, 9.0, 0.0], [0.0, 0.0, 0.0, 3.0]])
    rooms = {
        "a": SimpleNamespace(in_plan=True, doors=np.array([[2.0, 0.08, 2.9, 0.08]]), closed_plan_doors=()),
        "b": SimpleNamespace(
            in_plan=True, doors=np.array([[2.9, -0.09, 2.0, -0.09]]), closed_plan_doors=(1,)
        ),
        "c": SimpleNamespace(in_plan=False, doors=np.array([[9.0, 9.0, 9.0, 10.0]]), closed_plan_doors=()),
    }
    floor = SimpleNamespace(
        rooms=rooms,
        plan_doors=np.array([[4.0, 0.0, 5.0, 0.0], [0.0, 1.0, 0.0, 2.0], [2.1, 0.0, 2.9, 0.0]]),
        centrelines=centrelines,
        thickness=SimpleNamespace(thickness_m=np.array([0.16, 0.16, 0.2])),
    )
    feats = floor_doors(floor)
    got = [(f["properties"]["source"], f["properties"]["rooms"], f["properties"]["wall_id"]) for f in feats]
    # the seen door (one, both rooms), the plan's door in the gap (the nearer wall holds it); the plan's
    # door b showed closed and the plan's door under the seen one are not repeated
    assert got == [("observed", ["a", "b"], 0), ("plan", [], 0)]
    seen = np.asarray(feats[0]["geometry"]["coordinates"])
    assert seen[:, 1] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert sorted(seen[:, 0]) == pytest.approx([2.0, 2.9])
    assert host_wall(np.array([0.1, 1.0, 0.1, 2.0]), centrelines, np.array([0.16, 0.16, 0.2])) == 2


# --------------------------------------------------------------------------------------------------- DXF


def test_dxf_layers_hold_the_known_entity_counts(tmp_path):
    floor = two_rooms()
    counts = dxf.write(floor, tmp_path / "floor.dxf")
    doc = ezdxf.readfile(tmp_path / "floor.dxf")
    auditor = doc.audit()
    assert len(auditor.errors) == 0
    assert doc.dxfversion == "AC1024" and doc.header["$INSUNITS"] == 6
    read = {}
    for e in doc.modelspace():
        read[e.dxf.layer] = read.get(e.dxf.layer, 0) + 1
    # A-WALL: bottom, left, right whole; the top cut by the removed metre, the partition by its door
    expected = {
        "A-WALL": 7,
        "A-WALL-NEWW": 1,
        "A-WALL-DEMO": 1,
        "A-DOOR": 2,
        "A-AREA-IDEN": 2,
        "A-ANNO-CHNG": 8,
        "I-SCAN": 6,
    }
    assert read == expected and counts == expected
    outlines = [e for e in doc.modelspace().query("LWPOLYLINE[layer=='A-WALL']")]
    assert all(e.closed for e in outlines)
    areas = sorted(round(shapely.Polygon(e.get_points("xy")).area, 4) for e in outlines)
    # partition pieces 1.0 and 1.1 m at 0.1 m; top pieces 5 and 2 m at 0.2 m; three whole 0.2 m walls
    assert areas == pytest.approx(sorted([0.1, 0.11, 1.0, 0.4, 1.6, 0.6, 0.6]))
    texts = [e.text for e in doc.modelspace().query("MTEXT[layer=='A-AREA-IDEN']")]
    assert any("A (101)" in t and "10.78 m²" in t for t in texts)


def test_dxf_bytes_are_the_same_for_the_same_floor(tmp_path):
    dxf.write(two_rooms(), tmp_path / "a.dxf")
    dxf.write(two_rooms(), tmp_path / "b.dxf")
    assert (tmp_path / "a.dxf").read_bytes() == (tmp_path / "b.dxf").read_bytes()


# --------------------------------------------------------------------------------------------------- IFC


def test_ifc_counts_thickness_and_relations(tmp_path):
    floor = two_rooms()
    path = tmp_path / "floor.ifc"
    counts = ifc.write(floor, path, CFG.timestamp, CFG.door_height_m)
    assert counts == {"Wall": 6, "Space": 2, "Door": 1, "OpeningElement": 1}
    assert ifc.validate(path) == []
    f = ifcopenshell.open(str(path))
    assert f.schema == "IFC4"
    for kind in ("IfcProject", "IfcSite", "IfcBuilding", "IfcBuildingStorey"):
        assert len(f.by_type(kind)) == 1
    thick = ifc.wall_thicknesses(path)
    for wall in [*floor.walls, *floor.added]:
        assert thick[ifc.guid(wall.key)] == pytest.approx(wall.thickness_m, abs=1e-3)
    usage = f.by_type("IfcMaterialLayerSetUsage")[0]
    assert usage.LayerSetDirection == "AXIS2" and usage.DirectionSense == "POSITIVE"
    for w in f.by_type("IfcWall"):
        assert w.PredefinedType == "STANDARD"
        reps = {r.RepresentationIdentifier: r for r in w.Representation.Representations}
        assert set(reps) == {"Axis", "Body"} and reps["Body"].RepresentationType == "SweptSolid"
    (void,) = f.by_type("IfcRelVoidsElement")
    (fill,) = f.by_type("IfcRelFillsElement")
    assert void.RelatingBuildingElement.GlobalId == ifc.guid("wall:4")
    assert fill.RelatingOpeningElement == void.RelatedOpeningElement
    assert fill.RelatedBuildingElement.is_a("IfcDoor")
    assert fill.RelatedBuildingElement.OverallWidth == pytest.approx(0.9)
    spaces = {s.Name: s.LongName for s in f.by_type("IfcSpace")}
    assert spaces == {"A": "101", "B": "R2"}
    status = {}
    for rel in f.by_type("IfcRelDefinesByProperties"):
        pset = rel.RelatingPropertyDefinition
        if pset.Name == "Pset_WallCommon":
            for p in pset.HasProperties:
                if p.Name == "Status":
                    status[rel.RelatedObjects[0].GlobalId] = p.NominalValue.wrappedValue
    assert sorted(status.values()) == ["EXISTING"] * 5 + ["NEW"]


def test_ifc_bytes_are_the_same_for_the_same_floor(tmp_path):
    ifc.write(two_rooms(), tmp_path / "a.ifc", CFG.timestamp, 2.0)
    ifc.write(two_rooms(), tmp_path / "b.ifc", CFG.timestamp, 2.0)
    a = (tmp_path / "a.ifc").read_bytes()
    assert a == (tmp_path / "b.ifc").read_bytes()
    assert CFG.timestamp.encode() in a
    guids = [e.GlobalId for e in ifcopenshell.open(str(tmp_path / "a.ifc")).by_type("IfcRoot")]
    assert len(guids) == len(set(guids))


# -------------------------------------------------------------------------------------------------- mesh


def test_every_mesh_part_is_a_closed_box_of_the_right_volume(tmp_path):
    import open3d as o3d

    floor = two_rooms()
    path = tmp_path / "floor.ply"
    counts = mesh.write(floor, path, 0.1, 2.0)
    # 7 standing wall pieces, the added wall, the lintel over the door, two slabs
    assert counts == {"wall_boxes": 7, "added_boxes": 1, "lintels": 1, "slabs": 2}
    assert mesh.watertight_components(path) == (11, 11)
    whole = o3d.io.read_triangle_mesh(str(path))
    volume = 0.0
    for v, t, _ in mesh.build(floor, 0.1, 2.0)[0]:
        part = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
        volume += part.get_volume()
    walls = 0.2 * 2.5 * (8 + 7 + 3 + 3) + 0.1 * 2.5 * 2.1 + 0.08 * 2.5 * 1.0 + 0.1 * 0.5 * 0.9
    slabs = 0.1 * (3.85 * 2.8 + 3.85 * 2.8)
    assert volume == pytest.approx(walls + slabs, rel=1e-9)
    assert len(whole.triangles) == 9 * 12 + 2 * (2 * 2 + 2 * 4)


def test_a_slab_with_a_hole_is_closed():
    ring = shapely.box(0, 0, 4, 3).difference(shapely.box(1, 1, 2, 2))
    v, t = mesh.slab(ring, -0.1, 0.0)
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(t))
    assert m.is_watertight()
    assert m.get_volume() == pytest.approx(0.1 * 11.0)


def test_mesh_bytes_are_the_same_for_the_same_floor(tmp_path):
    mesh.write(two_rooms(), tmp_path / "a.ply", 0.1, 2.0)
    mesh.write(two_rooms(), tmp_path / "b.ply", 0.1, 2.0)
    assert (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()


# ------------------------------------------------------------------------------------------ room clouds


def test_voxel_reduce_keeps_one_mean_point_per_voxel():
    pts = np.array([[0.01, 0.01, 0.01], [0.03, 0.01, 0.01], [0.5, 0.5, 0.5], [0.51, 0.52, 0.53]])
    cols = np.array([[0, 0, 0], [100, 100, 100], [10, 20, 30], [30, 40, 50]], dtype=np.uint8)
    out, c = clouds.voxel_reduce(pts, cols, 0.1)
    assert out == pytest.approx(np.array([[0.02, 0.01, 0.01], [0.505, 0.51, 0.515]]))
    assert c.tolist() == [[50, 50, 50], [20, 30, 40]]


def test_voxel_index_is_uniques_row_order_also_with_negative_and_huge_coordinates():
    rng = np.random.default_rng(5)
    keys = rng.integers(-40, 40, size=(5000, 3))
    keys[:7] = [[-40, 39, -40], [39, -40, 39], [0, 0, 0], [0, 0, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1]]
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    got_inverse, got_counts = clouds.voxel_index(keys)
    assert np.array_equal(got_inverse, inverse.reshape(-1)) and np.array_equal(got_counts, counts)
    huge = np.array([[2**40, 0, 0], [-(2**40), 5, 0], [0, 2**40, -(2**40)], [2**40, 0, 0]])  # cannot pack
    _, inverse, counts = np.unique(huge, axis=0, return_inverse=True, return_counts=True)
    got_inverse, got_counts = clouds.voxel_index(huge)
    assert np.array_equal(got_inverse, inverse.reshape(-1)) and list(got_counts) == [1, 1, 2]


@pytest.mark.parametrize("source", ["register", "cloud"])
def test_room_cloud_goes_into_the_plan_frame_with_the_floor_at_zero(tmp_path, source):
    levelled = np.array([[1.0, 0.0, -1.2], [0.0, 2.0, 1.3]])
    art.write_ply_points(
        tmp_path / "levelled.ply", levelled, np.array([[1, 2, 3], [4, 5, 6]], dtype=np.uint8)
    )
    transform = np.eye(4)
    transform[:3, 3] = [0.5, -0.5, 1.2]  # a given cloud: its walls are 0.5 m left and 0.5 m up of these
    levelling = {"transform": transform.tolist(), "floor_z_m": -1.2, "source": source}
    turn = np.array([[0.0, -1.0, 10.0], [1.0, 0.0, 20.0], [0.0, 0.0, 1.0]])  # 90 degrees, then (10, 20)
    cloud = clouds.room_cloud(tmp_path / "levelled.ply", levelling, turn)
    xy = levelled[:, :2] - ([0.5, -0.5] if source == "cloud" else [0.0, 0.0])
    expect = np.column_stack([10.0 - xy[:, 1], 20.0 + xy[:, 0], [0.0, 2.5]])
    assert cloud.points == pytest.approx(expect)
    assert cloud.frame == "plan" and cloud.colors.tolist() == [[1, 2, 3], [4, 5, 6]]
    own = clouds.room_cloud(tmp_path / "levelled.ply", levelling, None, "no plan room")
    assert own.frame == "own (not placed: no plan room)" and own.points[:, 2] == pytest.approx([0.0, 2.5])
    clouds.write_cloud(tmp_path / "cloud.ply", cloud.points, cloud.colors)
    back = art.read_cloud(tmp_path / "cloud.ply")
    assert back.points == pytest.approx(expect, abs=1e-5)


# ------------------------------------------------------------------------------------- floor.geojson in


def _line(seg, **props):
    return {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": [seg[:2], seg[2:]]},
        "properties": props,
    }


def test_read_floor_puts_changes_on_their_walls_and_marks_demolished(tmp_path):
    feats = [
        {
            "type": "Feature",
            "geometry": shapely.geometry.mapping(shapely.box(0.1, 0.1, 3.9, 2.9)),
            "properties": {"kind": "room", "id": "A", "room_id": "A", "plan_room": "R1", "area_m2": 10.64},
        },
        _line([0, 0, 4, 0], kind="wall", thickness_m=0.2, origin="plan", rooms=["A", None]),
        _line([0, 3, 4, 3], kind="wall", thickness_m=0.2, origin="plan", rooms=[None, "A"]),
        _line([1, 0, 2, 0], kind="door", source="observed", rooms=["A"], wall_id=0),
    ]
    path = tmp_path / "floor.geojson"
    art.write_json(path, {"type": "FeatureCollection", "features": feats})
    marks = [
        ChangeMark(np.array([0.0, 3.05, 3.8, 3.05]), "removed", "A"),
        ChangeMark(np.array([3.0, 0.0, 3.5, 0.0]), "removed", "A"),
    ]
    floor = read_floor(path, {"A": 2.7}, {"R1": "101"}, marks, CFG)
    assert [w.status for w in floor.walls] == ["existing", "demolished"]
    assert [c.wall_id for c in floor.changes] == [1, 0]
    assert floor.rooms[0].label == "101" and floor.walls[0].height_m == 2.7
    from tasks.deliver.floor import standing_pieces

    assert standing_pieces(floor, floor.walls[0]) == [(0.0, 1.0), (2.0, 3.0), (3.5, 4.0)]
    assert standing_pieces(floor, floor.walls[1]) == []


def test_a_wall_without_thickness_is_a_clear_error(tmp_path):
    path = tmp_path / "floor.geojson"
    art.write_json(
        path, {"type": "FeatureCollection", "features": [_line([0, 0, 1, 0], kind="wall", thickness_m=0)]}
    )
    with pytest.raises(art.ArtefactError, match=r"floor.geojson: wall 0 has thickness 0"):
        read_floor(path, {}, {}, [], CFG)


# ---------------------------------------------------------------------------------------------- data/mini


def check_deliverables(work: Path) -> dict:
    """The must-show figures of a finished run's outputs (asserted) and the counts (returned)."""
    out = Path(work) / "outputs"
    geo = json.loads((out / "floor.geojson").read_text())
    assert geo["crs"]["properties"]["name"] == PLAN_CRS_WKT
    assert (out / "floor.prj").read_text() == PLAN_CRS_WKT
    kinds: dict[str, list] = {}
    for feat in geo["features"]:
        kinds.setdefault(feat["properties"]["kind"], []).append(feat["properties"])
    for room in kinds["room"]:
        assert {"id", "plan_room", "area_m2"} <= set(room)
    for wall in kinds["wall"]:
        assert wall["thickness_m"] > 0 and wall["origin"] == "plan" and len(wall["rooms"]) == 2
    for face in kinds["wall_face"]:
        assert face["origin"] in ("observed", "extended", "gap_filled")
    changes = art.read_table(out / "changes.parquet").to_pydict()["kind"]
    doc = ezdxf.readfile(out / "floor.dxf")
    audit = doc.audit()
    assert len(audit.errors) == 0
    layers: dict[str, int] = {}
    for e in doc.modelspace():
        layers[e.dxf.layer] = layers.get(e.dxf.layer, 0) + 1
    assert layers["A-AREA-IDEN"] == len(kinds["room"])
    assert layers["A-DOOR"] == 2 * len(kinds["door"])
    assert layers.get("A-WALL-DEMO", 0) == changes.count("removed")
    assert layers.get("A-ANNO-CHNG", 0) == 2 * len(changes)
    assert layers["A-WALL"] >= len(kinds["wall"]) - changes.count("removed")
    errors = ifc.validate(out / "floor.ifc")
    assert errors == []
    f = ifcopenshell.open(str(out / "floor.ifc"))
    status = {}
    for rel in f.by_type("IfcRelDefinesByProperties"):
        if rel.RelatingPropertyDefinition.Name == "Pset_WallCommon":
            for p in rel.RelatingPropertyDefinition.HasProperties:
                if p.Name == "Status":
                    status[rel.RelatedObjects[0].GlobalId] = p.NominalValue.wrappedValue
    plan_walls = [g for g, s in status.items() if s != "NEW"]
    assert len(plan_walls) == len(kinds["wall"])
    assert len(f.by_type("IfcWall")) == len(status)
    assert layers.get("A-WALL-NEWW", 0) == list(status.values()).count("NEW")
    assert len(f.by_type("IfcSpace")) == len(kinds["room"])
    assert len(f.by_type("IfcDoor")) == len(kinds["door"])
    thick = ifc.wall_thicknesses(out / "floor.ifc")
    for i, wall in enumerate(kinds["wall"]):
        assert thick[ifc.guid(f"wall:{i}")] == pytest.approx(wall["thickness_m"], abs=1e-3)
    components, watertight = mesh.watertight_components(out / "floor.ply")
    assert components == watertight > len(kinds["wall"])
    rooms = sorted(p.name for p in (out / "rooms").iterdir() if (p / "cloud.ply").is_file())
    for rid in rooms:
        cloud = art.read_cloud(out / "rooms" / rid / "cloud.ply")
        assert cloud.colors is not None
        assert abs(float(np.percentile(cloud.points[:, 2], 5))) < 0.05  # the floor at z = 0
    return {
        "dxf_audit_errors": len(audit.errors),
        "dxf_layers": layers,
        "ifc_errors": len(errors),
        "ifc": {k: len(f.by_type(k)) for k in ("IfcWall", "IfcSpace", "IfcDoor", "IfcOpeningElement")},
        "geojson": {k: len(v) for k, v in kinds.items()},
        "mesh_components": components,
        "watertight": watertight,
        "room_clouds": rooms,
    }


@pytest.mark.slow
def test_mini_deliverables(mini_run):
    code, work = mini_run
    assert code == 0
    figures = check_deliverables(work)
    assert figures["room_clouds"] == ["hall", "r1", "r2", "r3", "r4", "r5"]


DETERMINISM_SCRIPT = """
import sys
from pathlib import Path
import numpy as np, shapely
from tasks.deliver import dxf, ifc, mesh
from tasks.deliver.floor import ChangeMark, Door, Floor, Room, Wall
walls = [Wall(f"wall:{i}", np.array(s, dtype=float), 0.2, 2.5, "existing", "plan", ("A", None), i)
         for i, s in enumerate([(0, 0, 4, 0), (4, 0, 4, 3), (4, 3, 0, 3), (0, 3, 0, 0)])]
floor = Floor(walls, [], [Door("door:0", np.array([1.0, 0.0, 1.9, 0.0]), 0, "observed", ("A",))],
              [Room("A", "R1", "101", shapely.box(0.1, 0.1, 3.9, 2.9), 2.5)],
              [ChangeMark(np.array([2.5, 3.0, 3.5, 3.0]), "removed", "A", 2)])
out = Path(sys.argv[1])
dxf.write(floor, out / "floor.dxf")
ifc.write(floor, out / "floor.ifc", "2000-01-01T00:00:00", 2.0)
mesh.write(floor, out / "floor.ply", 0.1, 2.0)
"""


def test_deliverable_bytes_do_not_depend_on_the_process(tmp_path):
    """Two processes with different string hashing (set orders) write the same bytes."""
    import os
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    digests = []
    for seed in ("1", "4"):  # ezdxf 1.4 (before the fix) orders its CLASSES differently under these two
        out = tmp_path / seed
        out.mkdir()
        env = {**os.environ, "PYTHONHASHSEED": seed, "PYTHONPATH": str(repo)}
        subprocess.run([sys.executable, "-c", DETERMINISM_SCRIPT, str(out)], check=True, env=env, cwd=repo)
        digests.append({p.name: art.sha256_file(p) for p in sorted(out.iterdir())})
    assert digests[0] == digests[1] and len(digests[0]) == 3
