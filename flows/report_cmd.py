"""`indoor-survey report WORK`: rebuild WORK/outputs/report.html from what the work dir holds. Reads the
store and outputs/ only: recomputes nothing, starts no Prefect."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

HELP = "rebuild WORK/outputs/report.html from a finished work dir (recomputes nothing)"
DESCRIPTION = """\
Write WORK/outputs/report.html: one self-contained page (pictures embedded, no network) with the fused
floor, a section per room (wall model, height histogram, figures, automatic choices), the rooms that
failed with their error, accuracy against truth where the survey has it, and the run (per-stage timings,
computed or cached, configuration differences from the defaults, versions). It reads the work dir only:
nothing is recomputed. `run` writes the same report at its end.
"""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """The `report` verb's parser."""
    p = subparsers.add_parser("report", help=HELP, description=DESCRIPTION)
    p.add_argument("work", type=Path, help="work dir of a run (holds cache/ and outputs/)")


def run(args: argparse.Namespace) -> int:
    """Write the report; prints its path and how long it took. A folder that is not a work dir is a
    one-line error (exit 2)."""
    from flows.cli import check_folder, writable_folder
    from tasks.report import write_report

    work = check_folder(args.work, "WORK")
    if not work.is_dir():
        raise ValueError(f"WORK {work}: no such folder")
    if not (work / "outputs").is_dir() and not (work / "cache").is_dir():
        raise ValueError(
            f"WORK {work}: no outputs/ or cache/ here: not the work dir of an `indoor-survey run`"
        )
    writable_folder(work / "outputs", "WORK/outputs")
    started = time.perf_counter()
    path = write_report(work)
    print(f"report written to {path} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    print(path)
    return 0


def write_report_safely(work: Path, warn: Callable[[str], object]) -> Path | None:
    """The report at the end of a run: its path, or None after a one-line warning (a report that cannot
    be written never fails a run whose stages finished)."""
    from tasks.report import write_report

    try:
        return write_report(work)
    except Exception as exc:
        warn(f"warning: report not written: {' '.join(str(exc).split())}")
        return None
