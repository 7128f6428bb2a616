"""The `indoor-survey` command line.

Every command checks its inputs before any work starts (a bad survey, config key, file or work dir gives
one line naming it and exit code 2), prints progress on long work to stderr, and leaves what was computed
before untouched when it fails. Whatever goes wrong, a command ends with one line, never a traceback
(INDOOR_SURVEY_DEBUG=1 shows it): exit 0 done, 3 partial (some rooms or stages failed, others finished),
1 nothing finished (or an unexpected error), 2 bad input or invocation (a busy work dir with --no-wait).
Commands that write a work dir hold its lock (flows.worklock) while they do; `status` only reads.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import logging
import os
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from flows.prefect_env import Launched

DESCRIPTION = """\
indoor-survey: turn low-cost indoor captures (RGB-D recordings, TLS clouds) plus a coarse floor plan
into as-built room models (after Khosravani 2016).

A survey is a folder with survey.yaml (see README). Every stage is cached by content: a rerun recomputes
only what a changed input, parameter or stage code touches. Stage caches live in WORK/cache, the
deliverables in WORK/outputs.
"""

EPILOG = """\
examples:
  indoor-survey run data/mini --work work/mini
  indoor-survey run data/mini --work work/mini --set preprocess.voxel_size_m=0.03
  indoor-survey rerun data/mini --work work/mini --stage preprocess --room r5
  indoor-survey status data/mini --work work/mini
  indoor-survey serve data/mini --work work/mini --cron "0 2 * * *"
  indoor-survey model-room room.ply --out room_model
