"""The stage table: the one registry of stages.

Each stage declares its partition (a building stage that runs before the rooms, a room stage, or a
building stage that runs after every room: a fan-in), the stages whose results it reads, the raw survey
files it reads, its config section and its deliverables. Its computation lives in one entry module with
`run(ctx, cfg, out)` (tasks.context); its config in a small dataclass module. Orchestration (flows/) is
generic over this table: adding a stage means its module, one entry here and its config section.

This module imports no stage computation: entry modules and config classes are named, and loaded when
used.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:  # the table loads no stage code, nor the artefact store
    from tasks.context import StageRun

Partition = Literal["before", "room", "after"]
""""before": a building stage the rooms may read (calibrate, plan); "room": runs once per room;
"after": a building stage over every room's results (fan-in)."""

REPO_ROOT = Path(__file__).resolve().parents[1]
PROJECT_PACKAGES = ("tasks", "flows")


@dataclass(frozen=True)
class Stage:
    name: str
    partition: Partition
    module: str
    """The entry module: defines `run(ctx, cfg, out)`."""
    config: str
    """"module:Class" of the stage's config section (named like the stage)."""
    upstream: tuple[str, ...] = ()
    """Stages whose results it reads. For a room stage: the room's own stages (those that apply to the
    room) or the building's "before" stages; for an "after" stage: the building's stages."""
    optional: tuple[str, ...] = ()
    """Upstream stages it can run without when they failed (it is then told so, and says so)."""
    room_upstream: tuple[str, ...] = ()
    """"after" stages only: every room's results of these stages."""
    raw_inputs: tuple[str, ...] = ()
    """Raw survey files it reads (their content hashes enter its key): capture, calibration, plan, track."""
    params: tuple[str, ...] = ()
    """Survey values it reads (in its key): plan_scale, rooms."""
    uses_profile: bool = False
    """Whether the survey's sensor profile is an input (then its content is part of the cache key)."""
    extra_sections: tuple[tuple[str, str], ...] = ()
    """Further (section, "module:Class") config sections it reads: register runs SfM and scale."""
    applies_to: Literal["any", "frames", "cloud"] = "any"
    """Room stages: the captures it applies to ("frames": RGB-D recordings, "cloud": registered clouds)."""
    deliverables: tuple[str, ...] = ()
    """Files published to outputs/ (a room stage's to outputs/rooms/<id>/)."""
    room_deliverables: tuple[str, ...] = ()
    """"after" stages: per-room files `<id>.<name>` published as outputs/rooms/<id>/<name>, in place of
    the room stage's file of that name (fusion puts a placed room's walls into the plan frame)."""

    @property
    def section(self) -> str:
        return self.name

    @property
    def sections(self) -> tuple[str, ...]:
        """Every config section in the stage's key: its own, then its extra ones."""
        return (self.name, *(name for name, _ in self.extra_sections))

    def runner(self) -> StageRun:
        return importlib.import_module(self.module).run

    def code_version(self) -> str:
        """Hash of the entry module and every project module it imports, transitively: editing any code
        the stage runs invalidates it (and, through content hashes, what depends on it)."""
        return code_version(self.module)

    def applies(self, capture_kind: str) -> bool:
        """Whether the stage runs for a room whose capture is of this kind (tasks.ingest.capture_kind:
        "cloud" for a registered cloud, else a kind of frame recording)."""
        if self.applies_to == "any":
            return True
        return (capture_kind == "cloud") == (self.applies_to == "cloud")


STAGES: dict[str, Stage] = {
    stage.name: stage
    for stage in (
        Stage(
            "calibrate",
            "before",
            "tasks.calibrate.stage",
            "tasks.calibrate.config:CalibrateConfig",
            raw_inputs=("calibration",),
            uses_profile=True,
        ),
        Stage(
            "plan",
            "before",
            "tasks.plan.stage",
            "tasks.plan.config:PlanConfig",
            raw_inputs=("plan",),
            params=("plan_scale",),
            deliverables=("plan_walls.parquet", "rooms.geojson", "plan_preview.png"),
        ),
        Stage(
            "ingest",
            "room",
            "tasks.ingest.stage",
            "tasks.ingest.config:IngestConfig",
            raw_inputs=("capture",),
            uses_profile=True,
        ),
        Stage(
            "register",
            "room",
            "tasks.register.stage",
            "tasks.register.config:RegisterConfig",
            upstream=("ingest", "calibrate", "plan"),
            optional=("calibrate", "plan"),
            raw_inputs=("track",),
            uses_profile=True,
            extra_sections=(
                ("sfm", "tasks.register.config:SfmConfig"),
                ("scale", "tasks.register.config:ScaleConfig"),
            ),
            applies_to="frames",
        ),
        Stage(
            "preprocess",
            "room",
            "tasks.preprocess.stage",
            "tasks.preprocess.config:PreprocessConfig",
            upstream=("register", "ingest"),
        ),
        Stage(
            "walls",
            "room",
            "tasks.walls.stage",
            "tasks.walls.config:WallsConfig",
            upstream=("preprocess",),
            deliverables=("walls.parquet", "plan.geojson", "model.ply", "preview.png"),
        ),
        Stage(
            "floor_index",
            "after",
            "tasks.floor_index.stage",
            "tasks.floor_index.config:FloorIndexConfig",
            room_upstream=("ingest", "register", "preprocess", "walls"),
            params=("rooms",),
            deliverables=("rooms.parquet",),
        ),
        Stage(
            "fuse",
            "after",
            "tasks.fuse.stage",
            "tasks.fuse.config:FuseConfig",
            upstream=("plan",),
            room_upstream=("walls", "preprocess", "register"),
            raw_inputs=("track",),
            params=("rooms",),
            deliverables=("floor.geojson", "thickness.parquet", "fuse.json"),
            room_deliverables=("walls.parquet", "plan.geojson"),
        ),
        Stage(
            "changes",
            "after",
            "tasks.changes.stage",
            "tasks.changes.config:ChangesConfig",
            upstream=("fuse", "plan"),
            room_upstream=("walls",),
            deliverables=("changes.parquet", "changes.geojson", "changes.png"),
        ),
        Stage(
            "deliver",
            "after",
            "tasks.deliver.stage",
            "tasks.deliver.config:DeliverConfig",
            upstream=("fuse", "changes", "plan"),
            optional=("changes",),
            room_upstream=("preprocess",),
            deliverables=("floor.dxf", "floor.ifc", "floor.ply", "floor.prj"),
            room_deliverables=("cloud.ply",),
        ),
    )
}
"""Every stage, in an order where each comes after the stages it reads."""


