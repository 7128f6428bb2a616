"""Prefect's settings for indoor-survey runs, applied by the entry point (the CLI, the test session)
before Prefect is imported: nothing is set as a side effect of importing a module. And the embedded API
server of a run, which must die with the run however the run ends (see `embedded_server`)."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import socket
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

DEFAULTS = {
    # Offline, quiet and patient: the embedded server needs more than the default 20 s to start here.
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DO_NOT_TRACK": "1",
    # Stage failures are reported by the run summary in one line each; Prefect's own copy of them is a
    # traceback. PREFECT_LOGGING_LEVEL=ERROR in the environment brings those back for debugging.
    "PREFECT_LOGGING_LEVEL": "CRITICAL",
    # The embedded server is stopped when a run ends; its event writer's cancellation is not an error.
    "PREFECT_SERVER_LOGGING_LEVEL": "CRITICAL",
    "PREFECT_LOGGING_TO_API_ENABLED": "false",
    "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "true",
}


def apply() -> None:
    """Set each default that the environment does not already set."""
    for name, value in DEFAULTS.items():
        os.environ.setdefault(name, value)


# ------------------------------------------------------------------------------------ embedded server

SERVER_RECORD = "prefect-server.json"
"""In the work dir: the embedded server of the run using it (pids and start times), so that a later run
can stop a server whose run died without it."""

_LAUNCHER = """\
import ctypes, gc, os, runpy, signal, sys
# Die with the run: the kernel sends SIGKILL to this process when the thread that started it ends, even
# when the run is killed with SIGKILL (no handler or atexit of the run's can do that).
try:
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
except (OSError, AttributeError):
    pass  # not Linux: the next run's reaping stops an orphan instead
if os.getppid() != int(sys.argv[1]):
    sys.exit(1)  # the run died before the signal was armed
# The start is imports and the building of the API (the pydantic models and schemas of every route):
# millions of objects that live as long as the server, in which the collector's frequent young
# collections find nothing to free, at about a sixth of the start's CPU time. So it collects rarely
# until the app is built (Prefect then collects once), and as usual after.
usual = gc.get_threshold()
gc.set_threshold(100_000, 50, 50)
import prefect.server.api.server as server
build = server.create_app
def create_app(*args, **kwargs):
    try:
        return build(*args, **kwargs)
    finally:
        gc.set_threshold(*usual)