"""


class CliError(Exception):
    """A one-line error for the user (exit code 2)."""


EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_PARTIAL = 0, 1, 2, 3
"""README "Errors and exit codes": done; nothing finished (every room failed) or an unexpected error; bad
input or invocation; partial (some rooms or stages failed, the others finished)."""

DEBUG_VARIABLE = "INDOOR_SURVEY_DEBUG"


def check_folder(path: Path, what: str) -> Path:
    """`path` as a folder to use (it may not exist yet): a one-line error when it, or a folder above it,
    is a file. Writes nothing."""
    path = Path(path).expanduser()
    for folder in (path, *path.parents):
        if folder.exists() or folder.is_symlink():
            if not folder.is_dir():
                where = "is a file" if folder == path else f"lies below {folder}, which is a file"
                raise CliError(f"{what} {path}: {where}, not a folder")
            break
    return path


def writable_folder(path: Path, what: str) -> Path:
    """`path` created if needed and probed with a file that is removed again: a one-line error when
    nothing can be written there (a read-only or foreign folder). Call it after every other check, just
    before the first write."""
    path = check_folder(path, what)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        raise CliError(f"{what} {path}: cannot write there ({exc.strerror or exc})") from None
    return path


def _user_errors() -> tuple[type[BaseException], ...]:
    from flows.worklock import WorkDirBusy
    from tasks.artefacts import ArtefactError
    from tasks.cloud import DegenerateInputError
    from tasks.config import ConfigError
    from tasks.ingest.errors import IngestError

    return (
        CliError,
        WorkDirBusy,
        ConfigError,
        ArtefactError,
        IngestError,
        DegenerateInputError,
        ValueError,
        FileNotFoundError,
    )


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _add_config_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        action="append",
        default=[],
        metavar="FILE",
        help="YAML overrides, applied after configs/default.yaml (repeatable)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="STAGE.KEY=VALUE",
        help="one override, e.g. --set preprocess.voxel_size_m=0.03 (repeatable; applied last)",
    )


def _add_work(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--work",
        type=Path,
        default=Path("work"),
        help="work directory: cache/ and outputs/ (default: ./work)",
    )


def _add_private_work(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--work",
        type=Path,
        default=None,
        help="stage cache: the verb runs the pipeline's own stages there, so a repeat recomputes nothing "
        "(default: OUT/.cache)",
    )
    _add_no_wait(p)


def _add_no_wait(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--no-wait",
        action="store_true",
        help="when another command is writing the work dir, exit 2 naming it instead of waiting for it",
    )


def _add_runner(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--runner",
        choices=["threads", "dask"],
        default="threads",
        help="what runs the rooms at once: a thread pool (default), or Dask (a local cluster of "
        "flow.max_workers processes, or the scheduler at --dask-address)",
    )
    p.add_argument(
        "--dask-address",
        default=None,
        metavar="tcp://HOST:PORT",
        help="with --runner dask: an existing Dask scheduler; its workers must see WORK at the same path",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="indoor-survey",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress output, only the summary")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run every stage on a survey (cached stages are not recomputed)")
    p.add_argument("survey", type=Path, help="survey folder (with survey.yaml)")
    _add_work(p)
    _add_config_args(p)
    p.add_argument("--rooms", nargs="+", default=[], metavar="ID", help="only these rooms (default: all)")
    _add_no_wait(p)
    _add_runner(p)

    p = sub.add_parser(
        "rerun",
        help="recompute one stage for one room or all (what follows it: only where its artefacts changed)",
    )
    p.add_argument("survey", type=Path)
    p.add_argument("--stage", required=True, help="stage to recompute, e.g. preprocess")
    p.add_argument("--room", default=None, help="only this room (default: every room)")
    _add_work(p)
    _add_config_args(p)
    _add_no_wait(p)
    _add_runner(p)

    p = sub.add_parser(
        "serve",
        help="run the survey on a cron schedule as a Prefect deployment (until stopped)",
        description="Registers deployment indoor-survey/NAME with the schedule and runs it when due (each run "
        "recomputes only what changed, as `run` does); uses the Prefect API of PREFECT_API_URL, else an "
        'embedded one. Ctrl-C or SIGTERM stops it. See README "Schedules".',
    )
    p.add_argument("survey", type=Path, help="survey folder (with survey.yaml)")
    p.add_argument("--cron", required=True, help='schedule, five fields, e.g. "0 2 * * *" (02:00 daily)')
    p.add_argument(
        "--timezone", default=None, help="time zone of the schedule, e.g. Europe/Berlin (default UTC)"
    )
    p.add_argument("--name", default=None, help="deployment name (default: the survey's name)")
    _add_work(p)
    _add_config_args(p)
    _add_runner(p)

    p = sub.add_parser("status", help="per room and stage: done, stale (inputs or config changed) or missing")
    p.add_argument("survey", type=Path)
    _add_work(p)
    _add_config_args(p)

    p = sub.add_parser("config", help="print the resolved configuration (defaults + files + --set)")
    _add_config_args(p)

    p = sub.add_parser(
        "model-room",
        help="ingest -> preprocess -> walls on one registered cloud (PLY/PCD/E57/LAS/LAZ, metres, z roughly up)",
        description="Model one room from a registered cloud. Writes walls.parquet, plan.geojson, model.ply, "
        "preview.png and levelling.json to --out; wall coordinates are in the cloud's own x-y frame.",
    )
    p.add_argument("cloud", type=Path, help="registered room cloud (PLY, PCD, E57, LAS or LAZ; metres)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    _add_private_work(p)
    _add_config_args(p)

    p = sub.add_parser(
        "evaluate-walls",
        help="wall completeness, correctness, accuracy, corner F1, angle error, room IoU of PRED vs TRUTH",
    )
    p.add_argument("pred", type=Path, help="predicted walls: walls.parquet or plan.geojson")
    p.add_argument(
        "truth",
        type=Path,
        help="truth walls: Parquet (x0 y0 x1 y1 ...) or GeoJSON LineStrings; with --points, labelled points",
    )
    p.add_argument(
        "--points",
        action="store_true",
        help="TRUTH is labelled points (a folder of <class>_<n>.txt files, or a text/CSV file of x y z label "
        "rows): completeness = share of wall points within the tolerance of a model wall, correctness = "
        "share of model wall length within it of a wall, column, door or window point, accuracy = mean and "
        "median distance of those wall points (plan view)",
    )
    p.add_argument("--tol-m", type=float, default=0.10, help="distance tolerance in metres (default 0.10)")

    p = sub.add_parser(
        "synth",
        help="write a synthetic building survey with ground truth (deterministic per seed)",
        description="Generate a complete survey folder: a floor with a hallway and rooms, RGB-D captures as "
        "ROS 2 MCAP, one TLS-like cloud, an IMU track, a calibration set, an evacuation-plan raster that "
        "differs from the as-built floor, and truth/. The same seed gives byte-identical files.",
    )
    p.add_argument("out", type=Path, help="output survey folder")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--rooms", type=int, default=None, help="number of rooms besides the hallway (default: all)"
    )
    p.add_argument("--profile", default="kinect_v1", choices=["kinect_v1", "kinect_v2", "tls"], help="sensor")
    p.add_argument(
        "--size", default="mini", choices=["mini", "full"], help="mini: 320x240, few frames; full: 640x480"
    )
    p.add_argument("--overwrite", action="store_true", help="replace the survey files in an existing OUT")

    p = sub.add_parser(
        "calibrate",
        help="RGB-D calibration from target images: Brown intrinsics, IR->RGB pose, disparity model",
        description="Writes OUT/calibration.json: {ir: {K, dist [k1 k2 p1 p2 k3], size, rms_px}, rgb: {...}, "
        "ir_to_rgb: {R, t_m}, stereo_rms_px, depth_model}. --ir alone calibrates one camera.",
    )
    p.add_argument(
        "--ir", required=True, metavar="GLOB", help="IR (or left) target images, e.g. 'cal/ir/*.png'"
    )
    p.add_argument("--rgb", default=None, metavar="GLOB", help="RGB (or right) images taken with the IR ones")
    p.add_argument(
        "--pattern",
        required=True,
        help="chessboard:COLSxROWS:SQUARE_M (inner corners) or circles:COLSxROWS:SPACING_M (asymmetric grid)",
    )
    p.add_argument("--flat", default=None, metavar="GLOB", help="raw disparity frames of a flat target")
    p.add_argument("--distances", default=None, help="their distances in metres, comma separated")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    _add_private_work(p)

    p = sub.add_parser(
        "parse-plan",
        help="coarse floor-plan raster -> metric wall centrelines with thickness, rooms, doors",
        description="Writes OUT/plan_walls.parquet (x0 y0 x1 y1 thickness_m), OUT/rooms.geojson and "
        "OUT/plan_preview.png, in metres with x right and y up: pixel (u, v) -> (u*s, -v*s).",
    )
    p.add_argument(
        "image", type=Path, help="plan raster (PNG or JPG): an evacuation plan photo or a CAD drawing"
    )
    p.add_argument("--out", type=Path, required=True)
    _add_private_work(p)
    # no scale given: the stage reads the scale bar printed on the plan, else its dimension lines (its
    # metrics say which was used)
    scale = p.add_mutually_exclusive_group()
    scale.add_argument(
        "--m-per-px",
        type=float,
        help="metres per pixel (default: read the printed scale bar, else the dimension lines)",
    )
    scale.add_argument(
        "--known-distance", metavar="X0,Y0,X1,Y1,METRES", help="two pixels and their distance in metres"
    )
    scale.add_argument("--outline-length", type=float, metavar="METRES", help="building outline perimeter")

    p = sub.add_parser(
        "register-room",
        help="ingest -> SfM -> metric scale -> fused coloured cloud for one RGB-D capture",
        description="Writes OUT/poses.parquet (frame_id t_ns qw qx qy qz tx ty tz method), OUT/cloud.ply and "
        "OUT/scale.json. CAPTURE is an MCAP recording, a TUM RGB-D folder or a 7-Scenes folder.",
    )
    p.add_argument("capture", type=Path)
    p.add_argument("--out", type=Path, required=True)
    _add_private_work(p)
    p.add_argument("--intrinsics", default=None, metavar="FX,FY,CX,CY", help="pinhole intrinsics (pixels)")
    p.add_argument(
        "--depth-scale", type=float, default=None, metavar="UNITS_PER_M", help="depth units per metre"
    )
    p.add_argument("--calibration", type=Path, default=None, help="calibration.json from `calibrate`")
    p.add_argument("--sensor", default="kinect_v1", help="sensor profile when there is no calibration")

    from flows import report_cmd

    report_cmd.add_parser(sub)
    return parser


def _setup_logging(quiet: bool) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", datefmt="%H:%M:%S"))
    log = logging.getLogger("indoor_survey")
    log.handlers[:] = [handler]
    log.setLevel(logging.WARNING if quiet else logging.INFO)
    log.propagate = False


def cmd_run(args: argparse.Namespace, force_stage: str | None = None) -> int:
    # A rerun always runs a flow (its forced stages): Prefect's server starts before this command's own
    # imports and checks, which then overlap its start; it is stopped when the command ends, unless the
    # run adopted it.
    launched = _launch_server(args) if force_stage else None
    from flows import planning
    from tasks import config as cfgmod

    work = check_folder(args.work, "--work").resolve()
    cfg = cfgmod.load_config(args.config, args.set)
    survey = cfgmod.load_survey(args.survey)
    rooms = list(getattr(args, "rooms", []) or ([args.room] if getattr(args, "room", None) else []))
    rooms = list(dict.fromkeys(rooms))  # --rooms r5 r5: once
    for room in rooms:
        survey.room(room)
    # A room whose capture is missing or unreadable fails alone, with its reason, and the other rooms run
    # (flows.planning.plan_survey); only when no requested room can run is it bad input.
    requested = [survey.room(r) for r in rooms] if rooms else survey.rooms
    problems = {room.id: planning.capture_problem(room.capture) for room in requested}
    if requested and all(problems.values()):
        raise CliError(
            "; ".join(
                f"{survey.root / 'survey.yaml'}: room {room}: {problem}" for room, problem in problems.items()
            )
        )
    if survey.plan is not None and not survey.plan.image.is_file():
        raise CliError(f"{survey.root / 'survey.yaml'}: plan.image {survey.plan.image} does not exist")
    force: list[tuple[str, str]] = []
    if force_stage:
        if force_stage not in planning.STAGES:
            raise CliError(f"unknown stage {force_stage!r} (stages: {', '.join(planning.STAGES)})")
        if planning.STAGES[force_stage].partition == "room":
            force = [(r, force_stage) for r in (rooms or survey.room_ids)]
        elif rooms:
            raise CliError(
                f"--room {rooms[0]}: stage {force_stage} is a building stage (one run for the whole "
                "survey); drop --room"
            )
        else:
            force = [(planning.BUILDING, force_stage)]
    runner, address = getattr(args, "runner", "threads"), getattr(args, "dask_address", None)
    if address or runner != "threads":
        from flows.runners import RunnerError, check_choice

        try:
            check_choice(runner, address)
        except RunnerError as exc:
            raise CliError(str(exc)) from None
    argv = ["indoor-survey", *sys.argv[1:]]
    req = planning.RunRequest(
        survey=str(survey.root),
        work=str(work),
        config_files=tuple(str(p) for p in args.config),
        sets=tuple(args.set),
        rooms=tuple(rooms),
        force=tuple(force),
    )
    writable_folder(work, "--work")  # the last check: from here on the run writes
    _lock(args, work)
    planning.store_for(work).sweep_temporaries()  # what a killed run left half-written
    planning.load_code_memo(work)
    started = time.perf_counter()
    # A rerun always has work (its forced stages); a run may be answered from the store alone
    rows = None if req.force else planning.all_current(req)
    saved = planning.save_resolved_config(work, cfg, argv)
    if rows is None:
        from flows import prefect_env
        from flows.ahead import Ahead

        prefect_env.apply()
        # While Prefect's server starts in another process, this one imports the flows and computes the
        # stages that are ready and short (flows/ahead.py); with a running server there is no wait to fill.
        ahead = None if prefect_env.api_url_configured() else Ahead(req)

        def import_flows() -> None:
            if ahead is not None:
                ahead.start()
                ahead.planned.wait()  # it has read the stages' code versions
            from flows import memory

            with memory.few_collections():
                from flows import pipeline  # (Prefect's import)

                pipeline.preload()
            if ahead is None:
                planning.read_code_versions()
                planning.save_code_memo(work)

        try:
            # Prefect's server lives and dies with this run
            with prefect_env.embedded_server(work, import_flows, launched, args.exit_stack) as embedded:
                from flows import pipeline

                done = ahead.finish() if ahead is not None else {}
                if done:
                    print(
                        f"{len(done)} stage runs computed while Prefect's server started "
                        f"({time.perf_counter() - started:.1f} s)",
                        file=sys.stderr,
                    )
                rows = pipeline.run_survey(req, runner, address, heartbeats=embedded is None, ahead=done)
        finally:
            if ahead is not None:
                ahead.finish()
    else:
        planning.save_code_memo(work)
        print("every stage is current: nothing to compute (Prefect not started)", file=sys.stderr)
    elapsed = time.perf_counter() - started
    print(f"{'room':<12} {'stage':<12} {'state':<9} {'seconds':>8}")
    for row in rows:
        note = f"  {row.error}" if row.error else ""
        without = _ran_without(row)
        if without:
            note += f"  ran without {', '.join(without)}"
        print(f"{row.room:<12} {row.stage:<12} {row.state:<9} {row.seconds:8.2f}{note}")
    counts = {
        s: sum(r.state == s for r in rows) for s in ("computed", "cached", "stored", "failed", "skipped")
    }
    summary = ", ".join(f"{n} {s}" for s, n in counts.items() if n)
    for what, path in survey.outside_inputs():
        print(f"note: {what} {path} lies outside the survey folder {survey.root}")
    print(f"{len(rows)} stage runs: {summary}; {elapsed:.1f} s; config saved to {saved}; run {req.run_id}")
    metrics = planning.write_truth_metrics(req, rows)
    if metrics is not None:
        from tasks.artefacts import read_json

        summary = read_json(metrics)["summary"]
        print(
            "against truth/: completeness {mean_completeness:.3f}, correctness {mean_correctness:.3f}, "
            "mean accuracy {acc}, corner F1 {mean_corner_f1:.2f} ({metrics})".format(
                acc=f"{1000 * summary['mean_accuracy_mean_m']:.1f} mm"
                if summary["mean_accuracy_mean_m"]
                else "n/a",
                metrics=metrics,
                **{k: v or 0.0 for k, v in summary.items() if k != "mean_accuracy_mean_m"},
            )
        )
    from flows.report_cmd import write_report_safely

    report = write_report_safely(work, lambda line: print(line, file=sys.stderr))
    if report is not None:
        print(f"report: {report}")
    failed = [r for r in rows if r.state == "failed"]
    for row in failed:
        print(f"error: room {row.room}, stage {row.stage}: {_one_line(row.error)}", file=sys.stderr)
    return {"done": EXIT_OK, "partial": EXIT_PARTIAL, "failed": EXIT_FAILED}[planning.exit_state(rows)]


def _launch_server(args: argparse.Namespace) -> Launched | None:
    """Prefect's embedded server for this command's run, launched now (None with a running server)."""
    from flows import prefect_env

    prefect_env.apply()
    launched = prefect_env.launch()
    if launched is not None:
        args.exit_stack.callback(launched.stop)  # the command ended before its run adopted it
    return launched


def _ran_without(row: object) -> list[str]:
    """The optional inputs a finished stage ran without (from its manifest: computed now or earlier)."""
    result = getattr(row, "result", None)
    if result is None:
        return []
    try:
        without = result.manifest.get("ran_without") or []
    except Exception:
        return []
    return [str(name) for name in without]


def _lock(args: argparse.Namespace, work: Path) -> None:
    """Hold `work`'s lock until the command ends (waiting for another writer, or with --no-wait not)."""
    from flows.worklock import work_lock

    stack: contextlib.ExitStack = args.exit_stack
    stack.enter_context(work_lock(work, wait=not getattr(args, "no_wait", False)))


