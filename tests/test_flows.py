"""The flows end to end on a tiny survey: caching, targeted recomputes, crash safety and bad input."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from flows.cli import main
from tasks.artefacts import ArtefactStore
from tests.captures import tiny_survey, write_box_room_ply, write_survey

pytestmark = pytest.mark.slow


@pytest.fixture
def prefect_home(prefect_harness):
    """The session's Prefect harness (the in-process flows and the subprocess share its server)."""
    yield


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    states = {}
    for line in out.out.splitlines()[1:]:
        parts = line.split()
        if len(parts) >= 3 and parts[1] in {"calibrate", "ingest", "register", "preprocess", "walls"}:
            states[(parts[0], parts[1])] = parts[2]
    return code, states, out


def test_cache_rerun_and_targeted_recompute(tmp_path, capsys, prefect_home, monkeypatch):
    survey = tiny_survey(tmp_path / "s", np.random.default_rng(1))
    work = str(tmp_path / "w")
    code, states, _ = run(capsys, "run", str(survey), "--work", work)
    assert code == 0
    assert set(states.values()) == {"computed"}
    assert states[("a", "preprocess")] == "computed"

    code, states, out = run(capsys, "run", str(survey), "--work", work)
    assert code == 0
    assert set(states.values()) == {"cached"}, states
    assert "nothing to compute (Prefect not started)" in out.err  # a no-op rerun skips the orchestrator

    code, states, _ = run(capsys, "run", str(survey), "--work", work, "--set", "preprocess.voxel_size_m=0.03")
    assert code == 0
    assert states[("a", "ingest")] == "cached"  # a Prefect cache hit (the run needed Prefect)
    assert {k: v for k, v in states.items() if v != "cached"} == {
        ("a", "preprocess"): "computed",
        ("a", "walls"): "computed",
        ("b", "preprocess"): "computed",
        ("b", "walls"): "computed",
    }

    from flows import pipeline

    submitted = []
    submit = pipeline._submit
    monkeypatch.setattr(pipeline, "_submit", lambda item, *a: submitted.append(item.ref) or submit(item, *a))
    code, states, out = run(
        capsys, "rerun", str(survey), "--work", work, "--stage", "preprocess", "--room", "a"
    )
    assert code == 0
    # nothing the building stages after the rooms read changed: they are read without a task run
    assert submitted == [] and "_building    floor_index  cached" in out.out
    # preprocess writes the same bytes again, so walls (content-keyed) stays current
    assert states[("a", "ingest")] == "cached" and states[("a", "preprocess")] == "computed"
    assert states[("a", "walls")] in ("cached", "stored") and len(states) == 3
    for name in ("walls.parquet", "plan.geojson", "model.ply", "preview.png"):
        assert (Path(work) / "outputs" / "rooms" / "a" / name).is_file()

    code, _, out = run(capsys, "status", str(survey), "--work", work)
    assert code == 0
    assert "a            preprocess   done" in out.out


