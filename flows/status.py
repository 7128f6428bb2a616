"""`indoor-survey status`: per room and stage, done (a verified artefact for today's inputs, config and
code), stale (an older artefact exists, but something it depends on changed) or missing. Reads the
artefact store only; starts no Prefect server."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from flows.pipeline import RunRequest, cache_key, plan_survey, store_for
from tasks import config as cfgmod
from tasks.artefacts import StageResult


@dataclass(frozen=True)
class StatusRow:
    room: str
    stage: str
    status: str
    detail: str


def _when(result: StageResult) -> str:
    finished = result.manifest.get("finished_at", 0)
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(finished))


def survey_status(survey_dir: Path, work: Path, config_files: list[Path], sets: list[str]) -> list[StatusRow]:
    cfg = cfgmod.load_config(config_files, sets)
    survey = cfgmod.load_survey(survey_dir)
    profile = cfgmod.load_sensor_profile(survey.sensor)
    store = store_for(work)
    req = RunRequest(survey=str(survey.root), work=str(Path(work).resolve()))
    done: dict[tuple[str, str], StageResult] = {}
    rows = []
    for item in plan_survey(req, cfg, survey, profile):
        call = item.call
        previous = store.latest(call.room, call.stage)
        waiting = [f"{stage}" for ref in item.upstream.values() if ref not in done for stage in [ref[1]]]
        if waiting:
            status = "stale" if previous else "missing"
            rows.append(StatusRow(call.room, call.stage, status, f"waits for {', '.join(waiting)}"))
            continue
        key = cache_key(call, {name: done[ref] for name, ref in item.upstream.items()})
        hit = store.lookup(call.room, call.stage, key)
        if hit:
            done[(call.room, call.stage)] = hit
            rows.append(StatusRow(call.room, call.stage, "done", f"{key[:12]} at {_when(hit)}"))
        elif previous:
            rows.append(
                StatusRow(
                    call.room,
                    call.stage,
                    "stale",
                    f"last run {_when(previous)}; inputs, config or code changed",
                )
            )
        else:
            rows.append(StatusRow(call.room, call.stage, "missing", "never run"))
    store.save_memo()
    return rows