def cmd_status(args: argparse.Namespace) -> int:
    from flows import planning, status

    work = check_folder(args.work, "--work")
    if not work.is_dir():
        raise CliError(f"--work {args.work}: no such work dir (pass --work DIR of an earlier run)")
    planning.store_for(work).read_only = True  # status reads: it writes nothing into the work dir
    states = status.survey_status(args.survey, work, args.config, args.set)
    print(f"{'room':<12} {'stage':<12} {'status':<8} detail")
    for state in states:
        call = state.planned.call
        print(f"{call.room:<12} {call.stage:<12} {state.status:<8} {state.detail}")
    for line in status.outputs_mismatch(work, args.config, args.set):
        print(line)
    return 0


def cmd_config(args: argparse.Namespace) -> int:
    from tasks import config as cfgmod

    print(cfgmod.to_yaml(cfgmod.load_config(args.config, args.set)), end="")
    return 0


def cmd_model_room(args: argparse.Namespace) -> int:
    import json

    from flows import oneoff
    from tasks import config as cfgmod

    cfg = cfgmod.load_config(args.config, args.set)
    if not args.cloud.is_file():
        raise CliError(f"{args.cloud}: no such file")
    _out_and_work(args)
    metrics = oneoff.model_room(args.cloud, args.out, args.work, cfg)
    walls = metrics["walls"]
    pre = metrics["preprocess"]
    print(
        json.dumps(
            {
                "walls": walls.get("walls"),
                "closed": walls.get("closed"),
                "alpha": walls.get("alpha"),
                "height_m": pre.get("height_m"),
                "out": str(args.out),
            }
        )
    )
    return 0


