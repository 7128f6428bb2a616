"""What a report shows, read from a work directory without recomputing anything.

Where a run wrote `outputs/manifest.json` (the run's record: every stage's state, timing and cache key, each
room's state and error, the versions), it says which stage folders the report reads and how each stage
went. Without it (an older run), the store itself says: every published deliverable names, by its content
hash, the stage folder that made it, and each folder's manifest names its inputs by their content hashes,
so the chain of folders behind `outputs/` is found again exactly, each room's from the run that last
computed it. Timings then come from the folders' manifests, and a folder finished after the last run
started counts as computed by it.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import platform
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tasks.artefacts import BUILDING, ArtefactError, ArtefactStore, read_json, read_table, sha256_file
from tasks.stages import STAGES

RUN_MANIFEST = "manifest.json"
"""outputs/manifest.json: the record of the last run (state, seconds and key of every stage)."""

KEY_LIBRARIES = {
    "indoor-survey": ("indoor-survey",),
    "numpy": ("numpy",),
    "open3d": ("open3d-cpu", "open3d"),
    "pycolmap": ("pycolmap",),
    "prefect": ("prefect",),
    "opencv": ("opencv-python-headless", "opencv-python"),
    "shapely": ("shapely",),
}


@dataclass(frozen=True)
class StageRow:
    """One stage of one room (room BUILDING for the building's stages) as the report shows it."""

    room: str
    stage: str
    state: str
    """"computed", "cached", "failed", "skipped" or "earlier run" (a result an earlier run made)."""
    seconds: float
    error: str = ""
    key: str = ""
    code_version: str = ""
    folder: Path | None = None
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def metrics(self) -> dict[str, Any]:
        metrics = self.manifest.get("metrics")
        return metrics if isinstance(metrics, dict) else {}

    def file(self, name: str) -> Path | None:
        """A file of the stage's folder, when the folder has it."""
        if self.folder is None or name not in (self.manifest.get("files") or {}):
            return None
        return self.folder / name


@dataclass
class RoomData:
    room: str
    stages: dict[str, StageRow] = field(default_factory=dict)
    state: str = "done"
    """"done" or "failed" (in the last run that ran it; its data are then an earlier run's, if any)."""
    error: str = ""
    plan_room: str = ""

    def metrics(self, stage: str) -> dict[str, Any]:
        row = self.stages.get(stage)
        return row.metrics if row else {}


@dataclass
class ReportData:
    work: Path
    rooms: dict[str, RoomData]
    building: dict[str, StageRow]
    rows: list[StageRow]
    """Every stage of the last run, in run order (the run section's table)."""
    run: dict[str, Any]
    """run_id, finished, config_hash, partial; "source": "manifest" or "store"."""
    versions: dict[str, str]
    config_changes: list[tuple[str, str, str]]
    """(dotted key, default value, value of the run) for every setting that differs from the defaults."""
    config_file: Path | None
    metrics: dict[str, Any] | None
    """outputs/metrics.json (accuracy against truth), when the survey has truth."""
    notes: list[str] = field(default_factory=list)
    """What could not be read, one line each (the report still shows the rest)."""
    survey: str = ""
    """The survey folder the last run read, as its command line named it (its saved config's first line)."""


# ------------------------------------------------------------------------------------------- the store


class _Folders:
    """Every committed stage folder of a work dir, indexed by (room, stage): read once, never hashed again
    beyond the deliverables that name them."""

    def __init__(self, store: ArtefactStore) -> None:
        self.store = store
        self.by_stage: dict[tuple[str, str], list[tuple[Path, dict[str, Any]]]] = {}
        if not store.cache.is_dir():
            return
        for root in sorted(store.cache.iterdir()):
            if not root.is_dir():
                continue
            for stage_root in sorted(root.iterdir()):
                if stage_root.name not in STAGES or not stage_root.is_dir():
                    continue
                found = []
                for folder in sorted(stage_root.iterdir()):
                    path = folder / "manifest.json"
                    if folder.name.startswith(".") or not path.is_file():
                        continue
                    try:
                        manifest = read_json(path)
                    except ArtefactError:
                        continue
                    if isinstance(manifest, dict) and isinstance(manifest.get("files"), dict):
                        found.append((folder, manifest))
                self.by_stage[(root.name, stage_root.name)] = found

    def by_key(self, room: str, stage: str, key: str) -> tuple[Path, dict[str, Any]] | None:
        for folder, manifest in self.by_stage.get((room, stage), []):
            if manifest.get("key") == key:
                return folder, manifest
        return None

    def by_content(self, room: str, stage: str, content_hash: str) -> tuple[Path, dict[str, Any]] | None:
        """The folder whose files hash to `content_hash` (the latest, when runs of other code made the same
        bytes)."""
        hits = [
            (f, m) for f, m in self.by_stage.get((room, stage), []) if m.get("content_hash") == content_hash
        ]
        return max(hits, key=lambda fm: fm[1].get("finished_at", 0)) if hits else None

    def by_file(self, room: str, stage: str, name: str, digest: str) -> tuple[Path, dict[str, Any]] | None:
        """The folder that holds file `name` with this sha256 (the latest, when several do)."""
        hits = [(f, m) for f, m in self.by_stage.get((room, stage), []) if m["files"].get(name) == digest]
        return max(hits, key=lambda fm: fm[1].get("finished_at", 0)) if hits else None


def _published(store: ArtefactStore, room: str, stage: str, folders: _Folders) -> tuple[Path, dict] | None:
    """The folder of `stage` whose deliverable was published to outputs/ (a room's to outputs/rooms/<id>/),
    found by the deliverable's content hash. A deliverable another stage replaces (fusion's plan-frame
    walls) is not used."""
    replaced = {name for s in STAGES.values() for name in s.room_deliverables}
    base = store.outputs if room == BUILDING else store.outputs / "rooms" / room
    for name in STAGES[stage].deliverables:
        if room != BUILDING and name in replaced:
            continue
        path = base / name
        if path.is_file():
            hit = folders.by_file(room, stage, name, sha256_file(path))
            if hit is not None:
                return hit
    return None


def _trace(
    room: str, stage: str, found: tuple[Path, dict], folders: _Folders, into: dict[tuple[str, str], tuple]
) -> None:
    """Record a stage folder and, through its manifest's input content hashes, the folders it read."""
    if (room, stage) in into:
        return
    into[(room, stage)] = found
    for name, content_hash in (found[1].get("inputs") or {}).items():
        if name not in STAGES or not isinstance(content_hash, str):
            continue
        up_room = BUILDING if STAGES[name].partition != "room" else room
        hit = folders.by_content(up_room, name, content_hash)
        if hit is not None:
            _trace(up_room, name, hit, folders, into)


# --------------------------------------------------------------------------------------------- reading


def _run_manifest(store: ArtefactStore) -> dict[str, Any] | None:
    path = store.outputs / RUN_MANIFEST
    if not path.is_file():
        return None
    data = read_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("stages", []), list):
        raise ArtefactError(f"{path}: not a run manifest (expected an object with a 'stages' list)")
    return data


