"""Known answers for change detection: added and removed walls, a wall never seen (unknown, not removed),
a moved door, and the room-level changes (split, merged, enlarged)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from shapely.geometry import box

from tasks.changes.config import ChangesConfig
from tasks.changes.detect import ADDED, REMOVED, UNKNOWN, PlacedRoom, added_walls, removed_walls, room_changes
from tasks.fuse.openings import Coverage
from tasks.fuse.truth import change_scores

CFG = ChangesConfig()
# a 6 x 4 room (faces), walls 0.2 thick: centrelines 0.1 outside the faces
CENTRE = np.array(
    [[-0.1, -0.1, 6.1, -0.1], [6.1, -0.1, 6.1, 4.1], [6.1, 4.1, -0.1, 4.1], [-0.1, 4.1, -0.1, -0.1]]
)
THICK = np.full(4, 0.2)
FACES = np.array([[0, 0, 6, 0], [6, 0, 6, 4], [6, 4, 0, 4], [0, 4, 0, 0]], dtype=float)


def seen_everywhere(lo=(-1.0, -1.0), hi=(7.0, 5.0), cell=0.1) -> Coverage:
    shape = (int((hi[1] - lo[1]) / cell), int((hi[0] - lo[0]) / cell))
    return Coverage(lo, cell, np.ones(shape, dtype=bool))


def room(walls: np.ndarray, coverage=None, doors=None, polygon=None, closed=()) -> PlacedRoom:
    return PlacedRoom(
        "r1",
        walls,
        np.ones(len(walls)),
        np.zeros((0, 4)) if doors is None else doors,
        coverage,
        "R1",
        box(0, 0, 6, 4) if polygon is None else polygon,
        closed,
    )


def test_a_new_partition_is_added_and_nothing_else() -> None:
    walls = np.vstack([FACES, [[0, 2.0, 2.0, 2.0], [2.0, 2.0, 2.0, 2.1], [2.0, 2.1, 0, 2.1]]])
    got = added_walls(room(walls, seen_everywhere()), CENTRE, THICK, np.zeros((0, 4)), CFG)
    assert [c.kind for c in got] == [ADDED, ADDED]
    assert min(got[0].x0, got[0].x1) == pytest.approx(0.1)  # from the wall's buffer (t/2 + margin) on
    assert all(c.distance_m > 1.0 for c in got)


def test_a_plan_wall_without_support_is_removed_where_seen_and_unknown_where_never_seen() -> None:
    plan = np.vstack([CENTRE, [[-0.1, 2.0, 3.0, 2.0]]])  # a partition the plan draws, gone in the room
    thick = np.append(THICK, 0.1)
    seen = removed_walls(plan, thick, [room(FACES, seen_everywhere())], CFG)
    assert [(c.kind, round(c.x1 - c.x0, 1)) for c in seen] == [(REMOVED, pytest.approx(3.0, abs=0.31))]
    never = Coverage((4.0, 0.0), 0.1, np.ones((40, 20), dtype=bool))  # the camera only saw x in 4..6
    unseen = removed_walls(plan, thick, [room(FACES, never)], CFG)
    assert [c.kind for c in unseen] == [UNKNOWN]


def test_a_moved_door_is_a_removed_gap_plus_an_added_one() -> None:
    """The plan has a door in the south wall at x 1..2; the room has it at x 4..5 and its wall closed
    at 1..2 (its capture shows that gap closed)."""
    plan = np.array([[-0.1, -0.1, 1.0, -0.1], [2.0, -0.1, 6.1, -0.1], *CENTRE[1:]])
    plan_doors = np.array([[1.0, -0.1, 2.0, -0.1]])
    model_doors = np.array([[4.0, 0.0, 5.0, 0.0]])
    thick = np.full(len(plan), 0.2)
    r = room(FACES, seen_everywhere(), doors=model_doors, closed=(0,))
    added = added_walls(r, plan, thick, plan_doors, CFG)
    removed = removed_walls(plan, thick, [r], CFG)
    assert [(c.kind, round(min(c.x0, c.x1), 1), round(max(c.x0, c.x1), 1)) for c in added] == [
        (ADDED, 1.0, 2.0)
    ]
    assert [c.kind for c in removed] == [REMOVED]
    assert 3.9 < min(removed[0].x0, removed[0].x1) < 4.3 and 4.7 < max(removed[0].x0, removed[0].x1) < 5.1
    open_gap = room(FACES, seen_everywhere(), doors=model_doors)  # the gap not shown closed: no claim
    assert added_walls(open_gap, plan, thick, plan_doors, CFG) == []


def test_a_door_seen_from_one_side_opens_the_wall_the_other_side_models_across_it() -> None:
    """The corridor models its wall across 102's new door near the ceiling (no door found in it); 102
    saw the door: the plan wall there is removed, cut by 102's door from both rooms' walls."""
    plan = np.array([[0.0, 0.0, 6.0, 0.0]])  # the wall between them, 0.2 thick
    thick = np.array([0.2])
    corridor = PlacedRoom(
        "hall", np.array([[0.0, -0.1, 6.0, -0.1]]), np.ones(1), np.zeros((0, 4)), seen_everywhere(), "C"
    )
    room_102 = PlacedRoom(
        "r2",
        np.array([[0.0, 0.1, 6.0, 0.1]]),
        np.ones(1),
        np.array([[2.0, 0.1, 2.9, 0.1]]),  # its door, on its own face
        seen_everywhere(),
        "R",
    )
    got = removed_walls(plan, thick, [corridor, room_102], CFG)
    assert [c.kind for c in got] == [REMOVED]
    assert min(got[0].x0, got[0].x1) == pytest.approx(2.0, abs=0.06)
    assert max(got[0].x0, got[0].x1) == pytest.approx(2.9, abs=0.06)
    assert removed_walls(plan, thick, [corridor], CFG) == []  # the corridor alone: no claim


def test_an_added_wall_stands_in_a_plan_rooms_free_space() -> None:
    """The plan's wall lines leave a 0.4 m gap at a junction (a vectorization gap, the drawn wall is
    there): the room's wall along it is no new wall; a partition inside the room is."""
    plan = np.array([[-0.1, -0.1, 2.5, -0.1], [2.9, -0.1, 6.1, -0.1], *CENTRE[1:]])
    thick = np.full(len(plan), 0.2)
    walls = np.vstack([FACES, [[3.0, 0.0, 3.0, 2.0]]])
    r = room(walls, seen_everywhere())
    everything = added_walls(r, plan, thick, np.zeros((0, 4)), CFG)
    assert len(everything) == 2  # without the plan's rooms: the junction's piece too
    got = added_walls(r, plan, thick, np.zeros((0, 4)), CFG, [box(0, 0, 6, 4)])
    assert len(got) == 1 and got[0].x0 == pytest.approx(3.0) and got[0].x1 == pytest.approx(3.0)


