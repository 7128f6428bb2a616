"""Prefect flows over the artefact store.

`building_flow` runs the building's stages that the rooms read (calibrate, plan), maps `room_task` over
the rooms concurrently (a room is a partition: rooms are independent until fusion; its stages run one
after another inside its task, as nested task runs), then runs the building-after stages (fan-in) on
every room's results, a failed room passed to them as failed. Each stage is one Prefect task whose cache
key is the content address of its run (input content hashes + its config sections + its code version),
with results persisted under the work dir, so Prefect's logs and UI show cache hits. A stage that is
current before the run starts (every input current, a verified artefact for its key) is read from the
store and makes no task run. The artefact store stays the source of truth: a key whose artefact folder is missing
or fails its hashes has its Prefect record dropped and recomputes.

Prefect's settings (offline, quiet, patient start-up) are the caller's: `flows.prefect_env.apply()`
before this module is imported (the CLI does it).
"""

from __future__ import annotations

import importlib
import logging
from pathlib import Path
from typing import Any

from prefect import flow, task
from prefect.cache_policies import NO_CACHE
from prefect.futures import PrefectFuture, wait

from flows.planning import (
    Executed,
    FanIn,
    PlannedStage,
    RunRequest,
    StageCall,
    StageOutcome,
    SurveyPlan,
    cache_key,
    current_results,
    execute,
    fan_in_for,
    plan_survey,
    publish_deliverables,
    room_failures,
    store_for,
)
from tasks import config as cfgmod
from tasks.artefacts import BUILDING, ArtefactError, StageResult

log = logging.getLogger("indoor_survey")

PREFECT_RESULTS = "prefect-results"


# ----------------------------------------------------------------------------------------- stage calls


def _results(upstream: dict[str, Any]) -> dict[str, StageResult]:
    """Upstream values as results; an optional upstream that failed arrives as its exception and is left
    out (the stage runs without it)."""
    return {name: value.result for name, value in upstream.items() if isinstance(value, Executed)}


def _prefect_cache_key(context: Any, parameters: dict[str, Any]) -> str | None:
    """Prefect's cache key is the content key; a record whose artefact is gone is dropped first."""
    call: StageCall = parameters["call"]
    if call.force:
        return None
    key = cache_key(call, _results(parameters.get("upstream") or {}), parameters.get("fan_in"))
    store = store_for(call.work)
    # The record holds a StageResult naming the room's folder, so rooms with identical inputs must
    # not share one: the room and stage prefix the content key.
    prefect_key = f"{call.room}-{call.stage}-{key}"
    if store.lookup(call.room, call.stage, key) is None:
        record = store.work / PREFECT_RESULTS / prefect_key
        if record.exists():
            record.unlink()
    return prefect_key


@task(cache_key_fn=_prefect_cache_key, persist_result=True, task_run_name="{call.stage}[{call.room}]")
def stage_task(call: StageCall, upstream: dict[str, Any], fan_in: FanIn | None = None) -> Executed:
    """One stage for one room (or for the building)."""
    results = _results(upstream)
    for name in sorted(set(upstream) - set(results)):
        log.warning("[%s] %s: runs without %s, which failed", call.room, call.stage, name)
    return execute(call, results, fan_in)


def _task_for(item: PlannedStage) -> Any:
    storage = Path(item.call.work) / PREFECT_RESULTS
    return stage_task.with_options(result_storage=storage, refresh_cache=item.call.force or None)


def _submit(item: PlannedStage, upstream: dict[str, Any], fan_in: FanIn | None = None) -> PrefectFuture:
    return _task_for(item).submit(item.call, upstream, fan_in)


# ----------------------------------------------------------------------------------------------- flows


