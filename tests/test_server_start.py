"""The start and end of a run's own Prefect server (flows/prefect_env.py) and of the command's process
(flows/cli.py `entry`), on stand-ins: a sleeping process for the server, a tiny HTTP server for its API."""

from __future__ import annotations

import contextlib
import http.server
import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from flows import prefect_env
from flows.cli import main
from tests.captures import write_box_room_ply, write_survey

REPO = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def fake_api() -> Iterator[tuple[int, list[str]]]:
    """An HTTP server answering 200 to every GET: (its port, the paths asked for, in order)."""
    paths: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            paths.append(self.path)
            self.send_response(200)
            self.send_header("Content-Length", "4")
            self.end_headers()
            self.wfile.write(b"true")

        def log_message(self, *args: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1], paths
    finally:
        server.shutdown()
        server.server_close()


@pytest.fixture
def stand_in(monkeypatch: pytest.MonkeyPatch) -> list[subprocess.Popen[bytes]]:
    """Each server a run launches is a sleeping process instead (listed in launch order); no running
    server is configured."""
    launched: list[subprocess.Popen[bytes]] = []

    def launch(port: int, migrate: bool = True) -> subprocess.Popen[bytes]:
        launched.append(subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"]))
        return launched[-1]

    monkeypatch.setattr(prefect_env, "_launch", launch)
    monkeypatch.setattr(prefect_env, "api_url_configured", lambda: False)
    monkeypatch.setattr(prefect_env, "_default_database", lambda: None)
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    yield launched
    for proc in launched:
        proc.kill()
        proc.wait()


def test_prefect_reads_the_servers_url_before_it_answers_and_a_request_warms_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stand_in: list[subprocess.Popen[bytes]]
) -> None:
    """While the server starts, the run imports Prefect with the server's URL set (no settings to read
    again once it answers); the server counts as started after its health answer and one request of
    the API's routers (which builds their routes); its stop is waited for by the command's stack."""
    seen: list[str | None] = []
    with fake_api() as (port, paths), contextlib.ExitStack() as stack:
        monkeypatch.setattr(prefect_env, "_free_port", lambda: port)
        meanwhile = lambda: seen.append(os.environ.get("PREFECT_API_URL"))  # noqa: E731
        with prefect_env.embedded_server(tmp_path, meanwhile, stop_later=stack) as url:
            assert url == f"http://127.0.0.1:{port}/api"
            assert seen == [url]
            assert paths == ["/api/health", "/api" + prefect_env.WARM_UP]
            assert (tmp_path / prefect_env.SERVER_RECORD).is_file()
        assert "PREFECT_API_URL" not in os.environ
        [server] = stand_in
        assert (tmp_path / prefect_env.SERVER_RECORD).is_file()  # told to stop, not yet waited for
        stack.close()
        assert server.returncode is not None
        assert not (tmp_path / prefect_env.SERVER_RECORD).exists()


def test_a_server_that_never_answers_is_stopped_and_its_record_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, stand_in: list[subprocess.Popen[bytes]]
) -> None:
    monkeypatch.setenv("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "1")  # Prefect reads an int
    monkeypatch.setattr(prefect_env, "_free_port", prefect_env._free_port)  # nobody listens there
    with pytest.raises(RuntimeError, match="did not answer within"):
        with prefect_env.embedded_server(tmp_path):
            pass
    [server] = stand_in
    assert server.returncode is not None
    assert not (tmp_path / prefect_env.SERVER_RECORD).exists()
    assert "PREFECT_API_URL" not in os.environ


def test_a_rerun_refused_after_launching_its_server_stops_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stand_in: list[subprocess.Popen[bytes]]
) -> None:
    """A rerun launches Prefect's server before its own checks; a bad invocation then stops it, and the
    work dir gets no server record."""
    survey = write_survey(tmp_path / "s", {"a": "rooms/a/cloud.ply"})
    write_box_room_ply(survey / "rooms" / "a" / "cloud.ply", np.random.default_rng(0), spacing_m=0.2)
    work = tmp_path / "w"
    assert main(["rerun", str(survey), "--work", str(work), "--stage", "walz"]) == 2
    assert "unknown stage 'walz'" in capsys.readouterr().err
    [server] = stand_in
    assert server.returncode is not None  # stopped and reaped
    assert not (work / prefect_env.SERVER_RECORD).exists()


def test_the_command_ends_without_teardown_but_runs_exit_handlers_and_flushes(tmp_path: Path) -> None:
    marker = tmp_path / "atexit-ran"
    script = (
        "import atexit, sys\n"
        f"atexit.register(lambda: open({str(marker)!r}, 'w').write('ran'))\n"
        "from flows.cli import entry\n"
        "entry(sys.argv[1:])\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-c", script, "config"], env=env, cwd=REPO, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    assert marker.read_text() == "ran"
    assert done.stdout.startswith("flow:") and done.stdout.endswith("\n")  # all of it, flushed
    bad = subprocess.run(
        [sys.executable, "-m", "flows.cli", "status", str(tmp_path / "s"), "--work", str(tmp_path / "none")],
        env=env,
        cwd=REPO,
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2
    assert bad.stderr.startswith("error: --work") and bad.stderr.count("\n") == 1


def test_few_collections_raises_the_threshold_inside_only() -> None:
    import gc

    from flows.memory import few_collections

    usual = gc.get_threshold()
    with pytest.raises(KeyError), few_collections():
        assert gc.get_threshold()[0] > 10 * usual[0]
        raise KeyError("inside")
    assert gc.get_threshold() == usual


@pytest.mark.slow
def test_the_launched_server_is_prefects_and_answers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The launcher runs uvicorn on Prefect's app factory (collecting rarely until the app is built): the
    API answers, and the process is named as the reaping of a dead run's server expects."""
    import json
    import urllib.request

    import prefect

    monkeypatch.setattr(prefect_env, "api_url_configured", lambda: False)
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    with prefect_env.embedded_server(tmp_path) as url:
        assert url is not None
        with urllib.request.urlopen(url + "/admin/version", timeout=30) as reply:
            assert json.loads(reply.read()) == prefect.__version__
        pid = json.loads((tmp_path / prefect_env.SERVER_RECORD).read_text())["server_pid"]
        assert b"prefect.server.api.server:create_app" in Path(f"/proc/{pid}/cmdline").read_bytes()
    assert not Path(f"/proc/{pid}").exists()  # stopped and reaped