def test_fuse_s_wall_evidence_decides_removed_standing_and_unknown() -> None:
    """With fuse's evidence, a plan partition the model lacks is removed only where a crisp capture saw
    through it; where a capture shows it standing (the model missed it) it is no change; elsewhere
    unknown, however much of the floor beside it the capture saw."""
    plan = np.vstack([CENTRE, [[-0.1, 2.0, 3.0, 2.0]]])  # the partition, 3.1 m along its centreline
    thick = np.append(THICK, 0.1)
    r = room(FACES, seen_everywhere())
    got = removed_walls(plan, thick, [r], CFG, standing={4: [(2.0, 3.1)]}, seen_through={4: [(0.0, 1.2)]})
    assert [(c.kind, round(min(c.x0, c.x1), 1), round(max(c.x0, c.x1), 1)) for c in got] == [
        (REMOVED, 0.2, 1.1),  # from where the west wall stops supporting it
        (UNKNOWN, 1.1, 1.9),
    ]


def test_no_added_wall_from_a_smeared_capture_or_without_points_below_the_ceiling() -> None:
    """A partition in a crisp capture whose cloud shows it standing is added; the same wall from a smeared
    capture (frames centimetres apart: ghosts) or with nothing standing below the ceiling (a lamp the
    wall model read near the ceiling) is not."""
    walls = np.vstack([FACES, [[3.0, 0.5, 3.0, 3.5]]])
    standing = Coverage((2.9, 0.4), 0.05, np.ones((63, 4), dtype=bool))  # x 2.9..3.1, y 0.4..3.55
    nothing = Coverage((2.9, 0.4), 0.05, np.zeros((63, 4), dtype=bool))
    plan_rooms = [box(0, 0, 6, 4)]
    for crisp, surfaces, expected in ((True, standing, 1), (False, standing, 0), (True, nothing, 0)):
        r = PlacedRoom(
            "r1",
            walls,
            np.ones(len(walls)),
            np.zeros((0, 4)),
            seen_everywhere(),
            "R1",
            box(0, 0, 6, 4),
            (),
            surfaces,
            crisp,
        )
        assert len(added_walls(r, CENTRE, THICK, np.zeros((0, 4)), CFG, plan_rooms)) == expected