def _room_ids(store: ArtefactStore, folders: _Folders, notes: list[str]) -> tuple[list[str], dict[str, dict]]:
    """The survey's rooms in its order (floor_index's rooms.parquet, else what the store holds) and what
    floor_index says of each (plan_room, error)."""
    ids: list[str] = []
    info: dict[str, dict] = {}
    path = store.outputs / "rooms.parquet"
    if path.is_file():
        try:
            for row in read_table(path).to_pylist():
                ids.append(str(row["room_id"]))
                info[str(row["room_id"])] = row
        except (ArtefactError, KeyError) as exc:
            notes.append(f"{path}: unreadable ({exc})")
    more = {room for room, _ in folders.by_stage if room != BUILDING}
    rooms_dir = store.outputs / "rooms"
    if rooms_dir.is_dir():
        more |= {p.name for p in rooms_dir.iterdir() if p.is_dir()}
    ids += sorted(more - set(ids))
    return ids, info


def _run_started(work: Path) -> tuple[float | None, Path | None]:
    """When the last run started (its runs/<stamp>/ folder, stamped in local time) and its config file."""
    runs = sorted(
        p for p in (work / "runs").glob("*/config.yaml") if re.fullmatch(r"\d{8}T\d{6}", p.parent.name)
    )
    if not runs:
        return None, None
    stamp = runs[-1].parent.name
    return time.mktime(time.strptime(stamp, "%Y%m%dT%H%M%S")), runs[-1]


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        flat: dict[str, Any] = {}
        for key, value in data.items():
            flat.update(_flatten(value, f"{prefix}{key}."))
        return flat
    return {prefix[:-1]: data}


