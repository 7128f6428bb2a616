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


def outputs_mismatch(work: Path, config_files: list[Path], sets: list[str]) -> list[str]:
    """Lines flagging deliverables in WORK/outputs that another configuration made (from
    outputs/manifest.json): each room whose outputs/rooms/<id>/ came from a run with another config
    hash, a room whose last run failed (its outputs are an earlier run's), and the building's outputs
    when the last run had another configuration. Empty when everything matches."""
    from flows.planning import config_hash, read_outputs_manifest
    from tasks import config as cfgmod

    manifest = read_outputs_manifest(work)
    if manifest is None:
        return []
    current = config_hash(cfgmod.load_config(list(config_files), list(sets)))
    lines = []
    if manifest.get("config_hash") != current:
        lines.append(
            f"outputs/: last written by run {manifest.get('run_id')} with config {str(manifest.get('config_hash'))[:12]}, "
            f"not the current configuration ({current[:12]}): building outputs may not match it"
        )
    for room, entry in sorted(manifest["rooms"].items()):
        if not isinstance(entry, dict):
            continue
        if entry.get("state") != "done":
            lines.append(
                f"outputs/rooms/{room}/: its last run failed ({entry.get('error', '')}); earlier outputs kept"
            )
        if entry.get("config_hash") != current:
            made = entry.get("config_hash") or "none"
            lines.append(
                f"outputs/rooms/{room}/: from run {entry.get('run_id') or 'none'} with config {made[:12]}, "
                f"not the current configuration ({current[:12]})"
            )
    return lines
