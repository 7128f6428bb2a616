"""`indoor-survey status`: per room and stage, done, stale or missing (flows.planning.survey_state).
Reads the artefact store only; starts no Prefect server."""

from __future__ import annotations

from pathlib import Path

from flows.planning import RunRequest, StageState, survey_state


def survey_status(
    survey_dir: Path, work: Path, config_files: list[Path], sets: list[str]
) -> list[StageState]:
    req = RunRequest(
        survey=str(survey_dir),
        work=str(Path(work).resolve()),
        config_files=tuple(map(str, config_files)),
        sets=tuple(sets),
    )
    return survey_state(req)
