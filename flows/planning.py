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
from dataclasses import dataclass, field, replace
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
from tasks.context import StageContext
from tasks.ingest.capture import capture_kind
from tasks.stages import STAGES, downstream_of, load_class, stages_of

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


@dataclass(frozen=True)
class Executed:
    """What one stage call returned: its result, and whether this call computed it or found it in the
    store (a Prefect cache hit returns the record of the call that made it: flows tell that apart)."""

    result: StageResult
    how: str
    """"computed" or "stored"."""
    seconds: float


@dataclass(frozen=True)
class FanIn:
    """A building-after stage's view of the rooms: each room's results of the stages it reads, and the
    rooms without them, with the reason."""

    rooms: dict[str, dict[str, StageResult]] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)


_stores: dict[str, ArtefactStore] = {}
_stores_lock = threading.Lock()


def store_for(work: str | Path) -> ArtefactStore:
    """One store per work dir per process, so the input-hash memo is shared by all tasks."""
    key = str(Path(work).resolve())
    with _stores_lock:
        if key not in _stores:
            _stores[key] = ArtefactStore(Path(key))
        return _stores[key]


def cache_key(call: StageCall, upstream: dict[str, StageResult], fan_in: FanIn | None = None) -> str:
    store = store_for(call.work)
    stage = STAGES[call.stage]
    inputs = {name: result.content_hash for name, result in upstream.items()}
    inputs.update({name: store.input_hash(Path(path)) for name, path in call.raw_inputs.items()})
    if call.params:
        inputs["params"] = hash_json(call.params)
    if stage.uses_profile:  # e.g. how to read a capture (topics, depth convention), fallback intrinsics
        inputs["sensor_profile"] = cfgmod.hash_profile(call.profile)
    if fan_in is not None:
        inputs["rooms"] = hash_json(
            {room: {s: r.content_hash for s, r in results.items()} for room, results in fan_in.rooms.items()}
        )
        inputs["failed_rooms"] = hash_json(fan_in.failed)
    config = {stage.section: call.config, **call.extra_config} if call.extra_config else call.config
    return store.cache_key(stage.name, stage.code_version(), config, inputs)


def execute(call: StageCall, upstream: dict[str, StageResult], fan_in: FanIn | None = None) -> Executed:
    """Load-or-compute one stage: a verified store hit returns at once; otherwise the stage runs into a
    private folder that the store renames into place."""
    store = store_for(call.work)
    stage = STAGES[call.stage]
    key = cache_key(call, upstream, fan_in)
    started = time.perf_counter()
    if not call.force:
        hit = store.lookup(call.room, call.stage, key)
        if hit is not None:
            return Executed(hit, "stored", time.perf_counter() - started)
    cfg = cfgmod.build_section(load_class(stage.config), call.config)
    extra = {
        name: cfgmod.build_section(load_class(target), call.extra_config[name])
        for name, target in stage.extra_sections
    }

    def progress(message: str) -> None:
        log.info("[%s] %s: %s", call.room, call.stage, message)

    fan_in = fan_in or FanIn()
    ctx = StageContext(
        call.room,
        upstream,
        call.raw_inputs,
        call.profile,
        progress,
        extra,
        call.params,
        fan_in.rooms,
        fan_in.failed,
    )
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
    if fan_in.rooms or fan_in.failed:
        manifest["rooms"] = {room: sorted(results) for room, results in fan_in.rooms.items()}
        manifest["failed_rooms"] = fan_in.failed
    run = stage.runner()

    def write(out: Path) -> dict[str, Any]:
        t0 = time.perf_counter()
        report = run(ctx, cfg, out)  # {"metrics": {...}, other manifest entries...}
        return {**report, "compute_seconds": round(time.perf_counter() - t0, 3)}

    result = store.commit(call.room, call.stage, key, write, manifest)
    seconds = time.perf_counter() - started
    log.info("[%s] %s: done in %.1f s", call.room, call.stage, seconds)
    return Executed(result, "computed", seconds)


def room_stages(capture: Path) -> list[str]:
    """The room stages that apply to a room, given what its capture is (a registered cloud needs no
    registration), in table order."""
    kind = capture_kind(capture)
    return [s.name for s in stages_of("room") if s.applies(kind)]


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
    found: dict[str, str] = {}
    for name in STAGES[stage_name].raw_inputs:
        if name == "capture" and room is not None:
            found[name] = str(room.capture)
        elif survey is None:
            continue
        elif name == "calibration" and survey.calibration is not None:
            # target images (a folder), or a calibration.json made earlier
            if survey.calibration.is_dir() or survey.calibration.suffix == ".json":
                found[name] = str(survey.calibration)
        elif name == "plan" and survey.plan is not None:
            found[name] = str(survey.plan.image)
        elif name == "track" and survey.track is not None and survey.track.is_file():
            found[name] = str(survey.track)
    return found


