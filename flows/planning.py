"""Planning and running stage calls without an orchestrator: which stages a survey implies, their cache
keys, load-or-compute of one stage, and the current state of a work dir. Prefect (flows/pipeline.py)
wraps `execute` in tasks; `status`, the no-op fast path of `run` and `model-room` use this module alone,
so they never pay Prefect's start-up.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import os
import platform
import threading
import time
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from flows import memory
from tasks import config as cfgmod
from tasks import stages as stagesmod
from tasks.artefacts import (
    BUILDING,
    ArtefactError,
    ArtefactStore,
    StageResult,
    atomic_path,
    hash_json,
    sha256_file,
    write_json,
)
from tasks.context import StageContext
from tasks.ingest.capture import capture_kind
from tasks.stages import STAGES, load_class, stages_of

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
    run_id: str = ""
    """The run that makes this call, and the hash of its whole configuration: recorded in the manifest of
    what it computes (never in the key), so outputs/manifest.json can say which run computed a stage."""
    config_hash: str = ""


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
        "run_id": call.run_id,
        "config_hash": call.config_hash,
    }
    without = ran_without(call, upstream)
    if without:
        manifest["ran_without"] = without
        log.info("[%s] %s: runs without %s", call.room, call.stage, ", ".join(without))
    if fan_in.rooms or fan_in.failed:
        manifest["rooms"] = {room: sorted(results) for room, results in fan_in.rooms.items()}
        manifest["failed_rooms"] = fan_in.failed
    run = stage.runner()

    def write(out: Path) -> dict[str, Any]:
        t0 = time.perf_counter()
        report = run(ctx, cfg, out)  # {"metrics": {...}, other manifest entries...}
        if without and isinstance(report.get("metrics"), dict):
            report = {**report, "metrics": {**report["metrics"], "ran_without": without}}
        return {**report, "compute_seconds": round(time.perf_counter() - t0, 3)}

    result = store.commit(call.room, call.stage, key, write, manifest)
    memory.release()  # what the stage freed goes back, so a run's RSS does not ratchet up room by room
    seconds = time.perf_counter() - started
    log.info("[%s] %s: done in %.1f s", call.room, call.stage, seconds)
    return Executed(result, "computed", seconds)


def ran_without(call: StageCall, upstream: dict[str, StageResult]) -> list[str]:
    """The optional inputs a stage call runs without: optional upstream stages that failed or are not
    part of the survey (register without plan or calibrate), and optional raw survey files the survey
    lacks (a track)."""
    stage = STAGES[call.stage]
    missing = [name for name in stage.optional if name not in upstream]
    missing += [
        name for name in stage.raw_inputs if name not in REQUIRED_RAW_INPUTS and name not in call.raw_inputs
    ]
    return missing


def capture_problem(capture: Path) -> str | None:
    """Why a room's capture cannot be read at all (missing, unreadable, of a kind no reader takes), in one
    line naming it; None when it can be handed to ingest (which checks its content)."""
    capture = Path(capture)
    if not capture.exists():
        return f"capture {capture} does not exist"
    try:
        if capture.is_dir():
            os.listdir(capture)
        else:
            with open(capture, "rb") as fh:
                fh.read(1)
    except OSError as exc:
        return f"capture {capture} cannot be read ({exc.strerror or exc})"
    try:
        capture_kind(capture)
    except (ValueError, OSError) as exc:
        return " ".join(str(exc).split())
    return None


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
    run_id: str = field(default_factory=lambda: new_run_id())
    """This run's id (UTC start time and a random suffix), recorded with what it computes."""


def new_run_id() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ") + "-" + uuid.uuid4().hex[:6]


def config_hash(cfg: cfgmod.PipelineConfig) -> str:
    """Hash of the whole resolved configuration but `flow` (how stages are scheduled changes no
    artefact): what outputs/manifest.json records and `status` compares."""
    return hash_json({name: cfgmod.section(cfg, name) for name in cfgmod.STAGE_SECTIONS})


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
    failed: dict[str, str] = field(default_factory=dict)
    """Requested rooms that fail before any stage runs (a missing or unreadable capture): the reason."""
    first_stage: dict[str, str] = field(default_factory=dict)
    """Room -> the stage its failure is reported on (the room's first stage)."""

    def failed_rows(self) -> list[StageOutcome]:
        """The pre-check failures as the run's outcome rows."""
        return [
            StageOutcome(room, self.first_stage.get(room, "ingest"), "failed", 0.0, reason)
            for room, reason in self.failed.items()
        ]

    def items(self) -> list[PlannedStage]:
        """The stage runs of the request, in dependency order."""
        return [*self.before, *(i for chain in self.rooms.values() for i in chain), *self.after]


