"""`indoor-survey status`: per room and stage, done (a verified artefact for today's inputs, config and
code), stale (an older artefact exists, but something it depends on changed) or missing. Reads the
artefact store only; starts no Prefect server."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from flows.pipeline import UPSTREAM, cache_key, make_call, room_stages, store_for
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
    rows = []
    for room in survey.rooms:
        done: dict[str, StageResult] = {}
        for stage in room_stages(room.capture):
            needs = [name for name in UPSTREAM.get(stage, ()) if name in room_stages(room.capture)]
            previous = store.latest(room.id, stage)
            if any(name not in done for name in needs):
                status = "stale" if previous else "missing"
                rows.append(StatusRow(room.id, stage, status, f"waits for {', '.join(needs)}"))
                continue
            call = make_call(work, cfg, profile, room, stage)
            key = cache_key(call, {name: done[name] for name in needs})
            hit = store.lookup(room.id, stage, key)
            if hit:
                done[stage] = hit
                rows.append(StatusRow(room.id, stage, "done", f"{key[:12]} at {_when(hit)}"))
            elif previous:
                rows.append(
                    StatusRow(
                        room.id, stage, "stale", f"last run {_when(previous)}; inputs, config or code changed"
                    )
                )
            else:
                rows.append(StatusRow(room.id, stage, "missing", "never run"))
    store.save_memo()
    return rows
