"""`indoor-survey serve`: the survey run as a Prefect deployment on a cron schedule.

`survey_flow` is what a scheduled (or manually triggered) run executes: the same work as `indoor-survey
run` (the building flow as a subflow, so only what a changed capture, config or code touches is
recomputed; nothing at all, and no subflow, when every stage is current), and a record of the run in
WORK/runs/<timestamp>/ (config.yaml, summary.json). `serve` registers it with `flow.serve` and polls for
due runs until stopped (Ctrl-C or SIGTERM); each run executes in a child process.

Prefect's settings must be applied (`flows.prefect_env.apply()`) before this module is imported.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import signal
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from prefect import flow

from flows import planning
from flows.report_cmd import write_report_safely
from flows.worklock import work_lock
from tasks import config as cfgmod
from tasks.artefacts import write_json

log = logging.getLogger("indoor_survey")

FLOW_NAME = "indoor-survey"
"""The served flow's name: a deployment is addressed as `indoor-survey/<deployment name>`."""


class ServeError(ValueError):
    """A bad `serve` invocation: a one-line message for the user."""


def check_cron(cron: str, timezone: str | None = None) -> None:
    """A one-line error for a cron expression (five fields) or time zone Prefect would refuse."""
    from prefect.client.schemas.schedules import CronSchedule

    if len(cron.split()) != 5:
        raise ServeError(
            f"--cron {cron!r}: expected five fields, minute hour day month weekday (e.g. '0 2 * * *')"
        )
    try:
        CronSchedule(cron=cron, timezone=timezone)
    except ValueError as exc:
        errors = getattr(exc, "errors", None)  # pydantic: the first error's message, without its URL
        detail = errors()[0]["msg"] if callable(errors) and errors() else str(exc)
        what = f"--cron {cron!r}" + (f" --timezone {timezone!r}" if timezone else "")
        raise ServeError(f"{what}: {' '.join(str(detail).split())}") from None


def _record(work: Path, rows: list[planning.StageOutcome], saved: Path) -> Path:
    """WORK/runs/<timestamp>/summary.json beside the run's config.yaml: every stage's state."""
    path = saved.parent / "summary.json"
    counts = Counter(r.state for r in rows)
    write_json(
        path,
        {
            "counts": dict(sorted(counts.items())),
            "stages": [
                {
                    "room": r.room,
                    "stage": r.stage,
                    "state": r.state,
                    "seconds": round(r.seconds, 3),
                    "error": r.error,
                }
                for r in rows
            ],
        },
    )
    return path


@flow(name=FLOW_NAME, log_prints=False, validate_parameters=False, persist_result=False)
def survey_flow(
    survey: str,
    work: str,
    config_files: list[str] | None = None,
    sets: list[str] | None = None,
    runner: str = "threads",
    dask_address: str | None = None,
) -> list[planning.StageOutcome]:
    """One run of a survey into a work dir, as `indoor-survey run` does it: every stage that is not current
    is computed, the deliverables published, WORK/runs/<timestamp>/{config.yaml,summary.json} written.
    Raises (the flow run fails) when a stage failed; returns every stage's outcome."""
    config_files = list(config_files or [])
    sets = list(sets or [])
    cfg = cfgmod.load_config([Path(p) for p in config_files], sets)
    req = planning.RunRequest(
        survey=str(Path(survey).resolve()),
        work=str(Path(work).resolve()),
        config_files=tuple(config_files),
        sets=tuple(sets),
    )
    started = time.perf_counter()
    argv = ["indoor-survey", "serve", req.survey, "--work", req.work]
    # one writer at a time: a scheduled run waits for a `run` (or an earlier scheduled run) on this work dir
    with work_lock(Path(req.work), command=" ".join(argv), notify=log.warning):
        planning.store_for(req.work).sweep_temporaries()  # what a killed run left half-written
        rows = planning.all_current(req)
        if rows is None:
            from flows import pipeline

            rows = pipeline.run_survey(req, runner, dask_address)
        saved = planning.save_resolved_config(Path(req.work), cfg, argv)
        summary = _record(Path(req.work), rows, saved)
        planning.write_truth_metrics(req, rows)
        write_report_safely(Path(req.work), log.warning)
    counts = Counter(r.state for r in rows)
    log.warning(
        "survey %s: %s in %.1f s (%s)",
        req.survey,
        ", ".join(f"{n} {s}" for s, n in sorted(counts.items())),
        time.perf_counter() - started,
        summary,
    )
    failed = [r for r in rows if r.state == "failed"]
    if failed:
        first = failed[0]
        raise RuntimeError(
            f"{len(failed)} stage run(s) failed; first: room {first.room}, stage {first.stage}: {first.error}"
        )
    return rows