def cmd_evaluate_walls(args: argparse.Namespace) -> int:
    import json

    from tasks.artefacts import read_segments
    from tasks.evaluate import evaluate_walls, evaluate_walls_on_points, read_labelled_points

    pred, _ = read_segments(args.pred)
    if args.points:
        try:
            pts, labels = read_labelled_points(args.truth)
        except ValueError as exc:
            raise CliError(str(exc)) from None
        if not (labels == "wall").any():
            raise CliError(f"{args.truth}: no point is labelled wall")
        print(json.dumps(evaluate_walls_on_points(pred, pts[:, :2], labels, args.tol_m), indent=2))
        return 0
    truth, _ = read_segments(args.truth)
    if len(truth) == 0:
        raise CliError(f"{args.truth}: no walls")
    print(json.dumps(evaluate_walls(pred, truth, args.tol_m), indent=2))
    return 0


def cmd_synth(args: argparse.Namespace) -> int:
    from tasks.synth.survey import generate_survey

    out = check_folder(args.out, "OUT")
    if out.is_dir() and any(out.iterdir()) and not args.overwrite:
        raise CliError(f"OUT {out}: the folder is not empty; pass --overwrite to replace its survey files")
    writable_folder(out, "OUT")
    started = time.perf_counter()
    out = generate_survey(
        args.out,
        seed=args.seed,
        rooms=args.rooms,
        profile=args.profile,
        size=args.size,
        overwrite=args.overwrite,
    )
    print(f"survey written to {out} in {time.perf_counter() - started:.1f} s")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from flows import oneoff

    distances = None
    if args.distances:
        try:
            distances = [float(v) for v in args.distances.split(",")]
        except ValueError as exc:
            raise CliError(f"--distances {args.distances!r}: expected metres separated by commas") from exc
    _out_and_work(args)
    path = oneoff.calibrate(
        args.out,
        args.ir,
        args.rgb,
        args.pattern,
        flat_glob=args.flat,
        known_distances=distances,
        work=args.work,
    )
    print(f"calibration written to {path}")
    return 0


