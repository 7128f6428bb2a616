"""The miniature survey in data/ end to end, as the README's first command runs it, with accuracy
thresholds against its truth/ (a synthetic survey: every answer is known). The run itself is the
session fixture `mini_run` (tests/conftest.py), which the register tests read too."""

import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from flows.cli import main

pytestmark = pytest.mark.slow

MINI = Path(__file__).resolve().parents[1] / "data" / "mini"


def test_every_stage_of_every_room_completes(mini_run):
    code, work = mini_run
    assert code == 0
    for room in ("r1", "r2", "r3", "r4", "r5", "hall"):
        for name in ("walls.parquet", "plan.geojson", "model.ply", "preview.png"):
            assert (work / "outputs" / "rooms" / room / name).is_file(), (room, name)
        walls = pq.read_table(work / "outputs" / "rooms" / room / "walls.parquet")
        assert walls.num_rows >= 4, room


def test_room_models_against_truth(mini_run):
    _, work = mini_run
    metrics = json.loads((work / "outputs" / "metrics.json").read_text())
    rooms = {r["room"]: r for r in metrics["rooms"]}
    # the TLS-like room: millimetre data, the thesis got 7 mm on TLS
    assert rooms["r5"]["accuracy_mean_m"] < 0.005
    assert rooms["r5"]["correctness"] > 0.95
    for room in ("r1", "r2", "r3", "r4"):  # Kinect v1 rooms registered by SfM + scale from depth
        assert rooms[room]["ate_2d_rmse_m"] < 0.10, room
        assert abs(rooms[room]["scale_error_pct"]) < 2.0, room
        assert rooms[room]["completeness"] > 0.95 and rooms[room]["correctness"] > 0.95, room
        assert rooms[room]["corner_f1"] >= 0.9, room
        assert rooms[room]["accuracy_mean_m"] < 0.015, room  # issue 4's target; the thesis: 30 mm
    # the hallway: SfM fails and the drifting IMU track places its frames (issue 6's fallback); its walls
    # are seen from a metre away and never reach the slice top
    assert rooms["hall"]["completeness"] > 0.9 and rooms["hall"]["correctness"] > 0.9
    assert metrics["summary"]["mean_completeness"] > 0.95


def test_rerun_recomputes_nothing(mini_run, capsys):
    _, work = mini_run
    capsys.readouterr()
    assert main(["run", str(MINI), "--work", str(work)]) == 0
    out = capsys.readouterr()
    summary = next(line for line in out.out.splitlines() if "stage runs:" in line)
    total = int(summary.split()[0])
    assert f"{total} stage runs: {total} cached" in summary
    assert "nothing to compute" in out.err
    shutil.rmtree(work / "outputs" / "rooms" / "r1")  # a deleted deliverable comes back from the cache
    assert main(["-q", "run", str(MINI), "--work", str(work)]) == 0
    assert (work / "outputs" / "rooms" / "r1" / "walls.parquet").is_file()


def test_floor_index_fans_in_every_room_and_follows_a_targeted_rerun(mini_run, capsys):
    """The building-after stage reads every room: rooms.parquet lists all of them; `rerun --stage walls
    --room r2` recomputes r2's walls, which writes the same bytes, so the index stays current (its key is a
    content key), and nothing of r1 is touched."""
    _, work = mini_run
    rooms = pq.read_table(work / "outputs" / "rooms.parquet").to_pylist()
    assert [r["room_id"] for r in rooms] == ["r1", "r2", "r3", "r4", "r5", "hall"]
    for row in rooms:
        assert row["walls"] >= 4 and row["error"] is None, row
        assert "walls" in row["stages_done"] and row["frame"]
    assert rooms[0]["closed"] and rooms[0]["area_m2"] > 5
    capsys.readouterr()
    assert main(["rerun", str(MINI), "--work", str(work), "--stage", "walls", "--room", "r2"]) == 0
    states = {
        tuple(line.split()[:2]): line.split()[2]
        for line in capsys.readouterr().out.splitlines()
        if len(line.split()) >= 3 and line.split()[0] in ("r1", "r2", "_building")
    }
    assert states[("r2", "walls")] == "computed"
    assert states[("_building", "floor_index")] in ("cached", "stored")
    assert states.get(("r1", "walls"), "not run") != "computed"
    assert len([p for p in (work / "cache" / "r1" / "walls").iterdir() if not p.name.startswith(".")]) == 1
    rerun = pq.read_table(work / "outputs" / "rooms.parquet").to_pylist()
    assert [r["room_id"] for r in rerun] == [r["room_id"] for r in rooms]
    # the partial run's report and metrics still hold every room, each from the run that last computed it
    page = (work / "outputs" / "report.html").read_text()
    assert all(f'id="room-{r["room_id"]}"' in page for r in rooms)
    metrics = json.loads((work / "outputs" / "metrics.json").read_text())
    assert sorted(r["room"] for r in metrics["rooms"]) == sorted(r["room_id"] for r in rooms)
    manifest = json.loads((work / "outputs" / "manifest.json").read_text())
    assert set(manifest["rooms"]) == {r["room_id"] for r in rooms}
    assert all(entry["run_id"] and entry["state"] == "done" for entry in manifest["rooms"].values())