def test_a_split_room_a_merged_room_and_an_enlarged_room() -> None:
    plan = {"A": box(0, 0, 6, 4), "B": box(6.2, 0, 10, 4)}
    west = PlacedRoom("w", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, 0, 2.9, 4))
    east = PlacedRoom("e", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(3.0, 0, 6, 4))
    split = room_changes([west, east], plan, CFG)
    assert [(c.kind, c.room_ids, c.plan_rooms) for c in split] == [("room_split", ("e", "w"), ("A",))]
    merged = PlacedRoom("m", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, 0, 10, 4))
    kinds = {c.kind: c for c in room_changes([merged], plan, CFG)}
    assert set(kinds) == {"rooms_merged"} and kinds["rooms_merged"].plan_rooms == ("A", "B")
    big = PlacedRoom("g", np.zeros((0, 4)), np.zeros(0), np.zeros((0, 4)), None, "A", box(0, -1.5, 6, 4))
    kinds = {c.kind: c for c in room_changes([big], plan, CFG)}
    assert set(kinds) == {"room_enlarged"} and kinds["room_enlarged"].share == pytest.approx(
        1.4 * 6 / 24, abs=0.02
    )


def test_a_split_by_a_new_wall_in_one_capture() -> None:
    walls = np.vstack([FACES, [[3.0, 0.0, 3.0, 4.0]]])
    one = PlacedRoom("s", walls, np.ones(5), np.zeros((0, 4)), None, "A", box(0, 0, 6, 4))
    got = room_changes([one], {"A": box(0, 0, 6, 4)}, CFG)
    assert [c.kind for c in got] == ["room_split"] and got[0].extra["parts"] == 2


def test_change_scores() -> None:
    truth = [
        {"x0": 0, "y0": 0, "x1": 2, "y1": 0, "kind": ADDED},
        {"x0": 5, "y0": 5, "x1": 6, "y1": 5, "kind": REMOVED},
    ]
    pred = [
        {"x0": 0.1, "y0": 0.05, "x1": 1.9, "y1": 0.05, "kind": ADDED},
        {"x0": 9, "y0": 9, "x1": 10, "y1": 9, "kind": ADDED},
        {"x0": 5, "y0": 5, "x1": 6, "y1": 5, "kind": UNKNOWN},
    ]
    got = change_scores(pred, truth)
    assert got["precision"] == pytest.approx(0.5) and got["recall"] == pytest.approx(0.5)