def cmd_parse_plan(args: argparse.Namespace) -> int:
    import json

    from flows import oneoff

    known = None
    if args.known_distance:
        try:
            known = tuple(float(v) for v in args.known_distance.split(","))
        except ValueError as exc:
            raise CliError(f"--known-distance {args.known_distance!r}: expected x0,y0,x1,y1,metres") from exc
        if len(known) != 5:
            raise CliError(
                f"--known-distance {args.known_distance!r}: expected five numbers x0,y0,x1,y1,metres"
            )
    for option, value in (("--m-per-px", args.m_per_px), ("--outline-length", args.outline_length)):
        if value is not None and not 0 < value < float("inf"):
            raise CliError(f"{option} {value}: expected a positive number")
    if not args.image.is_file():
        raise CliError(f"{args.image}: no such image file")
    _out_and_work(args)
    report = oneoff.parse_plan(
        args.image, args.out, args.m_per_px, known, args.outline_length, work=args.work
    )
    keep = {k: v for k, v in report.items() if isinstance(v, int | float | str)}
    print(json.dumps(keep, indent=2))
    return 0


def cmd_register_room(args: argparse.Namespace) -> int:
    import json

    from flows import oneoff
    from tasks import config as cfgmod

    sets = []
    if args.intrinsics is not None:
        try:
            values = [float(v) for v in args.intrinsics.split(",")]
        except ValueError:
            values = []
        if len(values) != 4 or not all(abs(v) < float("inf") for v in values):
            raise CliError(f"--intrinsics {args.intrinsics!r}: expected four numbers fx,fy,cx,cy in pixels")
        if values[0] <= 0 or values[1] <= 0:
            raise CliError(f"--intrinsics {args.intrinsics!r}: the focal lengths fx, fy must be positive")
        sets.append(f"ingest.intrinsics_px={values}")
    if args.depth_scale is not None:
        if not 0 < args.depth_scale < float("inf"):
            raise CliError(f"--depth-scale {args.depth_scale}: expected positive depth units per metre")
        sets.append(f"ingest.tum_depth_units_per_m={float(args.depth_scale)}")
    cfg = cfgmod.load_config([], sets)
    if not args.capture.exists():
        raise CliError(f"{args.capture}: no such capture")
    if args.calibration is not None:
        _check_calibration(args.calibration)
    cfgmod.load_sensor_profile(args.sensor)
    _out_and_work(args)
    report = oneoff.register_room(args.capture, args.out, args.sensor, args.calibration, args.work, cfg)
    print(json.dumps(report, indent=2, default=str))
    return 0


