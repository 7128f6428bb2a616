"""Prefect flows over the artefact store.

`building_flow` runs the building's stages that the rooms read (calibrate, plan), maps `room_flow` over
the rooms concurrently (a room is a partition: rooms are independent until fusion), then runs the
building-after stages (fan-in) on every room's results, a failed room passed to them as failed. Each
stage is one Prefect task whose cache key is the content address of its run (input content hashes + its
config sections + its code version), with results persisted under the work dir, so Prefect's logs and
UI show cache hits. The artefact store stays the source of truth: a key whose artefact folder is missing
or fails its hashes has its Prefect record dropped and recomputes.

Prefect's settings (offline, quiet, patient start-up) are the caller's: `flows.prefect_env.apply()`
before this module is imported (the CLI does it).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from prefect import allow_failure, flow, task
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
from tasks.artefacts import BUILDING, StageResult

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


def _submit(item: PlannedStage, upstream: dict[str, Any], fan_in: FanIn | None = None) -> PrefectFuture:
    storage = Path(item.call.work) / PREFECT_RESULTS
    task_ = stage_task.with_options(result_storage=storage, refresh_cache=item.call.force or None)
    return task_.submit(item.call, upstream, fan_in)


# ----------------------------------------------------------------------------------------------- flows


@flow(name="room", log_prints=False, validate_parameters=False, persist_result=False)
def room_flow(
    chain: list[PlannedStage], building: dict[str, Executed], settled: dict[str, Executed] | None = None
) -> list[StageOutcome]:
    """Every stage of one room, given the building stages' results it may read and the room's stages
    that are current already (`settled`: read from the store, no task run). Never raises: a stage that
    fails is reported, and the stages after it are skipped."""
    settled = settled or {}
    futures: dict[tuple[str, str], PrefectFuture] = {}
    rows: list[StageOutcome] = []
    for item in chain:
        if item.call.stage in settled:
            rows.append(_settled_row(item, settled[item.call.stage]))
            continue
        upstream: dict[str, Any] = {}
        missing = []
        for name, ref in item.upstream.items():
            if ref[0] == BUILDING:
                if name in building:
                    upstream[name] = building[name]
                elif name not in item.optional:
                    missing.append(name)
            elif ref[1] in settled:
                upstream[name] = settled[ref[1]]
            elif ref not in futures:
                missing.append(name)
            else:
                future = futures[ref]
                upstream[name] = allow_failure(future) if name in item.optional else future
        if missing:
            rows.append(StageOutcome(item.call.room, item.call.stage, "skipped", 0.0, f"{missing[0]} failed"))
            continue
        futures[item.ref] = _submit(item, upstream)
    wait(list(futures.values()))
    order = {item.call.stage: i for i, item in enumerate(chain)}
    return sorted(rows + outcomes(futures), key=lambda row: order[row.stage])


@task(name="room", task_run_name="room[{chain[0].call.room}]", cache_policy=NO_CACHE, persist_result=False)
def room_task(
    chain: list[PlannedStage], building: dict[str, Executed], settled: dict[str, Executed] | None = None
) -> list[StageOutcome]:
    """A room's subflow as a task, so the task runner runs rooms concurrently (threads, or Dask)."""
    return room_flow(chain, building, settled)


def _settled_row(item: PlannedStage, done: Executed) -> StageOutcome:
    return StageOutcome(item.call.room, item.call.stage, "cached", 0.0, "", done.result)


def settled_stages(plan: SurveyPlan) -> dict[tuple[str, str], Executed]:
    """The stage runs of a plan that are current before the run starts (not forced, every input current,
    a verified artefact for their key in the store): they are read, not run, so the run creates no
    Prefect task for them. What follows a forced or changed stage is left to the run: its key is known
    only once that stage has written its artefacts."""
    found = current_results(plan, plan.rooms, skip=lambda item: item.call.force)
    return {ref: Executed(result, "stored", 0.0) for ref, result in found.items()}


@flow(name="building", log_prints=False, validate_parameters=False, persist_result=False)
def building_flow(req: RunRequest) -> list[StageOutcome]:
    """All rooms of a survey (or those in `req.rooms`): the building's stages before the rooms, the rooms
    concurrently, then the building-after stages over every room."""
    cfg = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets))
    survey = cfgmod.load_survey(Path(req.survey))
    profile = cfgmod.load_sensor_profile(survey.sensor)
    plan = plan_survey(req, cfg, survey, profile)
    settled = settled_stages(plan)
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
        else:  # the subflow itself broke (not a stage): every stage of the room is reported failed
            message = _message(future)
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


def _message(future: PrefectFuture) -> str:
    exc = future.state.result(raise_on_failure=False)
    if isinstance(exc, BaseException):
        return " ".join(str(exc).split())
    return future.state.message or future.state.name


def outcomes(futures: dict[tuple[str, str], PrefectFuture]) -> list[StageOutcome]:
    """What happened to every stage call, for the summary and the exit code."""
    rows = []
    for (room, stage), future in futures.items():
        state = future.state
        if state.is_completed():
            done: Executed = state.result()
            how = "cached" if state.name == "Cached" else done.how
            rows.append(
                StageOutcome(room, stage, how, done.seconds if how == "computed" else 0.0, "", done.result)
            )
        elif state.is_failed() or state.is_crashed():
            rows.append(StageOutcome(room, stage, "failed", 0.0, _message(future)))
        else:  # never ran: an upstream stage failed
            rows.append(StageOutcome(room, stage, "skipped", 0.0, "an earlier stage failed"))
    return rows


def run_survey(
    req: RunRequest, runner: str = "threads", dask_address: str | None = None, heartbeats: bool = True
) -> list[StageOutcome]:
    """Run the building flow and report every stage's outcome; rooms run on `runner` ("threads" or
    "dask", see flows/runners.py), `flow.max_workers` at once.

    `heartbeats=False` (a run on its own embedded server, which dies with it): no flow-run heartbeats.
    They tell a long-lived server that a run crashed; each flow's heartbeat thread is also joined when
    the flow ends, about half a second per room's subflow."""
    from prefect.settings import PREFECT_FLOWS_HEARTBEAT_FREQUENCY, temporary_settings

    from flows.runners import task_runner

    workers = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets)).flow.max_workers
    store_for(req.work).sweep_temporaries()
    flow_ = building_flow.with_options(task_runner=task_runner(runner, workers, dask_address))
    if heartbeats:
        return flow_(req)
    with temporary_settings(updates={PREFECT_FLOWS_HEARTBEAT_FREQUENCY: None}):
        return flow_(req)