def config_sections() -> dict[str, str]:
    """Config section name -> "module:Class", in table order (the config tree's sections)."""
    sections: dict[str, str] = {}
    for stage in STAGES.values():
        for name, target in ((stage.name, stage.config), *stage.extra_sections):
            sections.setdefault(name, target)
    return sections


def load_class(target: str) -> type:
    """The class named by "module:Class"."""
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def stages_of(partition: Partition) -> list[Stage]:
    return [s for s in STAGES.values() if s.partition == partition]


def downstream_of(name: str) -> set[str]:
    """Every stage that reads `name`'s results, directly or through others (room stages read each other
    within a room, "after" stages read every room's)."""
    found: set[str] = set()
    frontier = [name]
    while frontier:
        current = frontier.pop()
        for stage in STAGES.values():
            if stage.name not in found and current in (*stage.upstream, *stage.room_upstream):
                found.add(stage.name)
                frontier.append(stage.name)
    return found


# --------------------------------------------------------------------------------------- code versions


def module_file(name: str) -> Path | None:
    """The source file of a project module (a package's __init__.py), or None when it is not one."""
    if name.split(".")[0] not in PROJECT_PACKAGES:
        return None
    base = REPO_ROOT.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


IMPORTS_MEMO: dict[str, list[str]] = {}
"""Module name and its source's sha256 -> the project modules that source imports (project_imports):
parsing every module costs about 0.7 CPU s per process, so a run keeps what it found in its work dir
(load_imports_memo / save_imports_memo). Keyed by the source's bytes, an entry never goes stale."""


def load_imports_memo(path: Path) -> None:
    """Add the import lists saved in `path` (a JSON object as IMPORTS_MEMO) to the memo; a missing or
    unreadable file adds nothing (the sources are parsed instead)."""
    try:
        saved = json.loads(path.read_text())
    except (OSError, ValueError):
        return
    if isinstance(saved, dict):
        IMPORTS_MEMO.update(
            (k, v) for k, v in saved.items() if isinstance(v, list) and all(isinstance(m, str) for m in v)
        )


def save_imports_memo(path: Path) -> None:
    """Write the memo entries this process used (the sources as they are now) to `path`, atomically;
    nothing when the file holds them already."""
    text = json.dumps({key: IMPORTS_MEMO[key] for key in sorted(_used)}, sort_keys=True)
    try:
        if path.read_text() == text:
            return
    except OSError:
        pass
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


_used: set[str] = set()
"""The memo keys this process looked up (the entries worth saving)."""


@functools.cache
def project_imports(name: str) -> tuple[str, ...]:
    """The project modules `name` imports anywhere in its source (also inside functions: a lazy import
    runs too), with the packages that hold them (from IMPORTS_MEMO when it has this source)."""
    path = module_file(name)
    if path is None:
        return ()
    source = path.read_bytes()
    key = f"{name}:{hashlib.sha256(source).hexdigest()}"
    _used.add(key)
    if key in IMPORTS_MEMO:
        return tuple(IMPORTS_MEMO[key])
    found = _parse_imports(name, path, source)
    IMPORTS_MEMO[key] = list(found)
    return found


def _parse_imports(name: str, path: Path, source: bytes) -> tuple[str, ...]:
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(source, filename=str(path))):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source = ".".join([*base, node.module] if node.module else base)
            else:
                source = node.module or ""
            # `from tasks.walls import image` imports the submodule tasks.walls.image
            candidates = [source, *(f"{source}.{alias.name}" for alias in node.names)]
        else:
            continue
        for candidate in candidates:
            parts = candidate.split(".")
            for k in range(1, len(parts) + 1):  # importing a.b.c runs a and a.b first
                if module_file(".".join(parts[:k])) is not None:
                    found.add(".".join(parts[:k]))
    found.discard(name)
    return tuple(sorted(found))


def module_closure(name: str) -> list[str]:
    """`name` and every project module it imports, transitively, sorted."""
    seen = {name}
    frontier = [name]
    while frontier:
        for dep in project_imports(frontier.pop()):
            if dep not in seen:
                seen.add(dep)
                frontier.append(dep)
    return sorted(m for m in seen if module_file(m) is not None)


@functools.cache
def code_version(module: str) -> str:
    """Hash of the source of `module` and of every project module it imports (not third-party code).
    Read once per process."""
    digest = hashlib.sha256()
    for name in module_closure(module):
        path = module_file(name)
        assert path is not None
        digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]
