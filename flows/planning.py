"""Planning and running stage calls without an orchestrator: which stages a survey implies, their cache
keys, load-or-compute of one stage, and the current state of a work dir. Prefect (flows/pipeline.py)
wraps `execute` in tasks; `status`, the no-op fast path of `run` and `model-room` use this module alone,
so they never pay Prefect's start-up.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tasks import config as cfgmod
from tasks.artefacts import (
    BUILDING,
    ArtefactStore,
    StageResult,
    atomic_path,
    hash_json,
    sha256_file,
    write_json,
)
from tasks.cloud import DegenerateInputError
from tasks.ingest.capture import capture_kind
from tasks.stages import BUILDING_DELIVERABLES, ROOM_DELIVERABLES, STAGES, StageContext

log = logging.getLogger("indoor_survey")


@dataclass(frozen=True)
class StageCall:
    """Everything one stage run needs, as plain data (it crosses Prefect's task boundary)."""

    stage: str
    room: str
    work: str
    config: dict[str, Any]
    profile: dict[str, Any]
    raw_inputs: dict[str, str] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    """Survey-given values a stage needs besides files and config (the plan's scale); in the key."""
    force: bool = False
    extra_config: dict[str, dict[str, Any]] = field(default_factory=dict)


_stores: dict[str, ArtefactStore] = {}
_stores_lock = threading.Lock()
_outcomes: dict[tuple[str, str], tuple[str, float]] = {}
"""(room, stage) -> ("computed" | "stored", seconds) for the runs whose task body executed."""


def store_for(work: str | Path) -> ArtefactStore:
    """One store per work dir per process, so the input-hash memo is shared by all tasks."""
    key = str(Path(work).resolve())
    with _stores_lock:
        if key not in _stores:
            _stores[key] = ArtefactStore(Path(key))
        return _stores[key]


def cache_key(call: StageCall, upstream: dict[str, StageResult]) -> str:
    store = store_for(call.work)
    stage = STAGES[call.stage]
    inputs = {name: result.content_hash for name, result in upstream.items()}
    inputs.update({name: store.input_hash(Path(path)) for name, path in call.raw_inputs.items()})
    if call.params:
        inputs["params"] = hash_json(call.params)
    if stage.uses_profile:  # e.g. how to read a capture (topics, depth convention), fallback intrinsics
        inputs["sensor_profile"] = cfgmod.hash_profile(call.profile)
    config = {stage.section: call.config, **call.extra_config} if call.extra_config else call.config
    return store.cache_key(stage.name, stage.code_version(), config, inputs)


def execute(call: StageCall, upstream: dict[str, StageResult]) -> StageResult:
    """Load-or-compute one stage: a verified store hit returns at once; otherwise the stage runs into a
    private folder that the store renames into place."""
    store = store_for(call.work)
    stage = STAGES[call.stage]
    key = cache_key(call, upstream)
    started = time.perf_counter()
    if not call.force:
        hit = store.lookup(call.room, call.stage, key)
        if hit is not None:
            _outcomes[(call.room, call.stage)] = ("stored", time.perf_counter() - started)
            return hit
    defaults = cfgmod.PipelineConfig()
    cfg = cfgmod.build_section(type(getattr(defaults, stage.section)), call.config)
    extra = {
        name: cfgmod.build_section(type(getattr(defaults, name)), call.extra_config[name])
        for name in stage.extra_sections
    }

    def progress(message: str) -> None:
        log.info("[%s] %s: %s", call.room, call.stage, message)

    ctx = StageContext(call.room, upstream, call.raw_inputs, call.profile, progress, extra, call.params)
    log.info("[%s] %s: computing", call.room, call.stage)
    manifest = {
        "inputs": {name: r.content_hash for name, r in upstream.items()},
        "raw_inputs": {
            name: {"path": p, "sha256": store.input_hash(Path(p))} for name, p in call.raw_inputs.items()
        },
        "config": call.config,
        "extra_config": call.extra_config,
        "code_version": stage.code_version(),
    }

    def write(out: Path) -> dict[str, Any]:
        t0 = time.perf_counter()
        report = stage.run(ctx, cfg, out)  # {"metrics": {...}, other manifest entries...}
        return {**report, "compute_seconds": round(time.perf_counter() - t0, 3)}

    result = store.commit(call.room, call.stage, key, write, manifest)
    seconds = time.perf_counter() - started
    _outcomes[(call.room, call.stage)] = ("computed", seconds)
    log.info("[%s] %s: done in %.1f s", call.room, call.stage, seconds)
    return result


def room_stages(capture: Path) -> list[str]:
    """The stages that apply to a room, given what its capture is: a registered cloud needs no
    registration."""
    if capture_kind(capture) == "cloud":
        return ["ingest", "preprocess", "walls"]
    return ["ingest", "register", "preprocess", "walls"]


UPSTREAM: dict[str, tuple[str, ...]] = {
    "register": ("ingest", "calibrate", "plan"),
    "preprocess": ("register", "ingest"),
    "walls": ("preprocess",),
}
"""Stage -> the stages whose results it reads (those that apply to the room, or the building's)."""

BUILDING_STAGES = ("calibrate", "plan")


@dataclass(frozen=True)
class RunRequest:
    """What to run: resolved before Prefect starts, so bad input fails fast with one line."""

    survey: str
    work: str
    config_files: tuple[str, ...] = ()
    sets: tuple[str, ...] = ()
    rooms: tuple[str, ...] = ()
    force: tuple[tuple[str, str], ...] = ()
    """(room, stage) pairs to recompute whatever the cache says."""


def survey_inputs(
    survey: cfgmod.Survey | None, room: cfgmod.RoomSpec | None, stage_name: str
) -> dict[str, str]:
    """The raw survey files a stage reads (their content hashes enter its cache key)."""
    if stage_name == "ingest" and room is not None:
        return {"capture": str(room.capture)}
    if survey is None:
        return {}
    if stage_name == "calibrate" and survey.calibration is not None and survey.calibration.is_dir():
        return {"calibration": str(survey.calibration)}
    if stage_name == "plan" and survey.plan is not None:
        return {"plan": str(survey.plan.image)}
    if stage_name == "register" and survey.track is not None and survey.track.is_file():
        return {"track": str(survey.track)}
    return {}


def survey_params(survey: cfgmod.Survey | None, stage_name: str) -> dict[str, Any]:
    """Values from survey.yaml a stage needs (the plan's scale)."""
    if stage_name == "plan" and survey is not None and survey.plan is not None:
        plan = survey.plan
        return {
            "m_per_px": plan.m_per_px,
            "known_distance": list(plan.known_distance) if plan.known_distance else None,
            "outline_length_m": plan.outline_length_m,
        }
    return {}


def make_call(
    work: str | Path,
    cfg: cfgmod.PipelineConfig,
    profile: dict[str, Any],
    room: cfgmod.RoomSpec | None,
    stage_name: str,
    force: bool = False,
    survey: cfgmod.Survey | None = None,
) -> StageCall:
    """The call for one stage of one room (room None: of the building): its config section and the raw
    survey files it reads."""
    return StageCall(
        stage=stage_name,
        room=room.id if room is not None else BUILDING,
        work=str(Path(work).resolve()),
        config=cfgmod.section(cfg, STAGES[stage_name].section),
        extra_config={name: cfgmod.section(cfg, name) for name in STAGES[stage_name].extra_sections},
        profile=profile,
        raw_inputs=survey_inputs(survey, room, stage_name),
        params=survey_params(survey, stage_name),
        force=force,
    )


@dataclass(frozen=True)
class PlannedStage:
    call: StageCall
    upstream: dict[str, tuple[str, str]]
    """Input name -> (room, stage) of the run that provides it."""


def plan_survey(
    req: RunRequest, cfg: cfgmod.PipelineConfig, survey: cfgmod.Survey, profile: dict[str, Any]
) -> list[PlannedStage]:
    """Every stage run a request implies, in dependency order: the building's stages the rooms need,
    then each room's chain. Forcing a stage forces what follows it in that room."""
    rooms = [survey.room(r) for r in (req.rooms or survey.room_ids)]
    chains = {room.id: room_stages(room.capture) for room in rooms}
    needed = {up for chain in chains.values() for s in chain for up in UPSTREAM.get(s, ())}
    planned: list[PlannedStage] = []
    available: set[str] = set()
    for stage_name in BUILDING_STAGES:
        if (
            stage_name in STAGES
            and stage_name in needed
            and (stage_name != "plan" or survey.plan is not None)
        ):
            force = (BUILDING, stage_name) in req.force
            planned.append(
                PlannedStage(make_call(req.work, cfg, profile, None, stage_name, force, survey), {})
            )
            available.add(stage_name)
    for room in rooms:
        forced = False
        for stage_name in chains[room.id]:
            forced = forced or (room.id, stage_name) in req.force
            upstream = {}
            for name in UPSTREAM.get(stage_name, ()):
                if name in chains[room.id][: chains[room.id].index(stage_name)]:
                    upstream[name] = (room.id, name)
                elif name in available:
                    upstream[name] = (BUILDING, name)
            call = make_call(req.work, cfg, profile, room, stage_name, forced, survey)
            planned.append(PlannedStage(call, upstream))
    return planned


def breadth_first(planned: list[PlannedStage]) -> list[PlannedStage]:
    """Stage runs ordered by their depth in the dependency graph: a worker thread waiting for an upstream
    result is a worker lost, so every room's first stage is submitted before any room's second."""
    depth: dict[tuple[str, str], int] = {}
    for item in planned:
        refs = item.upstream.values()
        depth[(item.call.room, item.call.stage)] = 1 + max((depth[ref] for ref in refs), default=-1)
    return sorted(planned, key=lambda item: depth[(item.call.room, item.call.stage)])


@dataclass(frozen=True)
class StageOutcome:
    room: str
    stage: str
    state: str
    """"computed", "cached" (Prefect cache hit), "stored" (store hit, Prefect record new), "failed", "skipped"."""
    seconds: float
    error: str = ""
    result: StageResult | None = None


def publish_deliverables(store: ArtefactStore, rows: list[StageOutcome]) -> None:
    """Copy finished deliverables to outputs/ (rooms' to outputs/rooms/<id>/), only what changed."""
    for row in rows:
        if row.result is None:
            continue
        if row.room == BUILDING:
            names, folder = BUILDING_DELIVERABLES.get(row.stage, ()), ()
        else:
            names, folder = ROOM_DELIVERABLES.get(row.stage, ()), ("rooms", row.room)
        for name in names:
            dest = store.outputs.joinpath(*folder, name)
            digest = row.result.files.get(name)
            if digest and not (dest.is_file() and sha256_file(dest) == digest):
                store.publish(row.result.file(name), *folder, name)


def save_resolved_config(work: Path, cfg: cfgmod.PipelineConfig, argv: Iterable[str]) -> Path:
    """The resolved config of this run, beside the run's log, for the record."""
    stamp = time.strftime("%Y%m%dT%H%M%S")
    path = Path(work) / "runs" / stamp / "config.yaml"
    with atomic_path(path) as tmp:
        tmp.write_text(f"# indoor-survey {' '.join(argv)}\n" + cfgmod.to_yaml(cfg))
    return path


def model_room(cloud: Path, out_dir: Path, cfg: cfgmod.PipelineConfig, work: Path) -> dict[str, Any]:
    """ingest -> preprocess -> walls on one registered cloud, without Prefect (a one-off tool), through
    the same cached stages; the room's deliverables and its levelling transform are copied to `out_dir`."""
    room = cfgmod.RoomSpec("room", Path(cloud).resolve())
    profile = cfgmod.load_sensor_profile("tls")
    results: dict[str, StageResult] = {}
    for stage_name in room_stages(room.capture):
        call = make_call(work, cfg, profile, room, stage_name)
        upstream = {n: results[n] for n in UPSTREAM.get(stage_name, ()) if n in results}
        try:
            results[stage_name] = execute(call, upstream)
        except ValueError as exc:  # bad input (DegenerateInputError, IngestError...): name the file
            message = " ".join(str(exc).split())
            raise DegenerateInputError(message if str(cloud) in message else f"{cloud}: {message}") from exc
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    store = store_for(work)
    for name in ROOM_DELIVERABLES["walls"]:
        with atomic_path(out_dir / name) as tmp:
            tmp.write_bytes(results["walls"].file(name).read_bytes())
    with atomic_path(out_dir / "levelling.json") as tmp:
        tmp.write_bytes(results["preprocess"].file("levelling.json").read_bytes())
    store.save_memo()
    return {
        "preprocess": results["preprocess"].manifest.get("metrics", {}),
        "walls": results["walls"].manifest.get("metrics", {}),
    }


@dataclass(frozen=True)
class StageState:
    planned: PlannedStage
    status: str
    """"done" (a verified artefact for today's inputs, config and code), "stale" (an older artefact exists
    but something it depends on changed) or "missing"."""
    result: StageResult | None
    detail: str


def survey_state(req: RunRequest) -> list[StageState]:
    """The state of every stage run a request implies, from the artefact store alone."""
    cfg = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets))
    survey = cfgmod.load_survey(Path(req.survey))
    profile = cfgmod.load_sensor_profile(survey.sensor)
    store = store_for(req.work)
    done: dict[tuple[str, str], StageResult] = {}
    states = []
    for item in plan_survey(req, cfg, survey, profile):
        call = item.call
        previous = store.latest(call.room, call.stage)
        waiting = sorted({ref[1] for ref in item.upstream.values() if ref not in done})
        if waiting:
            status = "stale" if previous else "missing"
            states.append(StageState(item, status, None, f"waits for {', '.join(waiting)}"))
            continue
        key = cache_key(call, {name: done[ref] for name, ref in item.upstream.items()})
        hit = None if call.force else store.lookup(call.room, call.stage, key)
        if hit:
            done[(call.room, call.stage)] = hit
            states.append(StageState(item, "done", hit, f"{key[:12]} at {_when(hit)}"))
        elif previous:
            states.append(
                StageState(item, "stale", None, f"last run {_when(previous)}; inputs, config or code changed")
            )
        else:
            states.append(StageState(item, "missing", None, "never run"))
    store.save_memo()
    return states