server.create_app = create_app
sys.argv = ["uvicorn", *sys.argv[2:]]
runpy.run_module("uvicorn", run_name="__main__", alter_sys=True)
"""
"""Run as `python -c _LAUNCHER RUN_PID UVICORN_ARGS...`: Prefect's embedded server (uvicorn serving
Prefect's app factory) in a process tied to the run's."""


def _prefect_home() -> Path:
    return Path(os.environ.get("PREFECT_HOME", Path.home() / ".prefect")).expanduser()


def _profile_settings() -> dict[str, object]:
    """The settings of Prefect's active profile (PREFECT_HOME/profiles.toml), read without importing
    Prefect; empty when there is none."""
    try:
        import tomllib

        profiles = tomllib.loads((_prefect_home() / "profiles.toml").read_text())
    except (OSError, ValueError):
        return {}
    active = os.environ.get("PREFECT_PROFILE") or profiles.get("active", "ephemeral")
    settings = (profiles.get("profiles") or {}).get(active) or {}
    return settings if isinstance(settings, dict) else {}


def api_url_configured() -> bool:
    """Whether Prefect is told to use a running server (the environment, an active profile, or a test
    harness' settings), in which case a run starts none."""
    if os.environ.get("PREFECT_API_URL"):
        return True
    if "prefect.settings" in sys.modules:
        from prefect.settings import PREFECT_API_URL

        return bool(PREFECT_API_URL.value())
    return bool(_profile_settings().get("PREFECT_API_URL"))


SERVER_SETTINGS = {
    # Block types are registered into the database for the UI and the blocks API, which a run's server
    # has none of and the run does not use (its result storage is a local path): about 1.3 CPU s of each
    # start (importing every installed Prefect collection, prefect-dask and Dask among them).
    "PREFECT_API_BLOCKS_REGISTER_ON_START": "false",
    "PREFECT_MEMOIZE_BLOCK_AUTO_REGISTRATION": "false",
    # py-key-value (under the server's task queue) wraps each of its modules in runtime type checks that
    # only warn: about 0.8 CPU s of the server's imports.
    "PY_KEY_VALUE_DISABLE_BEARTYPE": "true",
}
"""What the embedded server is started with, unless the environment says otherwise: settings that make
its start cheaper without touching what a run or `serve` asks of it."""

DB_RECORD = "indoor-survey-database.json"
"""In PREFECT_HOME: the migration revision that the database had when a server last migrated it, and
the Prefect version that did it: a later start skips the migrations while both still hold."""


def _default_database() -> Path | None:
    """The SQLite file of the server's database when it is Prefect's default one (PREFECT_HOME/prefect.db),
    None when the environment or the profile sets any database setting (then migrations always run)."""
    profile = _profile_settings()
    for name in [*os.environ, *profile]:
        if name.startswith(("PREFECT_API_DATABASE_", "PREFECT_SERVER_DATABASE_")):
            return None
    return _prefect_home() / "prefect.db"


def _revision(database: Path) -> str | None:
    """The database's migration revision (alembic_version), read-only; None when it has none."""
    if not database.is_file():
        return None
    try:
        with contextlib.closing(sqlite3.connect(f"file:{database}?mode=ro", uri=True, timeout=5)) as db:
            rows = db.execute("SELECT version_num FROM alembic_version").fetchall()
    except sqlite3.Error:
        return None
    return str(rows[0][0]) if len(rows) == 1 else None


def _prefect_version() -> str:
    from importlib.metadata import version

    return version("prefect")


def database_is_migrated(database: Path | None) -> bool:
    """Whether `database` is at the revision this Prefect version last migrated it to (DB_RECORD)."""
    if database is None:
        return False
    try:
        record = json.loads((database.parent / DB_RECORD).read_text())
    except (OSError, ValueError):
        return False
    return (
        isinstance(record, dict)
        and record.get("database") == str(database)
        and record.get("prefect") == _prefect_version()
        and record.get("revision") is not None
        and record.get("revision") == _revision(database)
    )


def record_migrated(database: Path | None) -> None:
    """After a server that ran the migrations answers: note the revision they left (atomically)."""
    if database is None:
        return
    revision = _revision(database)
    if revision is None:
        return
    record = {"database": str(database), "prefect": _prefect_version(), "revision": revision}
    tmp = database.parent / f".{DB_RECORD}.{os.getpid()}"
    try:
        tmp.write_text(json.dumps(record))
        os.replace(tmp, database.parent / DB_RECORD)
    except OSError:
        tmp.unlink(missing_ok=True)


def _start_time(pid: int) -> int | None:
    """A process's start time (clock ticks after boot, /proc/PID/stat field 22), or None when it is gone:
    a pid together with its start time names one process, never a later one that reuses the pid."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[19])


def _alive(pid: int, started: int | None) -> bool:
    return started is not None and _start_time(pid) == started


def reap_stale_server(work: Path) -> bool:
    """Stop the embedded server a dead run left in `work` (its record names it); True if one was stopped.
    A server whose run is alive is left alone."""
    record_path = Path(work) / SERVER_RECORD
    try:
        record = json.loads(record_path.read_text())
        server, run = int(record["server_pid"]), int(record["run_pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return False
    if _alive(run, record.get("run_started")):
        return False
    stopped = False
    if _alive(server, record.get("server_started")):
        try:
            cmdline = Path(f"/proc/{server}/cmdline").read_bytes()
        except OSError:
            cmdline = b""
        if b"prefect.server.api.server:create_app" in cmdline:
            with contextlib.suppress(OSError):
                os.kill(server, 9)
                stopped = True
    record_path.unlink(missing_ok=True)
    return stopped


def _free_port() -> int:
    with contextlib.closing(socket.socket(socket.AF_INET, socket.SOCK_STREAM)) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _launch(port: int, migrate: bool = True) -> subprocess.Popen[bytes]:
    """Prefect's embedded server (the uvicorn arguments and environment Prefect itself uses for it, and
    SERVER_SETTINGS), through the launcher that ties its life to this process. `migrate=False`: the
    database is known to be current, so its migrations are not checked again."""
    spec = importlib.util.find_spec("prefect")
    assert spec is not None and spec.submodule_search_locations
    app_dir = str(Path(next(iter(spec.submodule_search_locations))).parent)
    server = [
        "--app-dir",
        app_dir,
        "--factory",
        "prefect.server.api.server:create_app",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--log-level",
        "error",
        "--lifespan",
        "on",
    ]
    env = {
        **SERVER_SETTINGS,
        **({} if migrate else {"PREFECT_API_DATABASE_MIGRATE_ON_START": "false"}),
        **os.environ,
        "PREFECT_UI_ENABLED": "0",
        "PREFECT__SERVER_EPHEMERAL": "1",
        "PREFECT__SERVER_FINAL": "1",
    }
    return subprocess.Popen(
        [sys.executable, "-c", _LAUNCHER, str(os.getpid()), *server], env=env, stdin=subprocess.DEVNULL
    )


def _stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _refresh_prefect_settings() -> None:
    """Make an already imported Prefect read PREFECT_API_URL from the environment again."""
    if "prefect.context" in sys.modules:
        from prefect.context import refresh_global_settings_context

        refresh_global_settings_context()


def _record(work: Path, proc: subprocess.Popen[bytes], port: int) -> None:
    record = {
        "server_pid": proc.pid,
        "server_started": _start_time(proc.pid),
        "run_pid": os.getpid(),
        "run_started": _start_time(os.getpid()),
        "port": port,
    }
    (work / SERVER_RECORD).write_text(json.dumps(record))


class Launched:
    """Prefect's embedded server, launched and not yet answering: `launch` starts it as early as a
    command knows that it needs one, `embedded_server` adopts it (records it in the work dir, waits)."""

    def __init__(self, timeout: float) -> None:
        self.deadline = time.monotonic() + timeout
        self.timeout = timeout
        self.database = _default_database()
        self.migrate = not database_is_migrated(self.database)
        self.port = _free_port()
        self.proc = _launch(self.port, self.migrate)

    def relaunch(self) -> None:
        """Again on another port (the one chosen was taken meanwhile)."""
        self.port = _free_port()
        self.proc = _launch(self.port, self.migrate)

    def stop(self) -> None:
        """Stop it (and wait for its end) unless it has ended already."""
        if self.proc.returncode is None:
            _stop(self.proc)


def _timeout() -> float:
    return float(os.environ.get("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120"))


def launch() -> Launched | None:
    """Start a run's embedded server now, to be adopted by `embedded_server` (None: Prefect is told to
    use a running server). For a command that knows before its own imports and checks that it will run
    a flow (a rerun): the server's start (about 4 CPU s of imports in its own process) then overlaps
    them. The caller stops it (`Launched.stop`) if it ends before adopting it."""
    return None if api_url_configured() else Launched(_timeout())


WARM_UP = "/admin/version"
"""Requested once the server answers, before the run's first own request: the first request through
the API's routers builds FastAPI's state of every route (about 0.3 CPU s of the server), which the flow
would otherwise wait for. Any answer will do (even a refusal, e.g. with PREFECT_SERVER_API_AUTH_STRING)."""


def _use(url: str | None) -> None:
    """Point Prefect at `url` (None: at no server), whether or not it is imported yet."""
    if url is None:
        os.environ.pop("PREFECT_API_URL", None)
    else:
        os.environ["PREFECT_API_URL"] = url
    _refresh_prefect_settings()


def _wait(work: Path, server: Launched, meanwhile: Callable[[], object] | None = None) -> str:
    """Record the launched server, point Prefect at it, run `meanwhile` (the run's own start-up: the
    server's start is mostly its imports, a few CPU seconds in its own process, which the run's imports
    can overlap; Prefect imported then reads the server's URL as it imports), and wait until the server
    answers and has served one request of the API (WARM_UP); its API URL."""
    _record(work, server.proc, server.port)
    _use(f"http://127.0.0.1:{server.port}/api")
    if meanwhile is not None:
        meanwhile()
    while True:
        proc, url = server.proc, f"http://127.0.0.1:{server.port}/api"
        while proc.poll() is None:
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2) as reply:
                    if reply.status == 200:
                        if server.migrate:
                            record_migrated(server.database)
                        with contextlib.suppress(urllib.error.URLError, OSError):
                            left = max(2.0, server.deadline - time.monotonic())
                            urllib.request.urlopen(url + WARM_UP, timeout=left).close()
                        return url
            except (urllib.error.URLError, OSError):
                pass
            if time.monotonic() > server.deadline:
                raise RuntimeError(
                    f"Prefect's embedded server did not answer within {server.timeout:.0f} s "
                    "(PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS)"
                )
            time.sleep(0.05)
        if proc.returncode != 3 or time.monotonic() > server.deadline:  # 3: the port was taken meanwhile
            raise RuntimeError(f"Prefect's embedded server exited with code {proc.returncode}")
        server.relaunch()
        _record(work, server.proc, server.port)
        _use(f"http://127.0.0.1:{server.port}/api")


def _end(server: Launched, work: Path) -> None:
    server.stop()
    (work / SERVER_RECORD).unlink(missing_ok=True)


@contextlib.contextmanager
def embedded_server(
    work: Path,
    meanwhile: Callable[[], object] | None = None,
    launched: Launched | None = None,
    stop_later: contextlib.ExitStack | None = None,
) -> Iterator[str | None]:
    """Prefect's embedded API server for one run, yielding its URL (None, and nothing started, when
    Prefect is told to use a running server). `meanwhile` (e.g. importing the flows, which imports
    Prefect) runs while the server starts, in this thread; it runs in any case. `launched`: the server,
    started earlier by `launch` (in this thread); else it is started now. On leaving, the server is
    told to stop; `stop_later`: the wait for its end (a graceful stop takes 0.1-0.3 s) and the removal
    of its record are left to that stack, so that what the command does after its run overlaps them.

    Prefect would start this server itself, as a child process that outlives a killed or aborted run; a
    machine that reprocesses nightly then collects orphaned servers. Started here instead, it is the
    run's child with a parent-death signal (Linux: it is killed with the run, even by SIGKILL), stopped
    when the run ends, and recorded in WORK/prefect-server.json so that the next run in the work dir
    stops one that a dead run left (e.g. where no parent-death signal exists). Call it from the main
    thread: the signal follows the thread that started the server."""
    if api_url_configured():
        if launched is not None:
            launched.stop()
        if meanwhile is not None:
            meanwhile()
        yield None
        return
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    reap_stale_server(work)
    server = launched if launched is not None else Launched(_timeout())
    try:
        yield _wait(work, server, meanwhile)
    finally:
        if server.proc.returncode is None:
            server.proc.terminate()  # it stops while Prefect's settings are put back
        _use(None)
        if stop_later is None:
            _end(server, work)
        else:
            stop_later.callback(_end, server, work)