def plan_survey(
    req: RunRequest, cfg: cfgmod.PipelineConfig, survey: cfgmod.Survey, profile: dict[str, Any]
) -> SurveyPlan:
    """Every stage run a request implies. A forced stage is recomputed; what follows it is recomputed only
    when that changed its artefacts (keys are content keys: a forced stage that writes the same bytes
    leaves its dependants current)."""
    requested = set(req.rooms or survey.room_ids)
    # A room whose capture cannot be read fails alone, with its reason; a room outside the request is
    # not checked (it is never run: a building-after stage reads its current results, if it has any).
    failed, chains = {}, {}
    for room in survey.rooms:
        if room.id not in requested:
            with contextlib.suppress(ValueError, OSError):  # a room without a usable capture: no chain
                chains[room.id] = room_stages(room.capture)
        elif problem := capture_problem(room.capture):
            failed[room.id] = problem
        else:
            chains[room.id] = room_stages(room.capture)
    first_stage = stages_of("room")[0].name
    after_stages = stages_of("after")
    readers = [s for chain in chains.values() for s in chain] + [s.name for s in after_stages]
    needed = {up for name in readers for up in STAGES[name].upstream}
    stamp = {"run_id": req.run_id, "config_hash": config_hash(cfg)}
    before: list[PlannedStage] = []
    for stage in stages_of("before"):
        raw = survey_inputs(survey, None, stage.name)
        missing = [n for n in stage.raw_inputs if n in REQUIRED_RAW_INPUTS and n not in raw]
        if missing or not (stage.name in needed or stage.deliverables):
            continue
        force = (BUILDING, stage.name) in req.force
        call = replace(make_call(req.work, cfg, profile, None, stage.name, force, survey), **stamp)
        before.append(PlannedStage(call, {}))
    available = {item.call.stage for item in before}
    rooms: dict[str, list[PlannedStage]] = {}
    others: dict[str, list[PlannedStage]] = {}
    for room in survey.rooms:
        if room.id not in chains:
            continue
        chain = []
        for stage_name in chains[room.id]:
            forced = (room.id, stage_name) in req.force
            upstream = {}
            for name in STAGES[stage_name].upstream:
                if name in chains[room.id][: chains[room.id].index(stage_name)]:
                    upstream[name] = (room.id, name)
                elif name in available:
                    upstream[name] = (BUILDING, name)
            call = replace(make_call(req.work, cfg, profile, room, stage_name, forced, survey), **stamp)
            chain.append(PlannedStage(call, upstream))
        (rooms if room.id in requested else others)[room.id] = chain
    after = []
    for stage in after_stages:
        required = [name for name in stage.upstream if name not in stage.optional]
        if any(name not in available for name in required):  # fusion needs a plan: none, no fusion
            continue
        force = (BUILDING, stage.name) in req.force
        call = replace(make_call(req.work, cfg, profile, None, stage.name, force, survey), **stamp)
        upstream = {name: (BUILDING, name) for name in stage.upstream if name in available}
        after.append(PlannedStage(call, upstream, stage.room_upstream))
        available.add(stage.name)
    # Every stage's code version now, in this one thread: it parses the stage's modules with `ast`, and
    # CPython 3.11's parser is not safe to run from two room threads at once ("AST constructor recursion
    # depth mismatch" failed a stage); each version is read once per process.
    for name in sorted({i.call.stage for i in [*before, *after, *(i for c in rooms.values() for i in c)]}):
        STAGES[name].code_version()
    return SurveyPlan(before, rooms, after, others, failed, dict.fromkeys(failed, first_stage))


def read_code_versions() -> None:
    """Every stage's code version, read now (once per process; see plan_survey): a run does it while
    Prefect's server starts, instead of after, when it waits for nothing else."""
    for stage in STAGES.values():
        stage.code_version()


CODE_IMPORTS_MEMO = "_code_imports.json"
"""In WORK/cache: which project modules each source imports (tasks.stages.IMPORTS_MEMO), so a run reads
its stages' code versions without parsing every module again."""


def load_code_memo(work: str | Path) -> None:
    """Read the work dir's code-imports memo (before any code version is read)."""
    stagesmod.load_imports_memo(store_for(work).cache / CODE_IMPORTS_MEMO)