def _when(result: StageResult) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(result.manifest.get("finished_at", 0)))


def all_current(req: RunRequest) -> list[StageOutcome] | None:
    """When every stage of the request is done, the run's outcome without running anything (and without
    starting Prefect: its start-up would be most of a no-op rerun); else None."""
    states = survey_state(req)
    if req.force or any(s.status != "done" for s in states):
        return None
    rows = [
        StageOutcome(s.planned.call.room, s.planned.call.stage, "cached", 0.0, "", s.result) for s in states
    ]
    publish_deliverables(store_for(req.work), rows)
    return rows


def write_truth_metrics(req: RunRequest, rows: list[StageOutcome]) -> Path | None:
    """outputs/metrics.json: each room model against the survey's truth/, when it has one."""
    from tasks.benchmark import RoomRun, evaluate_runs

    survey = cfgmod.load_survey(Path(req.survey))
    if survey.truth is None or not (survey.truth / "walls.parquet").is_file():
        return None
    results = {(r.room, r.stage): r.result for r in rows if r.result is not None}
    runs = []
    for room in survey.room_ids:
        walls = results.get((room, "walls"))
        if walls is None:
            continue
        registered = (room, "register") in results
        pre = results.get((room, "preprocess"))
        runs.append(
            RoomRun(
                room=room,
                walls=walls.file("walls.parquet"),
                levelling=pre.file("levelling.json") if registered and pre else None,
                poses=results[(room, "register")].file("poses.parquet") if registered else None,
            )
        )
    if not runs:
        return None
    metrics = evaluate_runs(runs, survey.truth)
    return write_json(store_for(req.work).outputs / "metrics.json", metrics)