def _check_calibration(path: Path) -> None:
    """--calibration: a calibration.json `calibrate` could have written, or a one-line error naming it."""
    from tasks.calibrate.stage import read_calibration

    if not path.is_file():
        raise CliError(f"--calibration {path}: no such file")
    try:
        read_calibration(path)
    except ValueError:
        raise
    except Exception as exc:  # a JSON of another shape: {"ir": 5}, a list...
        raise CliError(f"{path}: not a calibration.json ({type(exc).__name__}: {_one_line(exc)})") from None


def _out_and_work(args: argparse.Namespace) -> None:
    """A one-off verb's OUT and private work dir: folders (not files) that can be written."""
    check_folder(args.out, "--out")
    if args.work is not None:
        check_folder(args.work, "--work")
    writable_folder(args.out, "--out")
    work = writable_folder(args.work if args.work is not None else Path(args.out) / ".cache", "--work")
    _lock(args, work)


COMMANDS = {
    "model-room": cmd_model_room,
    "evaluate-walls": cmd_evaluate_walls,
    "synth": cmd_synth,
    "calibrate": cmd_calibrate,
    "register-room": cmd_register_room,
    "parse-plan": cmd_parse_plan,
}


def _dispatch(args: argparse.Namespace) -> int:
    if args.command == "run":
        return cmd_run(args)
    if args.command == "rerun":
        return cmd_run(args, force_stage=args.stage)
    if args.command == "status":
        return cmd_status(args)
    if args.command == "serve":
        from flows import prefect_env

        prefect_env.apply()
        from flows.serve import cmd_serve

        return cmd_serve(args)
    if args.command == "config":
        return cmd_config(args)
    if args.command == "report":
        from flows import report_cmd

        return report_cmd.run(args)
    return COMMANDS[args.command](args)


