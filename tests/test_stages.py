"""The stage table, code versions that see every module a stage runs, and the import graph."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from tasks import stages as stmod
from tasks.stages import STAGES, module_closure, module_file, project_imports

REPO = Path(__file__).resolve().parents[1]


def test_table_is_consistent():
    order = list(STAGES)
    partitions = [s.partition for s in STAGES.values()]
    assert partitions == sorted(partitions, key=["before", "room", "after"].index)
    for stage in STAGES.values():
        assert callable(stage.runner()), stage.name
        stmod.load_class(stage.config)()  # a config section with defaults
        for name in (*stage.upstream, *stage.room_upstream):
            assert name in STAGES and order.index(name) < order.index(stage.name), (stage.name, name)
        assert set(stage.optional) <= set(stage.upstream)
        assert bool(stage.room_upstream) == (stage.partition == "after")


def test_code_version_covers_every_imported_project_module():
    closure = module_closure("tasks.walls.stage")
    assert "tasks.lines" in closure and "tasks.artefacts" in closure and "tasks.walls.config" in closure
    assert "tasks.ingest.stage" not in closure
    assert all(m.startswith("tasks") for m in closure)  # stages never reach into flows/


def _copy_project(dest: Path) -> None:
    for package in ("tasks", "flows"):
        shutil.copytree(REPO / package, dest / package, ignore=shutil.ignore_patterns("__pycache__"))


def test_editing_a_helper_module_changes_the_versions_of_the_stages_that_use_it(tmp_path, monkeypatch):
    """The stale-cache fault: editing tasks/lines.py (wall and plan geometry) must invalidate walls and
    plan, and nothing that does not import it."""
    _copy_project(tmp_path)
    monkeypatch.setattr(stmod, "REPO_ROOT", tmp_path)
    for cached in (stmod.project_imports, stmod.code_version):
        cached.cache_clear()
    before = {name: stage.code_version() for name, stage in STAGES.items()}
    helper = tmp_path / "tasks" / "lines.py"
    helper.write_text(helper.read_text() + "\n# an edit\n")
    for cached in (stmod.project_imports, stmod.code_version):
        cached.cache_clear()
    after = {name: stage.code_version() for name, stage in STAGES.items()}
    changed = {name for name in STAGES if before[name] != after[name]}
    assert {"walls", "plan"} <= changed
    assert "ingest" not in changed and "calibrate" not in changed
    for cached in (stmod.project_imports, stmod.code_version):
        cached.cache_clear()


def test_the_imports_memo_gives_the_same_versions_and_never_a_stale_import_list(tmp_path, monkeypatch):
    """A run keeps each source's import list in its work dir, keyed by the source's bytes: the next run
    reads the same versions without parsing, and a source edited to import more is parsed again."""
    _copy_project(tmp_path / "repo")
    monkeypatch.setattr(stmod, "REPO_ROOT", tmp_path / "repo")
    memo = tmp_path / "cache" / "_code_imports.json"

    def fresh() -> None:
        monkeypatch.setattr(stmod, "IMPORTS_MEMO", {})
        monkeypatch.setattr(stmod, "_used", set())
        for cached in (stmod.project_imports, stmod.code_version):
            cached.cache_clear()

    fresh()
    parsed = {name: stage.code_version() for name, stage in STAGES.items()}
    stmod.save_imports_memo(memo)
    fresh()
    stmod.load_imports_memo(memo)
    monkeypatch.setattr(stmod, "_parse_imports", None)  # every list must come from the memo
    assert {name: stage.code_version() for name, stage in STAGES.items()} == parsed
    monkeypatch.undo()
    monkeypatch.setattr(stmod, "REPO_ROOT", tmp_path / "repo")
    fresh()
    stmod.load_imports_memo(memo)
    entry = tmp_path / "repo" / "tasks" / "ingest" / "stage.py"
    entry.write_text(entry.read_text() + "\nfrom tasks import lines  # noqa\n")
    assert "tasks.lines" in module_closure("tasks.ingest.stage")
    assert STAGES["ingest"].code_version() != parsed["ingest"]
    memo.write_text("not json")  # an unreadable memo is no memo
    fresh()
    stmod.load_imports_memo(memo)
    assert STAGES["walls"].code_version() == parsed["walls"]
    for cached in (stmod.project_imports, stmod.code_version):
        cached.cache_clear()


def test_a_changed_code_version_recomputes_that_stage_and_only_what_follows(tmp_path, monkeypatch):
    """Through the store: model-room's chain twice; the second time the walls stage's code 'changed'
    (its version patched), so walls recomputes while ingest and preprocess are served from the store."""
    from flows import planning
    from tasks import config as cfgmod
    from tests.captures import write_box_room_ply

    cloud = write_box_room_ply(tmp_path / "room.ply", np.random.default_rng(3))
    cfg = cfgmod.load_config()
    profile = cfgmod.load_sensor_profile("tls")
    room = cfgmod.RoomSpec("room", cloud)
    work = tmp_path / "work"
    names = planning.room_stages(cloud)
    first = planning.run_chain(work, cfg, profile, names, room)
    real = stmod.Stage.code_version

    def patched(stage: stmod.Stage) -> str:
        return "edited-walls" if stage.name == "walls" else real(stage)

    monkeypatch.setattr(stmod.Stage, "code_version", patched)
    seen: dict[str, str] = {}
    execute = planning.execute

    def spy(call, upstream, fan_in=None):
        done = execute(call, upstream, fan_in)
        seen[call.stage] = done.how
        return done

    monkeypatch.setattr(planning, "execute", spy)
    second = planning.run_chain(work, cfg, profile, names, room)
    assert seen == {"ingest": "stored", "preprocess": "stored", "walls": "computed"}
    assert second["walls"].key != first["walls"].key


def _top_level_imports(name: str) -> set[str]:
    """Project modules imported at module level (what runs at import time)."""
    import ast

    path = module_file(name)
    tree = ast.parse(path.read_bytes())
    found = set()
    for node in tree.body:
        if isinstance(node, ast.If):  # `if TYPE_CHECKING:` blocks do not run
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            wrapper = ast.Module(body=[node], type_ignores=[])
            found |= _imports_of(wrapper, name)
    return found


def _imports_of(tree, name: str) -> set[str]:
    import ast

    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            for cand in [node.module, *(f"{node.module}.{a.name}" for a in node.names)]:
                if module_file(cand):
                    found.add(cand)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if module_file(a.name)}
    found.discard(name)
    return found


def _project_modules() -> list[str]:
    names = []
    for package in ("tasks", "flows"):
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


def test_import_graph_has_no_cycle_and_tasks_never_import_flows():
    import networkx as nx

    modules = _project_modules()
    graph = nx.DiGraph()
    for name in modules:
        graph.add_node(name)
        graph.add_edges_from((name, dep) for dep in _top_level_imports(name))
        if name.startswith("tasks"):
            assert not [d for d in project_imports(name) if d.startswith("flows")], name
    cycles = list(nx.simple_cycles(graph))
    assert not cycles, cycles[:3]


def test_loading_the_config_loads_no_stage_computation():
    code = (
        "import sys, tasks.config; print(','.join(sorted(m for m in sys.modules "
        "if m.split('.')[0] in ('tasks', 'cv2', 'open3d', 'pycolmap', 'skimage', 'sklearn'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    loaded = set(out.stdout.strip().split(","))
    allowed = {
        "tasks",
        "tasks.config",
        "tasks.stages",
        "tasks.artefacts",
        "tasks.cloud",
        "tasks.lines_config",
    }
    allowed |= {f"tasks.{name}" for name in STAGES} | {f"tasks.{name}.config" for name in STAGES}
    assert loaded <= allowed, sorted(loaded - allowed)


def test_room_chains_follow_the_capture_kind(tmp_path):
    from flows.planning import room_stages

    (tmp_path / "room.ply").write_bytes(b"ply\n")
    (tmp_path / "rec.mcap").write_bytes(b"")
    assert room_stages(tmp_path / "room.ply") == ["ingest", "preprocess", "walls"]
    assert room_stages(tmp_path / "rec.mcap") == ["ingest", "register", "preprocess", "walls"]