@task(name="room", task_run_name="room[{chain[0].call.room}]", cache_policy=NO_CACHE, persist_result=False)
def room_task(
    chain: list[PlannedStage], building: dict[str, Executed], settled: dict[str, Executed] | None = None
) -> list[StageOutcome]:
    """Every stage of one room, given the building stages' results it may read and the room's stages
    that are current already (`settled`: read from the store, no task run). One task per room, so the
    task runner runs rooms concurrently (threads, or Dask); a room's stages form a chain, each reading the
    one before, so they run one after another inside it, each a nested task run (no subflow: a flow run
    per room cost API calls and a thread pool of its own). Never raises: a stage that fails is reported,
    and the stages after it that need it are skipped."""
    settled = settled or {}
    done: dict[str, Executed] = dict(settled)
    failed: dict[str, BaseException | None] = {}
    rows: list[StageOutcome] = []
    for item in chain:
        if item.call.stage in settled:
            rows.append(_settled_row(item, settled[item.call.stage]))
            continue
        upstream: dict[str, Any] = {}
        missing, broken = [], []
        for name, ref in item.upstream.items():
            if ref[0] == BUILDING:
                if name in building:
                    upstream[name] = building[name]
                elif name not in item.optional:
                    missing.append(name)
            elif ref[1] in done:
                upstream[name] = done[ref[1]]
            elif ref[1] in failed and name in item.optional:
                upstream[name] = failed[ref[1]]  # runs without it, and says so
            elif ref[1] in failed:
                broken.append(name)
            else:
                missing.append(name)
        if broken:
            rows.append(StageOutcome(*item.ref, "skipped", 0.0, "an earlier stage failed"))
            continue
        if missing:
            rows.append(StageOutcome(*item.ref, "skipped", 0.0, f"{missing[0]} failed"))
            continue
        state = _task_for(item).with_options(task_run_name=f"{item.call.stage}[{item.call.room}]")(
            item.call, upstream, None, return_state=True
        )
        row = outcome(item.ref, state)
        rows.append(row)
        if row.result is None:
            failed[item.call.stage] = _exception(state)
        else:
            done[item.call.stage] = state.result()
    return rows


def _current(item: PlannedStage, upstream: dict[str, Any], fan_in: FanIn) -> Executed | None:
    """A building-after stage's verified artefact for the key its inputs give now (the key its task
    would look up), unless it is forced: after rooms whose recomputed stages wrote the same bytes, the
    stage is read from the store without a task run."""
    if item.call.force:
        return None
    call = item.call
    try:
        key = cache_key(call, _results(upstream), fan_in)
    except (ArtefactError, OSError):
        return None
    hit = store_for(call.work).lookup(call.room, call.stage, key)
    return None if hit is None else Executed(hit, "stored", 0.0)


def _settled_row(item: PlannedStage, done: Executed) -> StageOutcome:
    if done.how == "computed":  # computed while Prefect's server started (flows/ahead.py)
        return StageOutcome(item.call.room, item.call.stage, "computed", done.seconds, "", done.result)
    return StageOutcome(item.call.room, item.call.stage, "cached", 0.0, "", done.result)


def settled_stages(
    plan: SurveyPlan, ahead: dict[tuple[str, str], float] | None = None
) -> dict[tuple[str, str], Executed]:
    """The stage runs of a plan that are current before the run starts (not forced, every input current,
    a verified artefact for their key in the store): they are read, not run, so the run creates no
    Prefect task for them. `ahead`: the stages computed before the flow started (forced ones among them),
    reported as computed. What follows a forced or changed stage is left to the run: its key is known
    only once that stage has written its artefacts."""
    ahead = ahead or {}
    found = current_results(plan, plan.rooms, skip=lambda item: item.call.force and item.ref not in ahead)
    return {
        ref: Executed(result, "computed", ahead[ref]) if ref in ahead else Executed(result, "stored", 0.0)
        for ref, result in found.items()
    }