def config_changes(run_config: Path) -> list[tuple[str, str, str]]:
    """(key, default, run's value) of every setting of a run's saved config.yaml that differs from the
    defaults (configs/default.yaml over the code's defaults); "-" where one side lacks the key."""
    import yaml

    from tasks import config as cfgmod

    defaults = _flatten(cfgmod._plain(dataclasses.asdict(cfgmod.load_config())))
    try:  # written by yaml.safe_dump: the C loader reads it 10x faster than the checked reader
        ran = yaml.load(Path(run_config).read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        ran = cfgmod.read_yaml(run_config)  # its one-line error names the file and line
    ran = _flatten(ran or {})
    changes = []
    for key in sorted(set(defaults) | set(ran)):
        a, b = defaults.get(key, "-"), ran.get(key, "-")
        if a != b:
            changes.append((key, str(a), str(b)))
    return changes


def installed_versions() -> dict[str, str]:
    """The versions of the code and key libraries installed now."""
    versions = {"python": platform.python_version()}
    for name, dists in KEY_LIBRARIES.items():
        for dist in dists:
            try:
                versions[name] = importlib.metadata.version(dist)
                break
            except importlib.metadata.PackageNotFoundError:
                continue
    return versions


def gather(work: Path) -> ReportData:
    """Everything the report shows, from the work dir alone (nothing is recomputed)."""
    work = Path(work).resolve()
    store = ArtefactStore(work)
    store.read_only = True
    if not store.outputs.is_dir() and not store.cache.is_dir():
        raise ValueError(f"{work}: no outputs/ or cache/ here: not the work dir of an `indoor-survey run`")
    notes: list[str] = []
    folders = _Folders(store)
    record = _run_manifest(store)
    room_ids, index = _room_ids(store, folders, notes)
    started, config_file = _run_started(work)

    # the folders behind outputs/: the run manifest's keys first, then the deliverables' content hashes
    traced: dict[tuple[str, str], tuple[Path, dict]] = {}
    listed: dict[tuple[str, str], dict[str, Any]] = {}
    for entry in (record or {}).get("stages", []):
        if not isinstance(entry, dict) or entry.get("stage") not in STAGES:
            continue
        room = entry.get("room") or BUILDING
        listed[(room, entry["stage"])] = entry
        hit = folders.by_key(room, entry["stage"], str(entry.get("key") or ""))
        if hit is not None:
            _trace(room, entry["stage"], hit, folders, traced)
    for room in [BUILDING, *room_ids]:
        for stage in STAGES.values():
            if (stage.partition == "room") == (room != BUILDING) and (room, stage.name) not in traced:
                hit = _published(store, room, stage.name, folders)
                if hit is not None:
                    _trace(room, stage.name, hit, folders, traced)

    def row(room: str, stage: str) -> StageRow | None:
        entry = listed.get((room, stage))
        hit = traced.get((room, stage))
        folder, manifest = hit if hit else (None, {})
        if entry is not None:
            state = str(entry.get("state", ""))
            seconds = float(entry.get("seconds") or 0.0)
            if state in ("failed", "skipped") and hit is not None:
                state = f"{state}; earlier result shown"
            return StageRow(
                room,
                stage,
                state,
                seconds,
                str(entry.get("error") or ""),
                str(entry.get("key") or manifest.get("key", "")),
                str(manifest.get("code_version", "")),
                folder,
                manifest,
            )
        if hit is None:
            return None
        finished = float(manifest.get("finished_at") or 0.0)
        computed = started is not None and finished >= started
        return StageRow(
            room,
            stage,
            "computed" if computed else "cached",
            float(manifest.get("compute_seconds") or 0.0) if computed else 0.0,
            "",
            str(manifest.get("key", "")),
            str(manifest.get("code_version", "")),
            folder,
            manifest,
        )

    building = {s: r for s in STAGES if (r := row(BUILDING, s)) is not None}
    rooms: dict[str, RoomData] = {}
    room_records = (record or {}).get("rooms") if isinstance((record or {}).get("rooms"), dict) else {}
    failed_fanin = building.get("floor_index") or building.get("fuse")
    failed_rooms = (failed_fanin.manifest.get("failed_rooms") or {}) if failed_fanin else {}
    for room in room_ids:
        data = RoomData(room)
        for stage in STAGES.values():
            if stage.partition == "room" and (r := row(room, stage.name)) is not None:
                data.stages[stage.name] = r
        entry = room_records.get(room) if isinstance(room_records, dict) else None
        error = ""
        if isinstance(entry, dict):
            error = str(entry.get("error") or "") if entry.get("state") == "failed" else ""
            if entry.get("state") == "failed" and not error:
                error = "failed"
        elif room in failed_rooms:
            error = str(failed_rooms[room])
        elif index.get(room, {}).get("error"):
            error = str(index[room]["error"])
        if error:
            data.state, data.error = "failed", error
        data.plan_room = str(index.get(room, {}).get("plan_room") or "")
        rooms[room] = data

    rows = [r for r in building.values() if STAGES[r.stage].partition == "before"]
    rows += [r for data in rooms.values() for r in data.stages.values()]
    rows += [r for r in building.values() if STAGES[r.stage].partition == "after"]
    for (room, stage), entry in listed.items():  # failed or skipped stages with no folder at all
        if (room, stage) not in traced and entry.get("state") in ("failed", "skipped"):
            rows.append(row(room, stage))  # type: ignore[arg-type]

    versions = {str(k): str(v) for k, v in ((record or {}).get("versions") or {}).items()}
    if not versions:
        versions = {f"{name} (installed now)": v for name, v in installed_versions().items()}
    run = {
        "source": "manifest" if record else "store",
        "run_id": str((record or {}).get("run_id") or (config_file.parent.name if config_file else "")),
        "finished": str((record or {}).get("finished") or ""),
        "config_hash": str((record or {}).get("config_hash") or ""),
        "partial": bool((record or {}).get("partial", False)),
    }
    if not run["finished"]:
        last = max((float(r.manifest.get("finished_at") or 0) for r in rows), default=0.0)
        run["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(last)) if last else ""
    changes: list[tuple[str, str, str]] = []
    if config_file is not None:
        try:
            changes = config_changes(config_file)
        except ValueError as exc:
            notes.append(f"configuration differences not shown: {exc}")
    metrics = None
    path = store.outputs / "metrics.json"
    if path.is_file():
        try:
            metrics = read_json(path)
        except ArtefactError as exc:
            notes.append(str(exc))
    survey = ""
    if config_file is not None:
        words = config_file.read_text(errors="replace").split("\n", 1)[0].split()
        verbs = [i for i, w in enumerate(words) if w in ("run", "rerun")]
        if words[:1] == ["#"] and verbs and verbs[0] + 1 < len(words):
            survey = words[verbs[0] + 1]
    return ReportData(
        work, rooms, building, rows, run, versions, changes, config_file, metrics, notes, survey
    )


def utc(seconds: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(seconds))


__all__ = ["ReportData", "RoomData", "StageRow", "config_changes", "gather", "installed_versions"]
