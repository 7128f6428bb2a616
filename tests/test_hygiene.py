"""Import hygiene of the tests and benchmarks, read from the source (nothing is imported or run): test modules
share builders through helper modules (tests/captures.py, tests/scenes.py) or conftest fixtures, never by
importing each other; benchmarks run as `python -m bench.NAME` from the repository root and read tasks/,
never tests/, and never edit sys.path."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SYS_PATH_EDITS = {"insert", "append", "extend", "remove", "pop", "clear", "__setitem__", "__iadd__"}


def _imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, dotted module name) of every import statement; `from tests import x` counts as tests.x."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            if base.strip(".") in ("", "tests"):  # `from tests import test_x`, `from . import test_x`
                out += [(node.lineno, f"{base}.{alias.name}".replace("..", ".")) for alias in node.names]
            else:
                out.append((node.lineno, base))
    return out


def _is_test_module(name: str) -> bool:
    parts = name.lstrip(".").split(".")
    return parts[-1].startswith("test_") or (len(parts) > 1 and parts[-2].startswith("test_"))


def _sys_path_edits(tree: ast.AST) -> list[int]:
    """Lines that change sys.path: a mutating method call, an item or slice assignment, a rebinding."""

    def is_sys_path(node: ast.AST) -> bool:
        return (
            isinstance(node, ast.Attribute)
            and node.attr == "path"
            and isinstance(node.value, ast.Name)
            and node.value.id == "sys"
        )

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            if node.func.attr in SYS_PATH_EDITS and is_sys_path(node.func.value):
                lines.append(node.lineno)
        elif isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if is_sys_path(target) or (isinstance(target, ast.Subscript) and is_sys_path(target.value)):
                    lines.append(node.lineno)
    return sorted(lines)


def _parse(path: Path) -> ast.AST:
    return ast.parse(path.read_text(), filename=str(path))


def test_test_modules_do_not_import_each_other():
    found = []
    for path in sorted((REPO / "tests").glob("test_*.py")):
        for line, name in _imported_modules(_parse(path)):
            if _is_test_module(name):
                found.append(f"tests/{path.name}:{line} imports {name}")
    assert not found, "shared builders belong in a helper module or conftest:\n" + "\n".join(found)


def test_benchmarks_read_tasks_not_tests_and_leave_sys_path_alone():
    found = []
    for path in sorted((REPO / "bench").glob("*.py")):
        tree = _parse(path)
        for line, name in _imported_modules(tree):
            if (
                name.split(".")[0] == "tests"
                or _is_test_module(name)
                or name in ("rooms", "captures", "scenes")
            ):
                found.append(f"bench/{path.name}:{line} imports {name}")
        found += [f"bench/{path.name}:{line} edits sys.path" for line in _sys_path_edits(tree)]
    assert not found, "a benchmark runs as `python -m bench.NAME` and reads tasks/ only:\n" + "\n".join(found)


def test_the_checks_catch_what_they_are_for():
    """The two checks above see the patterns they forbid (so that an empty finding means something)."""
    bad = ast.parse(
        "import sys\nfrom tests.test_scale import look_pose\nimport tests.test_sfm\nfrom tests import test_walls\n"
        "from test_register import write_frames\nsys.path.insert(0, 'x')\nsys.path[:0] = ['y']\n"
        "sys.path += ['z']\n"
    )
    names = [name for _, name in _imported_modules(bad)]
    assert sum(_is_test_module(n) for n in names) >= 4
    assert _sys_path_edits(bad) == [6, 7, 8]
    good = ast.parse("import sys\nfrom tests.captures import tiny_survey\nprint(sys.path)\n")
    assert not any(_is_test_module(n) for _, n in _imported_modules(good))
    assert _sys_path_edits(good) == []
