"""The work-dir lock: one writer per work directory at a time.

`run`, `rerun` and the one-off verbs hold an exclusive `flock` on WORK/.lock (through `filelock`) for as
long as they write the work dir; `status` and reports read without it. The kernel drops a `flock` when
the process holding it dies, however it dies (SIGKILL included), so a lock is never left stale: the next
run takes it at once. Beside it the holder writes WORK/.lock.json (pid, host, start time, command) so that
a run that has to wait can say who it waits for; that sidecar is only a description: a sidecar whose
process is gone (its holder was killed and nobody has taken the lock since) is never reported as the
holder.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import socket
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from filelock import Timeout, UnixFileLock

LOCK_NAME = ".lock"
SIDECAR_NAME = ".lock.json"


class WorkDirBusy(Exception):
    """The work dir is locked by another process and the caller asked not to wait (exit code 2)."""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def read_holder(work: Path) -> dict[str, Any] | None:
    """The sidecar's description of the holder, or None when there is none, it is unreadable, or it names
    a process of this host that no longer exists (a killed holder's leftover)."""
    try:
        info = json.loads((Path(work) / SIDECAR_NAME).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or not isinstance(info.get("pid"), int):
        return None
    if info.get("host") == socket.gethostname() and not _alive(info["pid"]):
        return None
    return info


def describe_holder(work: Path) -> str:
    """One phrase naming who holds the lock of `work`."""
    info = read_holder(work)
    if info is None:
        return "another process (it has not described itself yet)"
    command = f", {info['command']}" if info.get("command") else ""
    return f"pid {info['pid']} on {info.get('host', '?')}, started {info.get('started', '?')}{command}"


def _write_sidecar(work: Path, command: str) -> None:
    info = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "command": command,
    }
    path = Path(work) / SIDECAR_NAME
    tmp = path.with_name(f"{SIDECAR_NAME}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(info) + "\n")
    os.replace(tmp, path)


@contextlib.contextmanager
def work_lock(
    work: Path,
    wait: bool = True,
    command: str = "",
    notify: Callable[[str], None] | None = None,
) -> Iterator[None]:
    """Hold the exclusive lock of `work` (created if needed) for the block. When another process holds it:
    with `wait`, say once who (through `notify`, default stderr) and block until it is free; without,
    raise WorkDirBusy naming the holder."""
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    lock = UnixFileLock(str(work / LOCK_NAME), preserve_lock_file=True, thread_local=False)
    try:
        lock.acquire(timeout=0)
    except Timeout:
        holder = describe_holder(work)
        if not wait:
            raise WorkDirBusy(
                f"work dir {work} is in use by {holder}; wait for it, or drop --no-wait to queue"
            ) from None
        say = notify or (lambda message: print(message, file=sys.stderr, flush=True))
        say(f"work dir {work} is in use by {holder}: waiting for it to finish")
        lock.acquire()
    try:
        _write_sidecar(work, command or " ".join(["indoor-survey", *sys.argv[1:]]))
        yield
    finally:
        with contextlib.suppress(OSError):
            (work / SIDECAR_NAME).unlink()
        lock.release()