def save_code_memo(work: str | Path) -> None:
    """Keep what this run found for the next (a memo that cannot be written is only a slower next run)."""
    with contextlib.suppress(OSError):
        stagesmod.save_imports_memo(store_for(work).cache / CODE_IMPORTS_MEMO)


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


def ready_inputs(
    item: PlannedStage, found: dict[tuple[str, str], StageResult]
) -> dict[str, StageResult] | None:
    """The inputs the flow gives `item` when every one of them is in `found` (its upstream map: an optional
    input the flow would pass, e.g. the plan to a room's register, is required too, since running without
    it is another key); None when any is not."""
    if any(ref not in found for ref in item.upstream.values()):
        return None
    return {name: found[ref] for name, ref in item.upstream.items()}


def current_results(
    plan: SurveyPlan,
    chains: dict[str, list[PlannedStage]],
    skip: Callable[[PlannedStage], bool] | None = None,
) -> dict[tuple[str, str], StageResult]:
    """The results of `chains` that are current for today's inputs, config and code, from the store alone
    (building-before results as the plan's own, when they are current); stage runs for which `skip` is
    true, and what reads them, are left out."""
    found: dict[tuple[str, str], StageResult] = {}
    for item in [*plan.before, *(i for chain in chains.values() for i in chain)]:
        call = item.call
        upstream = ready_inputs(item, found)
        if upstream is None or (skip is not None and skip(item)):
            continue
        store = store_for(call.work)
        try:
            key = cache_key(call, upstream)
        except (ArtefactError, OSError):  # another room's capture gone or unreadable: it has no result
            continue
        hit = store.lookup(call.room, call.stage, key)
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


def publish_deliverables(
    store: ArtefactStore, rows: list[StageOutcome], req: RunRequest | None = None
) -> None:
    """Copy finished deliverables to outputs/ (rooms' to outputs/rooms/<id>/), only what changed: every
    new file is first copied beside its destination under a temporary name, then all are renamed into
    place, so a failure while copying (a full disk) changes nothing. Then, last and atomically,
    outputs/manifest.json (with `req`: its run id and configuration; merged into the previous one)."""
    changed = {}
    for relative, (source, digest) in deliverable_files(rows).items():
        dest = store.outputs.joinpath(*relative)
        if not (dest.is_file() and sha256_file(dest) == digest):
            changed[relative] = source
    store.publish_all(changed)
    if req is not None:
        write_json(store.outputs / MANIFEST, outputs_manifest(store, rows, req))


MANIFEST = "manifest.json"
"""outputs/manifest.json: what the deliverables in outputs/ are, written last by every run."""

DONE_STATES = ("computed", "cached")


def read_outputs_manifest(work: str | Path) -> dict[str, Any] | None:
    """outputs/manifest.json of a work dir, or None when there is none or it is not one."""
    from tasks.artefacts import ArtefactError, read_json

    path = Path(work) / "outputs" / MANIFEST
    try:
        data = read_json(path) if path.is_file() else None
    except ArtefactError:
        return None
    ok = (
        isinstance(data, dict)
        and isinstance(data.get("stages"), list)
        and isinstance(data.get("rooms"), dict)
    )
    return data if ok else None


def software_versions() -> dict[str, str]:
    """The versions that make the outputs: this package, Python and the main numeric libraries."""
    from importlib import metadata

    def version(*names: str) -> str:
        for name in names:
            try:
                return metadata.version(name)
            except metadata.PackageNotFoundError:
                continue
        return "unknown"

    return {
        "indoor-survey": version("indoor-survey"),
        "python": platform.python_version(),
        "numpy": version("numpy"),
        "open3d": version("open3d", "open3d-cpu"),
        "pycolmap": version("pycolmap"),
        "prefect": version("prefect"),
    }