def test_fuse_and_changes_stage_bodies_on_a_two_room_plan(tmp_path) -> None:
    """The stage bodies on small artefacts: a room given in its own frame is placed by its label, a room
    whose walls are empty is reported, and the changes stage finds the partition added in the first."""
    import json
    import math

    from tasks import artefacts as art
    from tasks.changes.stage import run as run_changes
    from tasks.context import StageContext
    from tasks.fuse.config import FuseConfig
    from tasks.fuse.register2d import Placement
    from tasks.fuse.stage import run as run_fuse

    def result(folder, room, stage, manifest=None):
        files = {p.name: art.sha256_file(p) for p in folder.iterdir() if p.name != "manifest.json"}
        art.write_json(folder / "manifest.json", manifest or {})
        return art.StageResult(room, stage, "k", str(folder), files, art.hash_json(files))

    plan_dir = tmp_path / "plan"
    plan_dir.mkdir()
    art.write_table(plan_dir / "plan_walls.parquet", art.segments_table(CENTRE, thickness_m=THICK))
    feats = [
        {
            "type": "Feature",
            "geometry": json.loads(json.dumps(box(0, 0, 6, 4).__geo_interface__)),
            "properties": {"room_id": "R1", "label": "101"},
        }
    ]
    art.write_geojson(plan_dir / "rooms.geojson", feats)
    plan = result(plan_dir, art.BUILDING, "plan")
    truth = Placement(math.radians(40.0), (3.0, -1.0))
    walls = np.vstack([FACES, [[0, 2.0, 2.0, 2.0], [2.0, 2.0, 2.0, 2.1], [2.0, 2.1, 0, 2.1]]])
    ends = (walls.reshape(-1, 2) - np.asarray(truth.t)) @ truth.rotation
    rooms = {}
    for rid, w in (("a", ends.reshape(-1, 4)), ("b", np.zeros((0, 4)))):
        folder = tmp_path / rid
        folder.mkdir()
        art.write_table(
            folder / "walls.parquet",
            art.segments_table(
                w, height=np.full(len(w), 2.5), origin=["observed"] * len(w), support=np.ones(len(w))
            ),
            art.WALLS_SCHEMA,
        )
        rooms[rid] = {"walls": result(folder, rid, "walls")}
    params = {"rooms": [{"id": "a", "plan_room": "101"}, {"id": "b", "plan_room": "102"}]}
    ctx = StageContext(art.BUILDING, {"plan": plan}, {}, {}, lambda m: None, params=params, rooms=rooms)
    out = tmp_path / "fuse"
    out.mkdir()
    report = run_fuse(ctx, FuseConfig(), out)
    assert report["metrics"]["placed"] == 1 and "walls are empty" in report["metrics"]["not_placed"]["b"]
    fused = result(out, art.BUILDING, "fuse", report)
    placed, _ = art.read_segments(fused.file("a.walls.parquet"))
    assert np.abs(placed - walls).max() < 1e-6 or report["metrics"]["fit_scores"]["a"] == pytest.approx(1.0)
    ctx2 = StageContext(art.BUILDING, {"plan": plan, "fuse": fused}, {}, {}, lambda m: None)
    out2 = tmp_path / "changes"
    out2.mkdir()
    metrics = run_changes(ctx2, CFG, out2)["metrics"]
    assert metrics["added"] == 2 and metrics["removed"] == 0
    assert {"changes.parquet", "changes.geojson", "changes.png"} <= {p.name for p in out2.iterdir()}


def test_furniture_the_wall_model_took_for_a_wall_is_no_added_wall() -> None:
    """A wardrobe's front, 0.46 m before the east wall (x = 5.54, y 2..4), stands from the floor to 2.1 m
    under a 3 m ceiling: it stands in the room's free space like a partition, but only a wall reaches up
    to just below the ceiling (fuse's tops grid)."""
    walls = np.vstack([FACES, [[5.54, 2.0, 5.54, 4.0]]])
    everywhere = seen_everywhere(cell=0.05)
    below_ceiling = Coverage((-1.0, -1.0), 0.05, np.zeros((120, 160), dtype=bool))
    wall_of = replace(room(walls, seen_everywhere()), surfaces=everywhere, tops=everywhere)
    wardrobe = replace(wall_of, tops=below_ceiling)
    assert [c.kind for c in added_walls(wall_of, CENTRE, THICK, np.zeros((0, 4)), CFG)] == [ADDED]
    assert added_walls(wardrobe, CENTRE, THICK, np.zeros((0, 4)), CFG) == []


def test_a_room_claims_added_walls_only_beside_its_own_polygon() -> None:
    """A corridor (the 6 x 4 room) saw through a door a wall standing in the next plan room (y = 6): that
    room's to claim, not the corridor's; the corridor's own partition (y = 2) is claimed."""
    walls = np.vstack([FACES, [[0.5, 2.0, 2.5, 2.0], [1.0, 6.0, 3.0, 6.0]]])
    rooms = [box(0, 0, 6, 4), box(0, 4.2, 6, 8)]
    r = room(walls, seen_everywhere())
    anywhere = added_walls(r, CENTRE, THICK, np.zeros((0, 4)), CFG, rooms)
    assert sorted(round(c.y0, 1) for c in anywhere) == [2.0, 6.0]
    own = added_walls(r, CENTRE, THICK, np.zeros((0, 4)), CFG, rooms, box(0, 0, 6, 4))
    assert [round(c.y0, 1) for c in own] == [2.0]
