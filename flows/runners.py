"""The task runner that runs a survey's rooms: Prefect's thread pool (one machine), or Dask.

With `dask`, each room's task (`flows.pipeline.room_task`) is one Dask task; inside it the room's stages
run one after another as before, on the Dask worker. Without an address, a `distributed.LocalCluster` is
started for the run with `flow.max_workers` worker *processes* of one thread each, and closed when the run
ends. Processes rather than threads: a room's task then runs exactly as it would on a remote worker
(its call, results and fan-in cross a process boundary as pickled plain data, and it reaches the Prefect
API and the work dir on its own), so a single machine exercises the multi-machine path; and a room's
pure-Python parts do not share one interpreter lock with the other rooms. With an address, the run uses
an existing scheduler (`dask scheduler` plus `dask worker` processes on every machine); every worker must
see WORK at the same path and reach the run's Prefect API (see README "Scale-out").

Everything here is imported only when a run starts (Prefect and Dask are slow to import).
"""

from __future__ import annotations

import logging
import re
from typing import Any

RUNNERS = ("threads", "dask")

_ADDRESS = re.compile(r"^(tcp|tls|ucx|inproc)://[^\s/:]+(:\d{1,5})?$")


class RunnerError(ValueError):
    """A runner choice that cannot work (a one-line message for the user)."""


def check_address(address: str) -> str:
    """A Dask scheduler address `tcp://HOST:PORT` as given, or a one-line error saying what is wrong."""
    if not _ADDRESS.match(address):
        raise RunnerError(
            f"--dask-address {address!r}: expected a Dask scheduler address such as tcp://HOST:8786"
        )
    return address


def check_choice(kind: str, address: str | None) -> None:
    """A one-line error for a runner choice that cannot work; imports nothing."""
    if kind not in RUNNERS:
        raise RunnerError(f"--runner {kind!r}: expected one of {', '.join(RUNNERS)}")
    if address:
        if kind != "dask":
            raise RunnerError("--dask-address needs --runner dask")
        check_address(address)


def task_runner(kind: str, workers: int, address: str | None = None) -> Any:
    """The Prefect task runner for `kind` ("threads" or "dask") with `workers` rooms at once.

    threads: `ThreadPoolTaskRunner(max_workers=workers)`. dask: prefect-dask's `DaskTaskRunner` on the
    scheduler at `address`, or on a LocalCluster of `workers` single-threaded worker processes."""
    check_choice(kind, address)
    workers = max(1, int(workers))
    if kind == "threads":
        from prefect.task_runners import ThreadPoolTaskRunner

        return ThreadPoolTaskRunner(max_workers=workers)
    from prefect_dask import DaskTaskRunner

    # Dask's start-up and shut-down chatter (tens of INFO lines) is not the run's progress
    logging.getLogger("distributed").setLevel(logging.WARNING)

    if address:
        return DaskTaskRunner(address=address)
    return DaskTaskRunner(
        cluster_class="distributed.LocalCluster",
        cluster_kwargs={
            "n_workers": workers,
            "threads_per_worker": 1,
            "processes": True,
            # the scheduler's HTTP routes (it always starts them) on a free loopback port, not 8787
            "dashboard_address": "127.0.0.1:0",
            "host": "127.0.0.1",
        },
    )
