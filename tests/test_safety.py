"""Safe unattended runs: the work-dir lock, failure isolation, exit codes, outputs/manifest.json, and fault
injection (SIGKILL at random moments of a cold run, an OSError half-way through a stage's writer and
through publishing, two concurrent runs on one work dir)."""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from flows import worklock
from flows.cli import main
from tasks.artefacts import ArtefactStore, sha256_file
from tests.captures import write_box_room_ply, write_survey

REPO = Path(__file__).resolve().parents[1]

# ------------------------------------------------------------------------------------------------ helpers


def small_survey(root: Path) -> Path:
    """Two box rooms as registered clouds, coarse enough that a cold run takes seconds: ingest,
    preprocess and walls per room, then the building's floor_index."""
    rng = np.random.default_rng(7)
    rooms = {"a": "rooms/a/cloud.ply", "b": "rooms/b/cloud.ply"}
    for room, size in (("a", (3.0, 2.5, 2.5)), ("b", (2.5, 2.0, 2.4))):
        (root / "rooms" / room).mkdir(parents=True)
        write_box_room_ply(root / rooms[room], rng, size_m=size, spacing_m=0.05)
    return write_survey(root, rooms)


def temporaries(work: Path) -> list[Path]:
    """Half-written things a run may leave: stage folders under a temporary name (`.tmp-*`, `.old-*`)
    and outputs copied under a temporary name (`.<name>.<hex>.tmp`)."""
    found = [*work.glob("cache/*/*/.tmp-*"), *work.glob("cache/*/*/.old-*")]
    if (work / "outputs").is_dir():
        found += list((work / "outputs").rglob(".*.tmp"))
    return sorted(found)


def snapshot(work: Path) -> dict[str, str]:
    """Every final artefact by content hash: each committed stage folder's files (cache) and every
    deliverable in outputs/ (but manifest.json and report.html, which name the run)."""
    files: dict[str, str] = {}
    for manifest in sorted(work.glob("cache/*/*/*/manifest.json")):
        folder = manifest.parent
        if folder.name.startswith("."):
            continue
        for name, digest in json.loads(manifest.read_text())["files"].items():
            assert sha256_file(folder / name) == digest, folder / name
            files[str((folder / name).relative_to(work))] = digest
    for path in sorted((work / "outputs").rglob("*")):
        if path.is_file() and path.name not in ("manifest.json", "report.html"):
            files[str(path.relative_to(work))] = sha256_file(path)
    return files


def prefect_env() -> dict[str, str]:
    """The subprocesses talk to the session's Prefect harness instead of starting their own server."""
    from prefect.settings import PREFECT_API_URL

    return {**os.environ, "PREFECT_API_URL": PREFECT_API_URL.value(), "PYTHONPATH": str(REPO)}


AUDITED_RUN = """\
import json, os, sys
watched = tuple(json.loads(open(os.environ["AUDIT_WATCH"]).read()))
opened = []
def hook(event, args):
    # a read of anything a killed run left half-written (the sweep only lists and deletes them)
    if event == "open" and args and isinstance(args[0], (str, bytes, os.PathLike)):
        path = os.fsdecode(args[0])
        if path.startswith(watched) and not os.path.isdir(path):
            opened.append(path)
sys.addaudithook(hook)
from flows.cli import main
code = main(sys.argv[1:])
with open(os.environ["AUDIT_OUT"], "w") as fh:
    json.dump(opened, fh)
sys.exit(code)
"""


def cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "flows.cli", *argv]


def summary_states(stdout: str) -> dict[tuple[str, str], str]:
    states = {}
    for line in stdout.splitlines()[1:]:
        parts = line.split()
        if len(parts) >= 4 and parts[2] in {"computed", "cached", "stored", "failed", "skipped"}:
            states[(parts[0], parts[1])] = parts[2]
    return states


# ------------------------------------------------------------------------------------------------- lock

HOLDER = """\
import sys, time
from pathlib import Path
from flows.worklock import work_lock
with work_lock(Path(sys.argv[1]), command="holder"):
    print("held", flush=True)
    time.sleep(120)
"""

