"""`indoor-survey serve`: the scheduled deployment, a run triggered through the Prefect API, and that a
scheduled run recomputes only what changed (a room added to the survey)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from flows import prefect_env

REPO = Path(__file__).resolve().parents[1]
CRON = "0 2 * * *"


def _tls_survey(folder: Path, rooms: int, seed: int = 0) -> Path:
    """A synthetic survey whose rooms are all registered TLS clouds (the cheapest rooms to model)."""
    from tasks.synth.survey import generate_survey

    return generate_survey(folder, seed=seed, rooms=rooms, profile="tls")


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    env.update(prefect_env.DEFAULTS)
    env.update(extra)
    return env


@contextlib.contextmanager
def _prefect_api(home: Path) -> Iterator[str]:
    """A Prefect API server on its own temporary PREFECT_HOME and SQLite database; its URL."""
    home.mkdir(parents=True, exist_ok=True)
    port = prefect_env._free_port()
    env = _env(
        PREFECT_HOME=str(home),
        PREFECT_API_DATABASE_CONNECTION_URL=f"sqlite+aiosqlite:///{home / 'prefect.db'}",
        PREFECT_UI_ENABLED="0",
    )
    command = [sys.executable, "-m", "uvicorn", "--factory", "prefect.server.api.server:create_app"]
    command += ["--host", "127.0.0.1", "--port", str(port), "--log-level", "error"]
    proc = subprocess.Popen(command, env=env, stdin=subprocess.DEVNULL, cwd=home)
    try:
        deadline = time.monotonic() + 180
        while True:
            assert proc.poll() is None, f"the Prefect API server exited with code {proc.returncode}"
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=2) as reply:
                    if reply.status == 200:
                        break
            except (urllib.error.URLError, OSError):
                pass
            assert time.monotonic() < deadline, "the Prefect API server did not answer within 180 s"
            time.sleep(0.2)
        yield f"http://127.0.0.1:{port}/api"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _wait_for(what: str, timeout: float, probe):
    deadline = time.monotonic() + timeout
    while True:
        value = probe()
        if value is not None:
            return value
        assert time.monotonic() < deadline, f"{what}: not within {timeout:.0f} s"
        time.sleep(1.0)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--cron", "0 2 * *"], "expected five fields"),
        (["--cron", "61 2 * * *"], "Invalid cron string"),
        (["--cron", "0 2 * * *", "--timezone", "Mars/Base"], "Invalid timezone"),
        (["--cron", "0 2 * * *", "--dask-address", "tcp://h:1"], "needs --runner dask"),
    ],
)
def test_serve_refuses_a_bad_schedule_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    from flows.cli import EXIT_BAD_INPUT, main

    code = main(["serve", str(REPO / "data" / "mini"), "--work", str(tmp_path / "w"), *argv])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_BAD_INPUT
    assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "w").exists()


@pytest.mark.slow
def test_serve_registers_the_cron_deployment_and_runs_it(tmp_path: Path) -> None:
    import psutil
    from prefect.client.orchestration import get_client
    from prefect.exceptions import ObjectNotFound
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows.serve import FLOW_NAME, summary_of

    survey = _tls_survey(tmp_path / "survey", rooms=1)  # r1 and the hallway, both TLS clouds
    work = tmp_path / "work"
    with _prefect_api(tmp_path / "prefect-home") as url:
        env = _env(PREFECT_API_URL=url, PREFECT_HOME=str(tmp_path / "prefect-home"))
        command = [sys.executable, "-m", "flows.cli", "-q", "serve", str(survey), "--work", str(work)]
        command += ["--cron", CRON, "--name", "nightly"]
        log = (tmp_path / "serve.log").open("wb")
        serve = subprocess.Popen(command, env=env, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT)
        family: set[psutil.Process] = set()
        try:
            with temporary_settings({PREFECT_API_URL: url}), get_client(sync_client=True) as client:

                def deployment():
                    assert serve.poll() is None, (tmp_path / "serve.log").read_text()[-2000:]
                    with contextlib.suppress(ObjectNotFound):
                        return client.read_deployment_by_name(f"{FLOW_NAME}/nightly")
                    return None

                found = _wait_for("the deployment", 300, deployment)
                crons = [s.schedule.cron for s in found.schedules if s.active]
                assert crons == [CRON]
                assert found.parameters["survey"] == str(survey.resolve())
                assert found.parameters["work"] == str(work.resolve())

                run = client.create_flow_run_from_deployment(found.id)

                def finished():
                    with contextlib.suppress(psutil.Error):
                        family.update(psutil.Process(serve.pid).children(recursive=True))
                    state = client.read_flow_run(run.id).state
                    return state if state is not None and state.is_final() else None

                state = _wait_for("the triggered run", 900, finished)
                assert state.is_completed(), f"{state.name}: {state.message}"
            summary = summary_of(work)
            assert summary is not None
            assert set(summary["counts"]) == {"computed"}, summary["counts"]  # a cold run: all computed
            stages = {(s["room"], s["stage"]) for s in summary["stages"]}
            assert {("r1", "walls"), ("hall", "walls"), ("_building", "fuse")} <= stages
            assert (work / "outputs" / "rooms" / "r1" / "walls.parquet").is_file()
        finally:
            with contextlib.suppress(psutil.Error):
                family.update(psutil.Process(serve.pid).children(recursive=True))
            serve.send_signal(signal.SIGTERM)  # what a service manager sends
            try:
                code = serve.wait(timeout=120)
            except subprocess.TimeoutExpired:
                serve.kill()
                code = serve.wait()
                for proc in family:
                    with contextlib.suppress(psutil.Error):
                        proc.kill()
                pytest.fail("serve did not stop within 120 s of SIGTERM")
            log.close()
        _, alive = psutil.wait_procs(list(family), timeout=30)
        assert not alive, f"serve left processes behind: {alive}"
        assert code == 0, (tmp_path / "serve.log").read_text()[-2000:]


@pytest.mark.slow
def test_a_scheduled_run_recomputes_only_the_added_room(tmp_path: Path, prefect_harness) -> None:
    """The flow a scheduled run executes, run twice: after a room folder is added to the survey, only that
    room's stages and the building stages that read every room run again."""
    from flows.serve import survey_flow
    from tasks.stages import stages_of

    survey = _tls_survey(tmp_path / "survey", rooms=2)  # r1 (TLS profile: a cloud), r5, hall
    spec = yaml.safe_load((survey / "survey.yaml").read_text())
    added = next(r for r in spec["rooms"] if r["id"] == "r1")
    shutil.move(survey / "rooms" / "r1", tmp_path / "r1-later")
    spec["rooms"].remove(added)
    (survey / "survey.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    work = tmp_path / "work"

    first = survey_flow(str(survey), str(work))
    assert {r.state for r in first} == {"computed"}
    assert "r1" not in {r.room for r in first}

    shutil.move(tmp_path / "r1-later", survey / "rooms" / "r1")
    spec["rooms"].append(added)
    (survey / "survey.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    second = survey_flow(str(survey), str(work))

    computed = {(r.room, r.stage) for r in second if r.state == "computed"}
    after = {s.name for s in stages_of("after")}
    room_stages = {r.stage for r in second if r.room == "r1"}
    assert room_stages  # ingest, preprocess, walls for a cloud
    assert computed == {("r1", s) for s in room_stages} | {("_building", s) for s in after}
    unchanged = [r for r in second if r.room != "r1" and r.stage not in after]
    assert len(unchanged) == len(first) - len(after)  # the plan and the other rooms' stages
    assert all(r.state in ("cached", "stored") for r in unchanged), [
        (r.room, r.stage, r.state) for r in unchanged
    ]
    assert (work / "outputs" / "rooms" / "r1" / "walls.parquet").is_file()
