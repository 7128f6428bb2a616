"""Stages computed while Prefect's server starts (flows/ahead.py): the same inputs, key and bytes as the
flow's, and the flow reports them computed without running them again."""

from pathlib import Path

import numpy as np
import pytest

from flows import ahead as aheadmod
from flows import planning
from flows.cli import main
from tasks import config as cfgmod
from tasks.artefacts import BUILDING, ArtefactStore
from tests.captures import tiny_survey

MINI = Path(__file__).resolve().parents[1] / "data" / "mini"


def _plan(req: planning.RunRequest) -> planning.SurveyPlan:
    survey = cfgmod.load_survey(Path(req.survey))
    return planning.plan_survey(
        req, cfgmod.load_config([], []), survey, cfgmod.load_sensor_profile(survey.sensor)
    )


def test_a_room_stage_that_reads_the_plan_waits_for_a_current_plan(tmp_path):
    """The fault an earlier early start had: a room's register ran without the building's plan (which
    the flow passes it), so under another key, and the corridor came out 24 cm off. The inputs come
    from the run's own plan, building stages included, and all of them must be current."""
    plan = _plan(planning.RunRequest(str(MINI), str(tmp_path / "w")))
    [register] = [item for item in plan.rooms["hall"] if item.call.stage == "register"]
    assert register.upstream["plan"] == (BUILDING, "plan")
    assert "plan" in register.optional  # the flow may run it without: so must not ahead
    [ingest] = [item for item in plan.rooms["hall"] if item.call.stage == "ingest"]
    found = {ref: object() for ref in register.upstream.values()}
    assert set(planning.ready_inputs(register, found)) == set(register.upstream)
    del found[(BUILDING, "plan")]
    assert planning.ready_inputs(register, found) is None
    assert planning.ready_inputs(ingest, {}) == {}
    assert aheadmod.last_seconds(ingest) is None  # never run: a cold run's stages are the flow's


@pytest.mark.slow
def test_stages_computed_ahead_are_the_flows_and_get_no_task_run(
    tmp_path, capsys, prefect_harness, monkeypatch
):
    survey = tiny_survey(tmp_path / "s", np.random.default_rng(3))
    work = tmp_path / "w"
    assert main(["run", str(survey), "--work", str(work)]) == 0
    capsys.readouterr()
    store = ArtefactStore(work)
    before = {room: store.latest(room, "walls") for room in ("a", "b")}

    # a rerun forcing a's preprocess and b's walls: a's walls is then a store hit (preprocess wrote the same
    # bytes), which is not a stage computed ahead
    req = planning.RunRequest(str(survey), str(work), force=(("a", "preprocess"), ("b", "walls")))
    early = aheadmod.Ahead(req)
    early.start()
    early.wait(120)
    done = early.finish()
    assert set(done) == {("a", "preprocess"), ("b", "walls")}
    assert all(seconds > 0 for seconds in done.values())

    from flows import pipeline

    submitted = []
    task_for = pipeline._task_for
    monkeypatch.setattr(pipeline, "_task_for", lambda item: submitted.append(item.ref) or task_for(item))
    rows = pipeline.run_survey(req, ahead=done)
    states = {(r.room, r.stage): r.state for r in rows}
    assert states[("a", "preprocess")] == states[("b", "walls")] == "computed"
    assert states[("a", "walls")] == states[("b", "preprocess")] == "cached"
    assert not [ref for ref in submitted if ref[0] in ("a", "b")]  # no room computed a second time
    for room, result in before.items():  # deterministic: the same bytes under the same key
        after = store.latest(room, "walls")
        assert (after.key, after.content_hash) == (result.key, result.content_hash)
    assert (
        store.latest("b", "walls").manifest["run_id"] == req.run_id
    )  # written by this run, ahead of the flow