@flow(name="building", log_prints=False, validate_parameters=False, persist_result=False)
def building_flow(req: RunRequest, ahead: list[tuple[str, str, float]] | None = None) -> list[StageOutcome]:
    """All rooms of a survey (or those in `req.rooms`): the building's stages before the rooms, the rooms
    concurrently, then the building-after stages over every room. `ahead`: (room, stage, seconds) of the
    stages computed while Prefect's server started (flows/ahead.py)."""
    cfg = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets))
    survey = cfgmod.load_survey(Path(req.survey))
    profile = cfgmod.load_sensor_profile(survey.sensor)
    plan = plan_survey(req, cfg, survey, profile)
    settled = settled_stages(plan, {(room, stage): seconds for room, stage, seconds in ahead or []})
    before = {item.ref: _submit(item, {}) for item in plan.before if item.ref not in settled}
    wait(list(before.values()))
    rows = [_settled_row(item, settled[item.ref]) for item in plan.before if item.ref in settled]
    rows += outcomes(before)
    building = {ref[1]: f.result() for ref, f in before.items() if f.state.is_completed()}
    building.update({ref[1]: done for ref, done in settled.items() if ref[0] == BUILDING})
    rooms = {}
    for room, chain in plan.rooms.items():
        done = {item.call.stage: settled[item.ref] for item in chain if item.ref in settled}
        if len(done) == len(chain):  # every stage current: no room task at all
            rows += [_settled_row(item, done[item.call.stage]) for item in chain]
        elif chain:
            rooms[room] = room_task.submit(chain, building, done)
    wait(list(rooms.values()))
    rows += plan.failed_rows()  # rooms whose capture cannot be read: failed alone, before any stage
    for room, future in rooms.items():
        if future.state.is_completed():
            rows += future.result()
        else:  # the room task itself broke (not a stage): every stage of the room is reported failed
            message = _message(future.state)
            rows += [StageOutcome(room, i.call.stage, "failed", 0.0, message) for i in plan.rooms[room]]
    results = {(r.room, r.stage): r.result for r in rows if r.result is not None}
    results.update(current_results(plan, plan.others))  # rooms outside the request: read, never run
    failures = room_failures(rows)
    finished = {
        ref[1]: Executed(result, "stored", 0.0) for ref, result in results.items() if ref[0] == BUILDING
    }
    for item in plan.after:
        fan_in = fan_in_for(item, results, failures, survey.room_ids)
        upstream = {name: finished[name] for name in item.upstream if name in finished}
        current = _current(item, upstream, fan_in)
        if current is not None:  # its inputs' bytes did not change: read, no task run
            rows.append(_settled_row(item, current))
            results[item.ref] = current.result
            finished[item.call.stage] = current
            continue
        future = _submit(item, upstream, fan_in)
        future.wait()
        [row] = outcomes({item.ref: future})
        rows.append(row)
        if row.result is not None:
            results[item.ref] = row.result
            finished[item.call.stage] = Executed(row.result, "stored", 0.0)
    store = store_for(req.work)
    store.save_memo()
    publish_deliverables(store, rows, req)  # outputs/, then outputs/manifest.json last
    return rows


# ---------------------------------------------------------------------------------------------- outcome


def _exception(state: Any) -> BaseException | None:
    exc = state.result(raise_on_failure=False)
    return exc if isinstance(exc, BaseException) else None


def _message(state: Any) -> str:
    exc = _exception(state)
    if exc is not None:
        return " ".join(str(exc).split())
    return state.message or state.name


def outcome(ref: tuple[str, str], state: Any) -> StageOutcome:
    """What happened to one stage call, from its final Prefect state."""
    room, stage = ref
    if state.is_completed():
        done: Executed = state.result()
        how = "cached" if state.name == "Cached" else done.how
        return StageOutcome(room, stage, how, done.seconds if how == "computed" else 0.0, "", done.result)
    if state.is_failed() or state.is_crashed():
        return StageOutcome(room, stage, "failed", 0.0, _message(state))
    return StageOutcome(room, stage, "skipped", 0.0, "an earlier stage failed")  # never ran


def outcomes(futures: dict[tuple[str, str], PrefectFuture]) -> list[StageOutcome]:
    """What happened to every stage call, for the summary and the exit code."""
    return [outcome(ref, future.state) for ref, future in futures.items()]


PRELOAD = (
    "prefect.flow_engine",
    "prefect.task_engine",
    "prefect.utilities.visualization",
    "fastapi.encoders",
    "flows.runners",
)


def preload() -> None:
    """Import what Prefect imports only once a flow or task is called (its flow and task engines, its
    run-graph tracker, FastAPI's encoder of flow parameters) and the task runners: a run does it while
    its embedded server starts, where it waits, instead of after (about 0.3 CPU s)."""
    for name in PRELOAD:
        importlib.import_module(name)


def run_survey(
    req: RunRequest,
    runner: str = "threads",
    dask_address: str | None = None,
    heartbeats: bool = True,
    ahead: dict[tuple[str, str], float] | None = None,
) -> list[StageOutcome]:
    """Run the building flow and report every stage's outcome; rooms run on `runner` ("threads" or
    "dask", see flows/runners.py), `flow.max_workers` at once. `ahead`: (room, stage) -> seconds of the
    stages already computed for this request (flows/ahead.py).

    `heartbeats=False` (a run on its own embedded server, which dies with it): no flow-run heartbeats.
    They tell a long-lived server that a run crashed; the flow's heartbeat thread is also joined when
    the flow ends (up to a second)."""
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    from flows.runners import task_runner

    workers = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets)).flow.max_workers
    store_for(req.work).sweep_temporaries()
    flow_ = building_flow.with_options(task_runner=task_runner(runner, workers, dask_address))
    done = [(room, stage, seconds) for (room, stage), seconds in sorted((ahead or {}).items())]
    if heartbeats:
        return flow_(req, done)
    with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        return flow_(req, done)