def serve(
    survey: Path,
    work: Path,
    cron: str,
    name: str,
    config_files: list[str],
    sets: list[str],
    timezone: str | None = None,
    runner: str = "threads",
    dask_address: str | None = None,
) -> None:
    """Register `survey_flow` for this survey as deployment `indoor-survey/<name>` with the cron schedule
    and execute its runs until stopped. Uses the Prefect API that PREFECT_API_URL (or the active profile)
    names; without one, an embedded server that lives as long as this process."""
    from prefect.schedules import Cron

    from flows import prefect_env

    parameters: dict[str, Any] = {
        "survey": str(survey.resolve()),
        "work": str(work.resolve()),
        "config_files": [str(Path(p).resolve()) for p in config_files],
        "sets": list(sets),
        "runner": runner,
        "dask_address": dask_address,
    }
    with prefect_env.embedded_server(work) as url:
        if url is not None:
            print(f"Prefect API (embedded, lives with this process): {url}", file=sys.stderr)
        from prefect.runner import Runner
        from prefect.types.entrypoint import EntrypointType

        runner = Runner(name=name)  # its schedule is paused when serve stops, resumed when it starts
        runner.add_flow(
            survey_flow,
            name=name,
            schedule=Cron(cron, timezone=timezone),
            parameters=parameters,
            description=f"indoor-survey run of {parameters['survey']} into {parameters['work']}",
            entrypoint_type=EntrypointType.MODULE_PATH,  # flows.serve.survey_flow: independent of the cwd
        )
        _run_until_stopped(runner)


def _run_until_stopped(runner: Any) -> None:
    """`runner.start()` until SIGINT or SIGTERM, either of which stops it cleanly (Prefect's own SIGTERM
    handler exits from inside the event loop, with tracebacks in the log: it is replaced by a cancel)."""

    async def main() -> None:
        started = asyncio.ensure_future(runner.start())
        for _ in range(200):  # start() installs its handler before its first await
            if started.done() or signal.getsignal(signal.SIGTERM) == runner.handle_sigterm:
                break
            await asyncio.sleep(0.05)
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, started.cancel)
        with contextlib.suppress(asyncio.CancelledError):
            await started

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())


def cmd_serve(args: argparse.Namespace) -> int:
    """The `serve` verb: checks everything before it registers anything."""
    from flows.cli import CliError

    try:
        return _serve_checked(args)
    except (
        CliError
    ) as exc:  # also when the CLI runs as `python -m flows.cli`, whose CliError is another class
        raise ServeError(str(exc)) from None


def _serve_checked(args: argparse.Namespace) -> int:
    from flows.cli import check_folder, writable_folder
    from flows.runners import RunnerError, check_choice

    work = check_folder(args.work, "--work").resolve()
    cfgmod.load_config(args.config, args.set)
    survey = cfgmod.load_survey(args.survey)
    try:
        check_cron(args.cron, args.timezone)
        check_choice(args.runner, args.dask_address)
    except RunnerError as exc:
        raise ServeError(str(exc)) from None
    for room in survey.rooms:
        if not room.capture.exists():
            raise ServeError(
                f"{survey.root / 'survey.yaml'}: room {room.id}: capture {room.capture} does not exist"
            )
    name = args.name or survey.name
    if not name or "/" in name:
        raise ServeError(f"--name {name!r}: a deployment name must be non-empty and without '/'")
    writable_folder(work, "--work")
    print(
        f"serving {FLOW_NAME}/{name}: {survey.root} into {work} on cron '{args.cron}'"
        f"{' (' + args.timezone + ')' if args.timezone else ' (UTC)'}; Ctrl-C stops",
        file=sys.stderr,
    )
    serve(
        survey.root,
        work,
        args.cron,
        name,
        [str(p) for p in args.config],
        list(args.set),
        args.timezone,
        args.runner,
        args.dask_address,
    )
    return 0


def summary_of(work: Path) -> dict[str, Any] | None:
    """The latest run record's summary.json in WORK/runs, or None."""
    records = sorted(Path(work).glob("runs/*/summary.json"))
    return json.loads(records[-1].read_text()) if records else None