def test_bad_capture_fails_that_room_only_and_keeps_earlier_artefacts(tmp_path, capsys, prefect_home):
    survey = tiny_survey(tmp_path / "s", np.random.default_rng(2), frames_room=True)
    work = tmp_path / "w"
    code, states, out = run(capsys, "run", str(survey), "--work", str(work))
    # the flat-wall recording ingests, but cannot be registered: a clear error, not a garbage cloud
    assert code == 3  # rooms a and b finished: partial
    assert states[("c", "ingest")] == "computed" and states[("c", "register")] == "failed"
    assert states[("c", "preprocess")] == "skipped"
    assert any("room c, stage register: cannot register" in line for line in out.err.splitlines())
    store = ArtefactStore(work)
    before = {room: store.latest(room, "ingest") for room in ("b", "c")}

    capture = survey / "rooms" / "c" / "capture.mcap"
    capture.write_bytes(capture.read_bytes()[:5000])  # truncated
    nan_cloud = survey / "rooms" / "b" / "cloud.ply"
    text = nan_cloud.read_bytes()
    # NaN coordinates written into a valid PLY: the stage must refuse the cloud, not crash later.
    head = text.index(b"end_header\n") + 11
    pts = np.frombuffer(text[head:], dtype=[("p", "<f8", 3), ("c", "u1", 3)]).copy()
    pts["p"][::50] = np.nan
    nan_cloud.write_bytes(text[:head] + pts.tobytes())

    code, states, out = run(capsys, "run", str(survey), "--work", str(work))
    assert code == 3  # room a (cached) finished: partial
    assert states[("a", "preprocess")] == "cached"
    assert states[("c", "ingest")] == "failed" and states[("b", "ingest")] == "failed"
    errors = [line for line in out.err.splitlines() if line.startswith("error:")]
    assert any("capture.mcap: truncated or corrupt MCAP" in line for line in errors)
    assert any("cloud.ply" in line and "NaN" in line for line in errors)
    # what an earlier run computed for the failed rooms is still there, verified
    for room, result in before.items():
        assert store.lookup(room, "ingest", result.key) == result


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--set", "preprocess.voxl_size_m=0.03"], "unknown key 'preprocess.voxl_size_m'"),
        (["--rooms", "zz"], "no room 'zz'"),
    ],
)
def test_bad_arguments_exit_2_with_one_line(tmp_path, capsys, argv, message):
    survey = write_survey(tmp_path / "s", {"a": "a.ply"})
    write_box_room_ply(survey / "a.ply", np.random.default_rng(0))
    code = main(["run", str(survey), "--work", str(tmp_path / "w"), *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and message in err[0]
    assert not (tmp_path / "w" / "cache").exists()


def test_malformed_survey_exit_2(tmp_path, capsys):
    (tmp_path / "survey.yaml").write_text("rooms: [")
    assert main(["run", str(tmp_path), "--work", str(tmp_path / "w")]) == 2
    assert "survey.yaml" in capsys.readouterr().err


def test_sigkill_mid_stage_then_rerun_completes(tmp_path, prefect_home):
    rng = np.random.default_rng(4)
    survey = write_survey(tmp_path / "s", {"big": "big.ply"})
    # dense enough that preprocess runs for a few seconds
    write_box_room_ply(survey / "big.ply", rng, size_m=(6.0, 5.0, 2.7), spacing_m=0.012)
    work = tmp_path / "w"
    from prefect.settings import PREFECT_API_URL

    # The subprocess talks to the harness' server instead of starting its own.
    env = {**os.environ, "PREFECT_API_URL": PREFECT_API_URL.value()}
    cmd = [sys.executable, "-m", "flows.cli", "-q", "run", str(survey), "--work", str(work)]
    proc = subprocess.Popen(
        cmd, env=env, cwd=Path(__file__).parents[1], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    stage_root = work / "cache" / "big" / "preprocess"
    deadline = time.time() + 240
    while time.time() < deadline and not any(stage_root.glob(".tmp-*")):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    assert any(stage_root.glob(".tmp-*")), "preprocess never started"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    store = ArtefactStore(work)
    assert store.latest("big", "preprocess") is None  # the half-written folder is not an artefact

    done = subprocess.run(
        cmd, env=env, cwd=Path(__file__).parents[1], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    assert "big          preprocess   computed" in done.stdout
    # served, not recomputed: by Prefect's record when the killed run wrote it, else by the store
    ingest = next(line for line in done.stdout.splitlines() if line.startswith("big          ingest"))
    assert ingest.split()[2] in ("cached", "stored"), ingest
    assert store.latest("big", "preprocess") is not None
    assert not any(stage_root.glob(".tmp-*"))  # swept


def test_memory_freed_by_pool_threads_goes_back_to_the_system():
    """What a stage frees on a pool thread is returned by `release` (glibc), as `execute` calls it after
    each stage, so a run's RSS stays flat stage after stage (without it, here: 30-180 MB more after each
    of eight such stages, varying); elsewhere both calls report that they did nothing."""
    import threading

    from flows import memory

    if not memory.limit_arenas(2):
        assert not memory.release()
        pytest.skip("not glibc: nothing to return")

    def rss_mb() -> float:
        fields = Path("/proc/self/statm").read_text().split()
        return int(fields[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

    def stage() -> None:  # arrays of 2.4, 16 and 8 MB, freed again, as a stage's would be
        arrays = [np.ones(n) for n in (300_000, 2_000_000, 1_000_000) * 10]
        del arrays
        memory.release()

    after = []
    for _ in range(9):  # the first sets up the thread's arena (43 MB once, in a full suite's process)
        thread = threading.Thread(target=stage)
        thread.start()
        thread.join()
        after.append(rss_mb())
    # stage after stage the RSS stays flat (0-18 MB here); another thread of a full suite's process may
    # allocate once meanwhile (52 MB seen in one CI run), so one step may rise, not the steps together
    steps = np.diff(after[1:])
    assert np.sort(steps)[-2] < 30 and after[-1] - after[1] < 90, after


def _database(path: Path, revision: str) -> Path:
    import sqlite3

    path.parent.mkdir(parents=True, exist_ok=True)
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE IF NOT EXISTS alembic_version (version_num TEXT)")
        db.execute("DELETE FROM alembic_version")
        db.execute("INSERT INTO alembic_version VALUES (?)", (revision,))
    return path


def test_migrations_are_skipped_only_while_the_database_is_where_they_left_it(tmp_path, monkeypatch):
    from flows import prefect_env

    for name in list(os.environ):
        if name.startswith(("PREFECT_API_DATABASE_", "PREFECT_SERVER_DATABASE_", "PREFECT_PROFILE")):
            monkeypatch.delenv(name)
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path))
    database = prefect_env._default_database()
    assert database == tmp_path / "prefect.db"
    assert not prefect_env.database_is_migrated(database)  # no database yet: migrate
    _database(database, "aaa")
    assert not prefect_env.database_is_migrated(database)  # never recorded: migrate
    prefect_env.record_migrated(database)
    assert prefect_env.database_is_migrated(database)
    _database(database, "bbb")  # another Prefect migrated it since
    assert not prefect_env.database_is_migrated(database)
    prefect_env.record_migrated(database)
    monkeypatch.setattr(prefect_env, "_prefect_version", lambda: "0.0.1")  # Prefect upgraded
    assert not prefect_env.database_is_migrated(database)
    monkeypatch.undo()
    monkeypatch.setenv("PREFECT_HOME", str(tmp_path))
    monkeypatch.setenv("PREFECT_API_DATABASE_CONNECTION_URL", "sqlite+aiosqlite:////elsewhere.db")
    assert prefect_env._default_database() is None  # a database of the user's choice: always migrate
    assert not prefect_env.database_is_migrated(None)


def test_server_start_settings_yield_to_the_environment(tmp_path, monkeypatch):
    from flows import prefect_env

    seen: list[dict[str, str]] = []
    monkeypatch.setattr(prefect_env.subprocess, "Popen", lambda cmd, env, stdin: seen.append(env))
    monkeypatch.delenv("PREFECT_API_DATABASE_MIGRATE_ON_START", raising=False)
    monkeypatch.setenv("PY_KEY_VALUE_DISABLE_BEARTYPE", "false")
    prefect_env._launch(1, migrate=False)
    prefect_env._launch(1, migrate=True)
    assert seen[0]["PREFECT_API_DATABASE_MIGRATE_ON_START"] == "false"
    assert "PREFECT_API_DATABASE_MIGRATE_ON_START" not in seen[1]
    assert seen[0]["PREFECT_API_BLOCKS_REGISTER_ON_START"] == "false"
    assert seen[0]["PY_KEY_VALUE_DISABLE_BEARTYPE"] == "false"  # the user's setting wins
    assert seen[0]["PREFECT_UI_ENABLED"] == "0"


def test_bench_counts_a_shared_servers_cpu_seconds_as_the_commands(tmp_path):
    """bench.run --prefect-server: the command is pointed at the shared server, and what that server
    burns while the command runs counts as the command's CPU seconds."""
    from bench.run import timed

    busy = "import time\nt = time.process_time()\nwhile time.process_time() - t < 60: pass"
    server = subprocess.Popen([sys.executable, "-c", busy])
    check = "import os, time; assert os.environ['PREFECT_API_URL'] == 'http://x/api'; time.sleep(2)"
    try:
        result = timed([sys.executable, "-c", check], tmp_path / "log", ("http://x/api", server.pid))
    finally:
        server.kill()
        server.wait()
    assert 0.02 < result["shared_server_cpu_s"] < result["cpu_s"]