REQUIRED_RAW_INPUTS = {"capture", "plan"}
"""Raw inputs without which a stage cannot run (the others have a fallback: the sensor profile's
calibration, registration without a track)."""


def survey_params(survey: cfgmod.Survey | None, stage_name: str) -> dict[str, Any]:
    """Values from survey.yaml a stage needs: the plan's scale, the survey's rooms."""
    params: dict[str, Any] = {}
    if survey is None:
        return params
    for name in STAGES[stage_name].params:
        if name == "plan_scale" and survey.plan is not None:
            plan = survey.plan
            params.update(
                m_per_px=plan.m_per_px,
                known_distance=list(plan.known_distance) if plan.known_distance else None,
                outline_length_m=plan.outline_length_m,
            )
        elif name == "rooms":
            params["rooms"] = [{"id": r.id, "plan_room": r.plan_room} for r in survey.rooms]
    return params


def make_call(
    work: str | Path,
    cfg: cfgmod.PipelineConfig,
    profile: dict[str, Any],
    room: cfgmod.RoomSpec | None,
    stage_name: str,
    force: bool = False,
    survey: cfgmod.Survey | None = None,
) -> StageCall:
    """The call for one stage of one room (room None: of the building): its config sections and the raw
    survey files it reads."""
    stage = STAGES[stage_name]
    return StageCall(
        stage=stage_name,
        room=room.id if room is not None else BUILDING,
        work=str(Path(work).resolve()),
        config=cfgmod.section(cfg, stage.section),
        extra_config={name: cfgmod.section(cfg, name) for name, _ in stage.extra_sections},
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
    room_upstream: tuple[str, ...] = ()
    """Building-after stages: the room stages it reads of every room."""

    @property
    def ref(self) -> tuple[str, str]:
        return (self.call.room, self.call.stage)

    @property
    def optional(self) -> tuple[str, ...]:
        return STAGES[self.call.stage].optional


@dataclass(frozen=True)
class SurveyPlan:
    """Every stage run a request implies: the building's stages before the rooms, each requested room's
    chain, the building's stages after the rooms, and the chains of the survey's other rooms (not run:
    a building-after stage reads their current results)."""

    before: list[PlannedStage]
    rooms: dict[str, list[PlannedStage]]
    after: list[PlannedStage]
    others: dict[str, list[PlannedStage]] = field(default_factory=dict)

    def items(self) -> list[PlannedStage]:
        """The stage runs of the request, in dependency order."""
        return [*self.before, *(i for chain in self.rooms.values() for i in chain), *self.after]


def plan_survey(
    req: RunRequest, cfg: cfgmod.PipelineConfig, survey: cfgmod.Survey, profile: dict[str, Any]
) -> SurveyPlan:
    """Every stage run a request implies. Forcing a room stage forces what follows it in that room and
    the building-after stages that read it."""
    requested = set(req.rooms or survey.room_ids)
    chains = {room.id: room_stages(room.capture) for room in survey.rooms}
    after_stages = stages_of("after")
    readers = [s for chain in chains.values() for s in chain] + [s.name for s in after_stages]
    needed = {up for name in readers for up in STAGES[name].upstream}
    before: list[PlannedStage] = []
    for stage in stages_of("before"):
        raw = survey_inputs(survey, None, stage.name)
        missing = [n for n in stage.raw_inputs if n in REQUIRED_RAW_INPUTS and n not in raw]
        if missing or not (stage.name in needed or stage.deliverables):
            continue
        force = (BUILDING, stage.name) in req.force
        before.append(PlannedStage(make_call(req.work, cfg, profile, None, stage.name, force, survey), {}))
    available = {item.call.stage for item in before}
    forced_after: set[str] = set()
    rooms: dict[str, list[PlannedStage]] = {}
    others: dict[str, list[PlannedStage]] = {}
    for room in survey.rooms:
        chain, forced = [], False
        for stage_name in chains[room.id]:
            if (room.id, stage_name) in req.force:
                forced = True
                forced_after |= downstream_of(stage_name)
            upstream = {}
            for name in STAGES[stage_name].upstream:
                if name in chains[room.id][: chains[room.id].index(stage_name)]:
                    upstream[name] = (room.id, name)
                elif name in available:
                    upstream[name] = (BUILDING, name)
            call = make_call(req.work, cfg, profile, room, stage_name, forced, survey)
            chain.append(PlannedStage(call, upstream))
        (rooms if room.id in requested else others)[room.id] = chain
    after = []
    for stage in after_stages:
        required = [name for name in stage.upstream if name not in stage.optional]
        if any(name not in available for name in required):  # fusion needs a plan: none, no fusion
            continue
        force = stage.name in forced_after or (BUILDING, stage.name) in req.force
        call = make_call(req.work, cfg, profile, None, stage.name, force, survey)
        upstream = {name: (BUILDING, name) for name in stage.upstream if name in available}
        after.append(PlannedStage(call, upstream, stage.room_upstream))
        available.add(stage.name)
    return SurveyPlan(before, rooms, after, others)


def fan_in_for(
    item: PlannedStage,
    results: dict[tuple[str, str], StageResult],
    failures: dict[str, str],
    room_ids: list[str],
) -> FanIn:
    """A building-after stage's rooms: each room's results of the stages it reads; a room whose chain did
    not finish is failed, with its first error."""
    fan = FanIn()
    for room in room_ids:
        got = {s: results[(room, s)] for s in item.room_upstream if (room, s) in results}
        if room in failures:
            fan.failed[room] = failures[room]
        elif got:
            fan.rooms[room] = got
        else:
            fan.failed[room] = "no result"
    return fan


def current_results(
    plan: SurveyPlan, chains: dict[str, list[PlannedStage]]
) -> dict[tuple[str, str], StageResult]:
    """The results of `chains` that are current for today's inputs, config and code, from the store alone
    (building-before results as the plan's own, when they are current)."""
    found: dict[tuple[str, str], StageResult] = {}
    for item in [*plan.before, *(i for chain in chains.values() for i in chain)]:
        call = item.call
        if any(ref not in found for ref in item.upstream.values()):
            continue
        store = store_for(call.work)
        hit = store.lookup(
            call.room, call.stage, cache_key(call, {n: found[r] for n, r in item.upstream.items()})
        )
        if hit is not None:
            found[item.ref] = hit
    return found


@dataclass(frozen=True)
class StageOutcome:
    room: str
    stage: str
    state: str
    """"computed", "cached" (Prefect cache hit), "stored" (store hit, Prefect record new), "failed", "skipped"."""
    seconds: float
    error: str = ""
    result: StageResult | None = None


def room_failures(rows: list[StageOutcome]) -> dict[str, str]:
    """Room -> the first error of a room whose chain did not finish."""
    failures: dict[str, str] = {}
    for row in rows:
        if row.room != BUILDING and row.state in ("failed", "skipped") and row.room not in failures:
            failures[row.room] = f"{row.stage}: {row.error}"
    return failures


def deliverable_files(rows: list[StageOutcome]) -> dict[tuple[str, ...], tuple[Path, str]]:
    """outputs/-relative path -> (artefact file, sha256) of every finished deliverable; a later stage's
    file replaces an earlier one of the same name (fusion's plan-frame walls replace the room frame's)."""
    files: dict[tuple[str, ...], tuple[Path, str]] = {}
    for row in rows:
        if row.result is None:
            continue
        stage = STAGES[row.stage]
        folder = () if row.room == BUILDING else ("rooms", row.room)
        for name in stage.deliverables:
            if name in row.result.files:
                files[(*folder, name)] = (row.result.file(name), row.result.files[name])
        for name in stage.room_deliverables:
            for room in (f[: -len(name) - 1] for f in row.result.files if f.endswith(f".{name}")):
                source = f"{room}.{name}"
                files[("rooms", room, name)] = (row.result.file(source), row.result.files[source])
    return files


def publish_deliverables(store: ArtefactStore, rows: list[StageOutcome]) -> None:
    """Copy finished deliverables to outputs/ (rooms' to outputs/rooms/<id>/), only what changed."""
    for relative, (source, digest) in deliverable_files(rows).items():
        dest = store.outputs.joinpath(*relative)
        if not (dest.is_file() and sha256_file(dest) == digest):
            store.publish(source, *relative)


def save_resolved_config(work: Path, cfg: cfgmod.PipelineConfig, argv: Iterable[str]) -> Path:
    """The resolved config of this run, beside the run's log, for the record."""
    stamp = time.strftime("%Y%m%dT%H%M%S")
    path = Path(work) / "runs" / stamp / "config.yaml"
    with atomic_path(path) as tmp:
        tmp.write_text(f"# indoor-survey {' '.join(argv)}\n" + cfgmod.to_yaml(cfg))
    return path


def run_chain(
    work: str | Path,
    cfg: cfgmod.PipelineConfig,
    profile: dict[str, Any],
    stage_names: list[str],
    room: cfgmod.RoomSpec | None = None,
    raw_inputs: dict[str, str] | None = None,
    params: dict[str, Any] | None = None,
) -> dict[str, StageResult]:
    """Stages run in order through load-or-compute without Prefect (the one-off CLI verbs), each reading
    the earlier ones' results: the same stage code and cache as `run`. `raw_inputs` and `params` give
    what a survey would (a plan image and its scale, a calibration folder)."""
    results: dict[str, StageResult] = {}
    for name in stage_names:
        call = make_call(work, cfg, profile, room, name)
        stage = STAGES[name]
        given = {k: v for k, v in (raw_inputs or {}).items() if k in stage.raw_inputs}
        call = replace(
            call, raw_inputs={**call.raw_inputs, **given}, params={**call.params, **(params or {})}
        )
        upstream = {n: results[n] for n in stage.upstream if n in results}
        results[name] = execute(call, upstream).result
    store_for(work).save_memo()
    return results


def export(result: StageResult, names: Iterable[str], out_dir: Path) -> list[Path]:
    """Copy a stage's files to a user's folder, each atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name in names:
        with atomic_path(out_dir / name) as tmp:
            tmp.write_bytes(result.file(name).read_bytes())
        written.append(out_dir / name)
    return written


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
    plan = plan_survey(req, cfg, survey, profile)
    done = current_results(plan, plan.others)  # rooms outside the request: read, never run
    states = []
    for item in plan.items():
        call = item.call
        previous = store.latest(call.room, call.stage)
        waiting = sorted({ref[1] for ref in item.upstream.values() if ref not in done})
        if item.room_upstream:
            chains = {**plan.rooms, **plan.others}
            waiting += sorted(
                {
                    r
                    for r, chain in chains.items()
                    for i in chain
                    if i.call.stage in item.room_upstream and i.ref not in done
                }
            )
        if waiting:
            status = "stale" if previous else "missing"
            states.append(StageState(item, status, None, f"waits for {', '.join(waiting)}"))
            continue
        fan_in = fan_in_for(item, done, {}, survey.room_ids) if item.room_upstream else None
        key = cache_key(call, {name: done[ref] for name, ref in item.upstream.items()}, fan_in)
        hit = None if call.force else store.lookup(call.room, call.stage, key)
        if hit:
            done[item.ref] = hit
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
    if any((room, "walls") not in results for room in survey.room_ids):  # rooms outside this run
        for state in survey_state(replace(req, rooms=(), force=())):
            if state.result is not None:
                results.setdefault(state.planned.ref, state.result)
    path = store_for(req.work).outputs / "metrics.json"
    earlier = _earlier_room_metrics(path)
    runs, kept = [], []
    for room in survey.room_ids:
        walls = results.get((room, "walls"))
        if walls is None:  # failed now: its outputs/rooms/<id>/ are the earlier run's, and so are its figures
            if room in earlier:
                kept.append({**earlier[room], "earlier_run": True})
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
    metrics["rooms"] += kept
    fuse = results.get((BUILDING, "fuse"))
    if fuse is not None:
        from tasks.fuse.truth import fusion_figures

        rooms = {
            room: {stage: result for (r, stage), result in results.items() if r == room}
            for room in survey.room_ids
        }
        metrics["fusion"] = fusion_figures(survey.truth, rooms, fuse, results.get((BUILDING, "changes")))
    return write_json(path, metrics)


def _earlier_room_metrics(path: Path) -> dict[str, dict[str, Any]]:
    """Room -> its entry in an earlier metrics.json (none when there is none or it is unreadable)."""
    from tasks.artefacts import ArtefactError, read_json

    try:
        rooms = read_json(path).get("rooms", []) if path.is_file() else []
    except (ArtefactError, AttributeError):
        return {}
    return {r["room"]: r for r in rooms if isinstance(r, dict) and "room" in r}