BARE_HOLDER = """\
import sys, time
from filelock import UnixFileLock
lock = UnixFileLock(sys.argv[1] + "/.lock", preserve_lock_file=True)
lock.acquire()
print("held", flush=True)
time.sleep(120)
"""


def _hold(work: Path, script: str = HOLDER) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", script, str(work)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_no_wait_names_the_holder_and_exits_2(tmp_path, capsys):
    survey = write_survey(tmp_path / "s", {"a": "a.ply"})
    write_box_room_ply(survey / "a.ply", np.random.default_rng(0), spacing_m=0.1)
    work = tmp_path / "w"
    holder = _hold(work)
    try:
        code = main(["run", str(survey), "--work", str(work), "--no-wait"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2
        assert len(err) == 1
        assert f"pid {holder.pid} on {socket.gethostname()}, started 20" in err[0], err
        assert "holder" in err[0] and "--no-wait" in err[0]
        assert not (work / "cache").exists()  # refused before any work
        # status reads without the lock (and says there is nothing yet rather than waiting)
        code = main(["status", str(survey), "--work", str(work)])
        assert code == 0
    finally:
        holder.kill()
        holder.wait()


def test_lock_of_a_killed_holder_is_taken_over_and_its_sidecar_never_named(tmp_path):
    work = tmp_path / "w"
    holder = _hold(work)
    stale = json.loads((work / ".lock.json").read_text())
    assert stale["pid"] == holder.pid and stale["host"] == socket.gethostname()
    with pytest.raises(worklock.WorkDirBusy, match=f"pid {holder.pid} "):
        with worklock.work_lock(work, wait=False):
            pass
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert (work / ".lock.json").is_file()  # the killed holder could not clean up its description
    assert worklock.read_holder(work) is None  # ... which names a dead process: not a holder
    # the kernel released the flock with the process: taken at once, no waiting
    with worklock.work_lock(work, wait=False):
        assert json.loads((work / ".lock.json").read_text())["pid"] == os.getpid()
    assert not (work / ".lock.json").exists()

    # a new holder that has not described itself yet, beside the dead one's sidecar: the message does
    # not blame the dead pid
    _write_stale = {**stale, "started": "2000-01-01T00:00:00+00:00"}
    (work / ".lock.json").write_text(json.dumps(_write_stale))
    bare = _hold(work, BARE_HOLDER)
    try:
        with pytest.raises(worklock.WorkDirBusy) as caught:
            with worklock.work_lock(work, wait=False):
                pass
        message = str(caught.value)
        assert str(holder.pid) not in message and "has not described itself" in message
        # waiting: one notice, then the lock once the holder ends
        notices: list[str] = []
        killer = subprocess.Popen(["sh", "-c", f"sleep 1; kill -9 {bare.pid}"])
        with worklock.work_lock(work, wait=True, notify=notices.append):
            assert bare.poll() is not None or bare.wait(5) is not None
        killer.wait()
        assert len(notices) == 1 and "waiting" in notices[0]
    finally:
        bare.kill()
        bare.wait()


def test_status_without_an_existing_work_dir_exits_2_and_creates_nothing(tmp_path, capsys, monkeypatch):
    survey = write_survey(tmp_path / "s", {"a": "a.ply"})
    write_box_room_ply(survey / "a.ply", np.random.default_rng(0), spacing_m=0.1)
    monkeypatch.chdir(tmp_path)
    code = main(["status", str(survey)])  # no --work: ./work, which does not exist
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "no such work dir" in err[0]
    assert not (tmp_path / "work").exists()


def test_exit_state_rules():
    from flows.planning import StageOutcome, exit_state

    def row(room: str, stage: str, state: str) -> StageOutcome:
        return StageOutcome(room, stage, state, 0.0)

    done = [row("_building", "plan", "computed"), row("a", "walls", "cached"), row("b", "walls", "stored")]
    assert exit_state(done) == "done"
    # calibrate failed (register runs without it) and room b failed: room a finished
    partial = [
        row("_building", "calibrate", "failed"),
        row("a", "walls", "cached"),
        row("b", "walls", "failed"),
    ]
    assert exit_state(partial) == "partial"
    # every room failed or skipped: nothing finished
    failed = [row("_building", "plan", "computed"), row("a", "walls", "failed"), row("b", "walls", "skipped")]
    assert exit_state(failed) == "failed"


@pytest.mark.slow
def test_missing_and_unreadable_captures_fail_their_room_alone(tmp_path, capsys, prefect_harness):
    survey = write_survey(
        tmp_path / "s",
        {"a": "a.ply", "gone": "gone.ply", "odd": "odd.txt"},
    )
    write_box_room_ply(survey / "a.ply", np.random.default_rng(0), spacing_m=0.05)
    (survey / "odd.txt").write_text("not a capture")
    work = tmp_path / "w"
    code = main(["run", str(survey), "--work", str(work)])
    out = capsys.readouterr()
    states = summary_states(out.out)
    assert code == 3, out.err
    assert states[("a", "walls")] == "computed"
    assert states[("gone", "ingest")] == "failed" and states[("odd", "ingest")] == "failed"
    errors = [line for line in out.err.splitlines() if line.startswith("error:")]
    assert any("room gone, stage ingest: capture" in e and "gone.ply does not exist" in e for e in errors)
    assert any("room odd, stage ingest:" in e and "unknown capture format '.txt'" in e for e in errors)
    manifest = json.loads((work / "outputs" / "manifest.json").read_text())
    assert manifest["partial"] is True
    assert manifest["rooms"]["a"]["state"] == "done"
    assert manifest["rooms"]["gone"]["state"] == "failed"
    assert "does not exist" in manifest["rooms"]["gone"]["error"]
    # `--rooms a` does not look at the broken rooms: all done, exit 0
    code = main(["run", str(survey), "--work", str(work), "--rooms", "a"])
    assert code == 0, capsys.readouterr().err
    # status shows the broken rooms as failed, with their reason, and reads without the lock
    main(["status", str(survey), "--work", str(work)])
    lines = capsys.readouterr().out.splitlines()
    assert any(line.split()[:3] == ["gone", "ingest", "failed"] for line in lines), lines
    # no requested room can run: bad input, one line, nothing written
    capsys.readouterr()
    code = main(["run", str(survey), "--work", str(tmp_path / "w2"), "--rooms", "gone", "odd"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "room gone: capture" in err[0] and "room odd:" in err[0]
    assert not (tmp_path / "w2").exists()


# ------------------------------------------------------------------------------------ outputs manifest


@pytest.mark.slow
def test_manifest_merges_partial_runs_and_status_flags_other_configs(tmp_path, capsys, prefect_harness):
    survey = small_survey(tmp_path / "s")
    work = tmp_path / "w"
    assert main(["-q", "run", str(survey), "--work", str(work)]) == 0
    capsys.readouterr()
    first = json.loads((work / "outputs" / "manifest.json").read_text())
    assert set(first) == {"run_id", "finished", "config_hash", "partial", "stages", "rooms", "versions"}
    assert set(first["versions"]) == {"indoor-survey", "python", "numpy", "open3d", "pycolmap", "prefect"}
    assert first["partial"] is False
    for row in first["stages"]:
        assert set(row) == {"room", "stage", "state", "seconds", "error", "key", "run_id", "config_hash"}
        assert row["state"] == "computed" and row["run_id"] == first["run_id"]
    assert {(r["room"], r["stage"]) for r in first["stages"]} >= {("", "floor_index"), ("a", "walls")}

    # one room with another config: merged, the other room's entries kept as they were
    code = main(
        [
            "-q",
            "run",
            str(survey),
            "--work",
            str(work),
            "--rooms",
            "a",
            "--set",
            "walls.shadow_m=0.9",
        ]
    )
    assert code == 0, capsys.readouterr().err
    second = json.loads((work / "outputs" / "manifest.json").read_text())
    assert second["run_id"] != first["run_id"]
    assert second["rooms"]["b"] == first["rooms"]["b"]
    assert second["rooms"]["a"]["run_id"] == second["run_id"]
    assert second["rooms"]["a"]["config_hash"] != first["rooms"]["a"]["config_hash"]
    rows = {(r["room"], r["stage"]): r for r in second["stages"]}
    assert rows[("a", "walls")]["state"] == "computed" and rows[("a", "walls")]["run_id"] == second["run_id"]
    # a cached row keeps the run that computed it
    assert rows[("a", "ingest")]["state"] == "cached" and rows[("a", "ingest")]["run_id"] == first["run_id"]
    assert rows[("b", "walls")] == next(
        r for r in first["stages"] if (r["room"], r["stage"]) == ("b", "walls")
    )

    # status under the default config: room a's outputs came from another configuration
    capsys.readouterr()
    assert main(["status", str(survey), "--work", str(work)]) == 0
    flagged = [line for line in capsys.readouterr().out.splitlines() if line.startswith("outputs/")]
    assert any(line.startswith("outputs/rooms/a/: from run " + second["run_id"]) for line in flagged)
    assert not any(line.startswith("outputs/rooms/b/") for line in flagged)
    # and under room a's config, room b is the odd one
    assert main(["status", str(survey), "--work", str(work), "--set", "walls.shadow_m=0.9"]) == 0
    flagged = [line for line in capsys.readouterr().out.splitlines() if line.startswith("outputs/rooms/")]
    assert [line.split(":")[0] for line in flagged] == ["outputs/rooms/b/"]


# -------------------------------------------------------------------------------------- fault injection


@pytest.mark.slow
def test_oserror_half_way_through_a_stage_writer_leaves_nothing_partial(
    tmp_path, capsys, monkeypatch, prefect_harness
):
    import contextlib

    from tasks import artefacts

    survey = small_survey(tmp_path / "s")
    work = tmp_path / "w"
    assert main(["-q", "run", str(survey), "--work", str(work)]) == 0
    capsys.readouterr()
    before = snapshot(work)
    store = ArtefactStore(work)
    walls_a = store.latest("a", "walls")
    manifest_before = json.loads((work / "outputs" / "manifest.json").read_text())

    real_atomic_path = artefacts.atomic_path
    writes: list[Path] = []

    @contextlib.contextmanager
    def full_disk(path: Path):
        with real_atomic_path(path) as tmp:
            if "/cache/a/walls/.tmp-" in str(path):
                writes.append(Path(path))
                if len(writes) == 2:  # the stage's second file: half of it reaches the disk
                    yield tmp
                    data = tmp.read_bytes() if tmp.exists() else b""
                    tmp.write_bytes(data[: len(data) // 2])
                    raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
            yield tmp

    monkeypatch.setattr(artefacts, "atomic_path", full_disk)
    code = main(["-q", "rerun", str(survey), "--work", str(work), "--stage", "walls"])
    err = capsys.readouterr().err
    assert len(writes) == 2, writes
    assert code == 3, err  # room b's walls were recomputed, room a's failed: partial
    assert "room a, stage walls" in err and "No space left on device" in err
    assert temporaries(work) == []  # nothing partial remains
    assert not list((work / "cache" / "a" / "walls").glob(".*"))
    # the previous artefacts are intact, byte for byte, and so are room a's outputs; room b's walls were
    # recomputed to the same bytes; only the floor index is new (it now lists room a as failed)
    after = snapshot(work)
    assert {k: after.get(k) for k in before if k != "outputs/rooms.parquet"} == {
        k: v for k, v in before.items() if k != "outputs/rooms.parquet"
    }
    assert {k for k in after if k not in before} == {
        k for k in after if k.startswith("cache/_building/floor_index/")
    } - {k for k in before}
    assert store.lookup("a", "walls", walls_a.key) == walls_a
    manifest = json.loads((work / "outputs" / "manifest.json").read_text())
    assert manifest["partial"] is True
    assert manifest["rooms"]["a"]["state"] == "failed"
    assert (
        manifest["rooms"]["a"]["run_id"] == manifest_before["rooms"]["a"]["run_id"]
    )  # still the earlier outputs
    assert manifest["rooms"]["b"]["state"] == "done"
    monkeypatch.setattr(artefacts, "atomic_path", real_atomic_path)

    # a full disk while publishing: outputs/ is left exactly as it was (new copies are made aside first)
    real_copy = artefacts.shutil.copyfile
    copies: list[str] = []

    def copy_then_fail(src, dst, *args, **kwargs):
        if "/outputs/" in str(dst):
            copies.append(str(dst))
            if len(copies) == 2:
                Path(dst).write_bytes(b"half")
                raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        return real_copy(src, dst, *args, **kwargs)

    monkeypatch.setattr(artefacts.shutil, "copyfile", copy_then_fail)
    outputs_before = {k: v for k, v in snapshot(work).items() if k.startswith("outputs/")}
    manifest_bytes = (work / "outputs" / "manifest.json").read_bytes()
    code = main(["-q", "run", str(survey), "--work", str(work), "--set", "preprocess.voxel_size_m=0.06"])
    capsys.readouterr()
    assert len(copies) == 2 and code == 1
    assert {k: v for k, v in snapshot(work).items() if k.startswith("outputs/")} == outputs_before
    assert (work / "outputs" / "manifest.json").read_bytes() == manifest_bytes
    assert temporaries(work) == []


@pytest.mark.slow
def test_sigkill_at_random_moments_of_a_cold_run(tmp_path, prefect_harness):
    """Cold runs (INDOOR_SURVEY_KILL_TRIALS, default 5 to keep the suite short; the README's figure is
    from 20), each killed with SIGKILL at a random moment of it, then run again: every final
    artefact equals a clean run's by content hash, and nothing a killed run left half-written is read
    (its files are overwritten with garbage before the rerun, and the rerun's opens are audited)."""
    survey = small_survey(tmp_path / "s")
    env = prefect_env()
    # Two clean cold runs: the first warms the file caches and is the reference; the second, timed, is
    # as long as the trials' runs (and must give the same bytes: the run is deterministic).
    cold = 0.0
    for name in ("clean", "clean2"):
        started = time.perf_counter()
        cmd = cli("-q", "run", str(survey), "--work", str(tmp_path / name))
        done = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=600)
        cold = time.perf_counter() - started
        assert done.returncode == 0, done.stderr
    reference = snapshot(tmp_path / "clean")
    assert snapshot(tmp_path / "clean2") == reference
    assert any(k.startswith("outputs/rooms/a/") for k in reference)

    script = tmp_path / "audited_run.py"
    script.write_text(AUDITED_RUN)
    trials = int(os.environ.get("INDOOR_SURVEY_KILL_TRIALS", "5"))
    moments = np.sort(np.random.default_rng(2026).uniform(0.03, 0.97, trials) * cold)
    outcomes = []
    for trial, moment in enumerate(moments):
        # A run may go faster than the timed one (the machine is shared): one that finishes before its
        # kill is not a trial; it is run again, in a fresh work dir, killed at half the moment.
        early = 0
        while True:
            work = tmp_path / f"w{trial}-{early}"
            cmd = cli("-q", "run", str(survey), "--work", str(work))
            proc = subprocess.Popen(
                cmd, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )
            try:
                proc.wait(timeout=moment)
            except subprocess.TimeoutExpired:
                break  # still running at its moment: kill it
            early += 1
            moment /= 2
            assert early < 5, "the run keeps finishing before it can be killed"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        left = temporaries(work) if work.is_dir() else []
        for thing in left:  # poison what the killed run left: reading any of it would change a hash
            for f in [thing] if thing.is_file() else [p for p in thing.rglob("*") if p.is_file()]:
                f.write_bytes(b"POISON")
        watch = tmp_path / f"watch{trial}.json"
        watch.write_text(json.dumps([str(p) for p in left] or ["\0none"]))
        audit = tmp_path / f"audit{trial}.json"
        rerun = subprocess.run(
            [sys.executable, str(script), "-q", "run", str(survey), "--work", str(work)],
            env={**env, "AUDIT_WATCH": str(watch), "AUDIT_OUT": str(audit)},
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=600,
        )
        reads = json.loads(audit.read_text()) if audit.is_file() else None
        final = snapshot(work) if rerun.returncode == 0 else {}
        manifest = (
            json.loads((work / "outputs" / "manifest.json").read_text()) if rerun.returncode == 0 else {}
        )
        outcomes.append(
            {
                "moment_s": round(float(moment), 2),
                "runs_that_finished_first": early,
                "left_partial": len(left),
                "rerun_code": rerun.returncode,
                "partial_reads": reads,
                "equal": final == reference,
                "complete": manifest.get("partial") is False
                and all(r["state"] in ("computed", "cached") for r in manifest.get("stages", [])),
                "temporaries_after": len(temporaries(work)),
                "err": rerun.stderr[-300:] if rerun.returncode else "",
            }
        )
    report = json.dumps({"cold_s": round(cold, 1), "trials": outcomes}, indent=1)
    print(report)
    (Path(os.environ.get("INDOOR_SURVEY_SAFETY_REPORT", tmp_path / "report.json"))).write_text(report)
    assert all(o["rerun_code"] == 0 for o in outcomes), report
    assert all(o["equal"] and o["complete"] for o in outcomes), report
    assert all(o["partial_reads"] == [] for o in outcomes), report
    assert all(o["temporaries_after"] == 0 for o in outcomes), report


@pytest.mark.slow
def test_two_concurrent_runs_compute_every_stage_once(tmp_path, prefect_harness):
    survey = small_survey(tmp_path / "s")
    work = tmp_path / "w"
    env = prefect_env()

    def start() -> subprocess.Popen:
        return subprocess.Popen(
            cli("run", str(survey), "--work", str(work)),
            env=env,
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    first = start()
    deadline = time.time() + 120
    while not (work / ".lock.json").is_file():  # the first holds the lock
        assert first.poll() is None and time.time() < deadline
        time.sleep(0.05)
    second = start()
    out1, err1 = first.communicate(timeout=600)
    out2, err2 = second.communicate(timeout=600)
    assert first.returncode == 0 and second.returncode == 0, (err1, err2)
    waits = [line for line in err2.splitlines() if "is in use by" in line]
    assert len(waits) == 1 and f"pid {first.pid} " in waits[0]  # said once, naming the first run
    s1, s2 = summary_states(out1), summary_states(out2)
    assert set(s1) == set(s2) and len(s1) >= 7
    assert set(s1.values()) == {"computed"}
    assert set(s2.values()) == {"cached"}  # the second found everything done: computed once in all
    manifest = json.loads((work / "outputs" / "manifest.json").read_text())
    first_id = next(line for line in out1.splitlines() if "stage runs:" in line).split("run ")[-1]
    assert manifest["run_id"] != first_id
    assert all(r["state"] == "cached" and r["run_id"] == first_id for r in manifest["stages"])


def test_optional_inputs_a_stage_ran_without_are_named(tmp_path):
    from flows.planning import StageCall, ran_without
    from tasks.artefacts import StageResult

    ingest = StageResult("a", "ingest", "k", str(tmp_path))
    calibrate = StageResult("_building", "calibrate", "k", str(tmp_path))
    call = StageCall("register", "a", str(tmp_path), {}, {}, raw_inputs={"capture": "x.mcap"})
    # register without a plan (failed or none), a calibration (failed) and a track (none in the survey)
    assert ran_without(call, {"ingest": ingest}) == ["calibrate", "plan", "track"]
    with_track = StageCall("register", "a", str(tmp_path), {}, {}, raw_inputs={"track": "t.csv"})
    assert ran_without(with_track, {"ingest": ingest, "calibrate": calibrate}) == ["plan"]
    # a stage with nothing optional never says so
    walls = StageCall("walls", "a", str(tmp_path), {}, {})
    assert ran_without(walls, {"preprocess": ingest}) == []
