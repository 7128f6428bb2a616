"""Prefect flows over the artefact store.

`room_flow` runs every stage that applies to one room; `building_flow` maps the rooms concurrently (a room
is a partition: rooms are independent until fusion). Each stage is one Prefect task whose cache key is
the content address of its run (input content hashes + its own config section + its code version), with
results persisted under the work dir, so Prefect's logs and UI show cache hits. The artefact store stays
the source of truth: a key whose artefact folder is missing or fails its hashes has its Prefect record
dropped and recomputes.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

for _name, _value in {
    # Offline, quiet and patient: the embedded server needs more than the default 20 s to start here.
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DO_NOT_TRACK": "1",
    # Stage failures are reported by the run summary in one line each; Prefect's own copy of them is a
    # traceback. PREFECT_LOGGING_LEVEL=ERROR in the environment brings those back for debugging.
    "PREFECT_LOGGING_LEVEL": "CRITICAL",
    # The embedded server is stopped when a run ends; its event writer's cancellation is not an error.
    "PREFECT_SERVER_LOGGING_LEVEL": "CRITICAL",
    "PREFECT_LOGGING_TO_API_ENABLED": "false",
    "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "true",
}.items():
    os.environ.setdefault(_name, _value)

from prefect import flow, task  # noqa: E402
from prefect.futures import PrefectFuture, wait  # noqa: E402
from prefect.task_runners import ThreadPoolTaskRunner  # noqa: E402

from flows.planning import (  # noqa: E402
    RunRequest,
    StageCall,
    StageOutcome,
    _outcomes,
    breadth_first,
    cache_key,
    execute,
    plan_survey,
    publish_deliverables,
    store_for,
)
from tasks import config as cfgmod  # noqa: E402
from tasks.artefacts import StageResult  # noqa: E402

log = logging.getLogger("indoor_survey")

PREFECT_RESULTS = "prefect-results"


# ----------------------------------------------------------------------------------------- stage calls


def _prefect_cache_key(context: Any, parameters: dict[str, Any]) -> str | None:
    """Prefect's cache key is the content key; a record whose artefact is gone is dropped first."""
    call: StageCall = parameters["call"]
    if call.force:
        return None
    upstream: dict[str, StageResult] = parameters.get("upstream") or {}
    key = cache_key(call, upstream)
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
def stage_task(call: StageCall, upstream: dict[str, StageResult]) -> StageResult:
    """One stage for one room (or for the building)."""
    return execute(call, upstream)


# -------------------------------------------------------------------------------------------- routing


def _run(req: RunRequest) -> list[StageOutcome]:
    cfg = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets))
    survey = cfgmod.load_survey(Path(req.survey))
    profile = cfgmod.load_sensor_profile(survey.sensor)
    results = Path(req.work).resolve() / PREFECT_RESULTS
    futures: dict[tuple[str, str], PrefectFuture] = {}
    for item in breadth_first(plan_survey(req, cfg, survey, profile)):
        call = item.call
        upstream = {name: futures[ref] for name, ref in item.upstream.items()}
        futures[(call.room, call.stage)] = stage_task.with_options(
            result_storage=results, refresh_cache=call.force or None
        ).submit(call, upstream)
    wait(list(futures.values()))
    store = store_for(req.work)
    store.save_memo()
    rows = outcomes(futures)
    publish_deliverables(store, rows)
    return rows


@flow(name="room", log_prints=False, validate_parameters=False, persist_result=False)
def room_flow(req: RunRequest) -> list[StageOutcome]:
    """Every stage that applies to the one room in `req.rooms`."""
    return _run(req)


@flow(
    name="building",
    log_prints=False,
    validate_parameters=False,
    persist_result=False,
)
def building_flow(req: RunRequest) -> list[StageOutcome]:
    """All rooms of a survey (or those in `req.rooms`), concurrently."""
    return _run(req)


# ---------------------------------------------------------------------------------------------- outcome


def outcomes(futures: dict[tuple[str, str], PrefectFuture]) -> list[StageOutcome]:
    """What happened to every stage of a run, for the summary and the exit code."""
    rows = []
    for (room, stage), future in futures.items():
        state = future.state
        if state.is_completed():
            result = state.result()
            kind, seconds = _outcomes.get((room, stage), ("cached", 0.0))
            rows.append(
                StageOutcome(room, stage, kind if state.name != "Cached" else "cached", seconds, "", result)
            )
        elif state.is_failed() or state.is_crashed():
            exc = state.result(raise_on_failure=False)
            message = (
                " ".join(str(exc).split()) if isinstance(exc, BaseException) else state.message or state.name
            )
            rows.append(StageOutcome(room, stage, "failed", 0.0, message))
        else:  # never ran: an upstream stage failed
            rows.append(StageOutcome(room, stage, "skipped", 0.0, "an earlier stage failed"))
    return rows


def run_survey(req: RunRequest) -> list[StageOutcome]:
    """Run the building flow (or the room flow for one room) and report every stage's outcome."""
    workers = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets)).flow.max_workers
    runner = room_flow if len(req.rooms) == 1 else building_flow
    store_for(req.work).sweep_temporaries()
    _outcomes.clear()
    return runner.with_options(task_runner=ThreadPoolTaskRunner(max_workers=max(1, workers)))(req)