def outputs_manifest(store: ArtefactStore, rows: list[StageOutcome], req: RunRequest) -> dict[str, Any]:
    """This run's rows merged into the previous manifest: a room this run touched is described by this
    run alone; the other rooms', and building stages this run did not run, are kept. A cached row keeps
    the run id and config hash of the run that computed it (from the stage's cache manifest, else from
    the previous outputs manifest)."""
    cfg = cfgmod.load_config([Path(p) for p in req.config_files], list(req.sets))
    survey = cfgmod.load_survey(Path(req.survey))
    current = config_hash(cfg)
    previous = read_outputs_manifest(store.work) or {"stages": [], "rooms": {}}
    known = {
        (r.get("room"), r.get("stage"), r.get("key")): r for r in previous["stages"] if isinstance(r, dict)
    }
    stages: dict[tuple[str, str], dict[str, Any]] = {}
    for row in rows:
        room = "" if row.room == BUILDING else row.room
        state = "cached" if row.state == "stored" else row.state
        key = row.result.key if row.result is not None else ""
        made_by = {"run_id": req.run_id, "config_hash": current}
        if state == "cached" and row.result is not None:
            try:
                manifest = row.result.manifest
            except Exception:  # an unreadable manifest would have failed the lookup; be safe anyway
                manifest = {}
            earlier = known.get((room, row.stage, key), {})
            made_by = {
                name: manifest.get(name) or earlier.get(name) or "" for name in ("run_id", "config_hash")
            }
        stages[(room, row.stage)] = {
            "room": room,
            "stage": row.stage,
            "state": state,
            "seconds": float(row.seconds),
            "error": " ".join(row.error.split()),
            "key": key,
            **made_by,
        }
    valid_rooms = set(survey.room_ids)
    touched = {row.room for row in rows if row.room != BUILDING}
    for old in previous["stages"]:
        if not isinstance(old, dict):
            continue
        room, stage = old.get("room", ""), old.get("stage", "")
        if (room, stage) in stages or room in touched or (room and room not in valid_rooms):
            continue
        if stage not in STAGES:
            continue
        stages[(room, stage)] = old
    rooms: dict[str, dict[str, Any]] = {}
    for room in survey.room_ids:
        earlier = previous["rooms"].get(room)
        if room not in touched:
            if isinstance(earlier, dict):
                rooms[room] = earlier
            continue
        own = [r for r in rows if r.room == room]
        bad = next((r for r in own if r.state not in (*DONE_STATES, "stored")), None)
        if bad is None:
            rooms[room] = {"run_id": req.run_id, "config_hash": current, "state": "done", "error": ""}
        else:  # its outputs/rooms/<id>/ are still an earlier run's (if any run published them)
            rooms[room] = {
                "run_id": earlier.get("run_id", "") if isinstance(earlier, dict) else "",
                "config_hash": earlier.get("config_hash", "") if isinstance(earlier, dict) else "",
                "state": "failed",
                "error": f"{bad.stage}: {' '.join(bad.error.split())}",
            }
    order = {name: i for i, name in enumerate(STAGES)}
    ordered = sorted(stages.values(), key=lambda r: (r["room"] != "", r["room"], order.get(r["stage"], 99)))
    partial = any(r["state"] not in DONE_STATES for r in ordered) or any(
        r["state"] != "done" for r in rooms.values()
    )
    return {
        "run_id": req.run_id,
        "finished": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "config_hash": current,
        "partial": partial,
        "stages": ordered,
        "rooms": rooms,
        "versions": software_versions(),
    }


def exit_state(rows: list[StageOutcome]) -> str:
    """ "done" (nothing failed or was skipped), "partial" (something failed, but at least one room
    finished every stage) or "failed" (no room finished: every room failed, e.g. because a stage they
    all need failed)."""
    if all(r.state in (*DONE_STATES, "stored") for r in rows):
        return "done"
    rooms: dict[str, bool] = {}
    for row in rows:
        if row.room != BUILDING:
            rooms[row.room] = rooms.get(row.room, True) and row.state in (*DONE_STATES, "stored")
    return "partial" if any(rooms.values()) else "failed"


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
    but something it depends on changed), "missing", or "failed" (the room's capture cannot be read)."""
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
    for room, reason in plan.failed.items():  # fails before any stage: the capture cannot be read
        call = make_call(req.work, cfg, profile, survey.room(room), plan.first_stage[room], survey=survey)
        states.append(StageState(PlannedStage(call, {}), "failed", None, reason))
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
    if req.force or any(s.status not in ("done", "failed") for s in states):
        return None
    rows = [
        StageOutcome(s.planned.call.room, s.planned.call.stage, "cached", 0.0, "", s.result)
        if s.status == "done"
        else StageOutcome(s.planned.call.room, s.planned.call.stage, "failed", 0.0, s.detail)
        for s in states
    ]
    publish_deliverables(store_for(req.work), rows, req)
    return rows


def write_truth_metrics(req: RunRequest, rows: list[StageOutcome]) -> Path | None:
    """outputs/metrics.json: each room model against the survey's truth/, when it has one."""
    survey = cfgmod.load_survey(Path(req.survey))
    if survey.truth is None or not (survey.truth / "walls.parquet").is_file():
        return None
    from tasks.benchmark import RoomRun, evaluate_runs  # only for a survey with truth/: 0.4 CPU s of imports

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