def main(argv: Sequence[str] | None = None) -> int:
    """The error boundary of every verb: whatever fails, one line on stderr and the README's exit code."""
    from tasks.artefacts import StageError

    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args.quiet)
    if args.command in ("run", "rerun"):  # rooms on pool threads: few malloc arenas (flows/memory.py)
        from flows import memory

        memory.limit_arenas(2)
    debug = bool(os.environ.get(DEBUG_VARIABLE))
    try:
        with contextlib.ExitStack() as stack:  # holds a work-dir lock taken by the command
            args.exit_stack = stack
            return _dispatch(args)
    except StageError as exc:  # a stage's unexpected failure, already one line naming its inputs
        if debug:
            traceback.print_exc()
        where = f"room {exc.room}, stage {exc.stage}: " if exc.stage else ""
        print(f"error: {where}{_one_line(exc)}", file=sys.stderr)
        return EXIT_FAILED
    except _user_errors() as exc:
        if debug:
            traceback.print_exc()
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:
        if debug:
            traceback.print_exc()
        print(
            f"error: {args.command}: unexpected {type(exc).__name__}: {_one_line(exc)[:300]} "
            f"(set {DEBUG_VARIABLE}=1 for the traceback)",
            file=sys.stderr,
        )
        return EXIT_FAILED


def entry(argv: Sequence[str] | None = None) -> NoReturn:
    """The `indoor-survey` command: `main`, then the process ends without the interpreter's teardown.
    With Prefect, Open3D and the like imported, tearing every module down costs about 0.5 CPU s at the
    end of each command, and leaves nothing to do: `main` has closed its files, stopped Prefect's server
    and released the work dir's lock before it returns. The exit handlers (`atexit`) still run and the
    output is flushed; a thread still working (none should be) gets the ordinary exit, which waits."""
    code = main(argv)
    others = [t for t in threading.enumerate() if t is not threading.main_thread()]
    if any(t.is_alive() and not t.daemon for t in others):
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # e.g. a closed pipe: nothing more can be said
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
