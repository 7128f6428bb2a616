"""The speed table in one command: every figure of the speed targets, each from its own benchmark run in a
child process, with its accuracy figure beside it.

    python -m bench.all                 # the whole table (long: the SfM row alone maps 100 frames three times)
    python -m bench.all --quick         # smaller inputs, no walls_survey or data/mini run (a few minutes)
    python -m bench.all --json table.json

Run from the repository root. Rows:

- SfM: seconds per frame on real 640x480 Kinect frames, frames registered and ATE (`bench.sfm`), and the
  yardstick: the whole register stage's time over plain pycolmap's on the same frames;
- scale: seconds per frame of the metric scale (`bench.sfm`);
- register: the whole register stage on a rendered walk, time and peak resident memory (`bench.register`);
- preprocess: input points per second (`bench.preprocess`), with the distance of its output to the true
  surfaces;
- walls_survey: the preprocess stage's accuracy where it counts, the wall figures of `bench.walls_survey`
  (preprocess then walls on the generator's buildings), tuning and held-out means per sensor;
- walls: the 10 m x 10 m room at a 1 cm grid (`bench.walls`);
- data/mini: a cold `indoor-survey run` of the miniature survey into a fresh work dir, with the mean wall
  figures of its metrics.json.

Each row's benchmark runs alone, one after the other; the CPU seconds of its child process tree (user +
system, every thread) are printed beside the wall time, and the load average before each row, since wall
time on a shared machine says little by itself. A row whose benchmark fails or prints something
unexpected shows why and the table goes on.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

FULL = {"sfm_frames": 100, "register_frames": 300, "preprocess_points": 5_000_000, "walls_seeds": 1}
QUICK = {"sfm_frames": 30, "register_frames": 60, "preprocess_points": 1_000_000, "walls_seeds": 1}


def child(args: list[str], timeout_s: float) -> dict[str, Any]:
    """Run `python ARGS` from the repository root: stdout, return code, wall and CPU seconds (the child's
    process tree: getrusage of the waited-for children) and the load average before."""
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=timeout_s
        )
        out, err, code = proc.stdout, proc.stderr, proc.returncode
    except subprocess.TimeoutExpired as exc:
        out, err, code = str(exc.stdout or ""), f"timed out after {timeout_s:.0f} s", -1
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"stdout": out, "stderr": err, "code": code, "wall_s": wall, "cpu_s": cpu, "load": load}


def _failed(run: dict[str, Any]) -> str | None:
    if run["code"] == 0:
        return None
    tail = (run["stderr"] or run["stdout"]).strip().splitlines()[-1:] or ["no output"]
    return f"failed (exit {run['code']}): {tail[0][:200]}"


def _search(pattern: str, text: str) -> re.Match[str]:
    m = re.search(pattern, text)
    if m is None:
        raise ValueError(f"no line matching {pattern!r} in its output")
    return m


def row_sfm(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    n = size["sfm_frames"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "sfm.json"
        args = ["-m", "bench.sfm", "--frames", str(n), "--register-frames", "0", "--json", str(out)]
        args += ["--no-yardstick"] if quick else []
        for s in sets:
            args += ["--set", s]
        run = child(args, 3600)
        why = _failed(run)
        data = json.loads(out.read_text()) if why is None and out.exists() else {}
    if why or "sfm" not in data:
        return [{"row": "SfM", "error": why or "bench.sfm wrote no figures"}]
    s = data["sfm"]
    rows = [
        {
            "row": "SfM",
            "figure": f"{s['sfm_s_per_frame']:.3f} s/frame ({s['sfm_cpu_s_per_frame']:.3f} s CPU)",
            "accuracy": f"{s['registered']}/{s['frames']} registered, ATE {s['ate_cm']:.2f} cm",
            "input": f"{n} real 640x480 Kinect frames, SIFT octave {s.get('sift_first_octave', -1)}",
            "load": run["load"],
            "data": s,
        },
        {
            "row": "scale",
            "figure": f"{s['scale_s_per_frame']:.3f} s/frame ({s['scale_cpu_s_per_frame']:.3f} s CPU)",
            "accuracy": f"{s['scale_frames_used']} frames used",
            "input": f"{n} real frames",
            "load": run["load"],
            "data": s,
        },
    ]
    if "yardstick" in data:
        y = data["yardstick"]
        plain, stage = y["plain_pycolmap"], y["register_stage"]
        rows.append(
            {
                "row": "yardstick",
                "figure": f"{y['ratio']:.2f}x wall ({y['cpu_ratio']:.2f}x CPU)",
                "accuracy": f"register stage {stage['seconds']:.0f} s vs plain pycolmap {plain['seconds']:.0f} s "
                f"({plain['registered']}/{n} registered, ATE {plain['ate_cm']:.2f} cm)",
                "input": f"{n} real frames",
                "load": run["load"],
                "data": y,
            }
        )
    return rows


def row_register(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    n = size["register_frames"]
    run = child(["-m", "bench.register", "--frames", str(n)], 3600)
    pattern = r"register (\d+) frames: ([\d.]+) s wall, ([\d.]+) s CPU, peak RSS ([\d.]+) GB"
    why = _failed(run)
    if why:
        return [{"row": "register", "error": why}]
    m = _search(pattern, run["stdout"])
    placed = re.search(r"(\d+) registered by SfM", run["stdout"])
    return [
        {
            "row": "register",
            "figure": f"{float(m.group(2)):.0f} s ({float(m.group(3)):.0f} s CPU), peak {float(m.group(4)):.2f} GB",
            "accuracy": f"{placed.group(1)}/{m.group(1)} registered by SfM" if placed else "",
            "input": f"{m.group(1)} rendered 640x480 frames",
            "load": run["load"],
        }
    ]


def row_preprocess(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    n = size["preprocess_points"]
    run = child(["-m", "bench.preprocess", "--points", str(n)], 3600)
    why = _failed(run)
    if why:
        return [{"row": "preprocess", "error": why}]
    # the step table's total row: points in, seconds, CPU seconds, points/s, points per CPU second
    total = _search(r"\ntotal\s+([\d,]+)\s+([\d.]+)\s+([\d.]+)\s+([\d,]+)", run["stdout"])
    cpu = re.search(r"CPU time ([\d.]+) s", run["stdout"])
    rss = re.search(r"peak RSS ([\d.]+) GiB", run["stdout"])
    tilt = re.search(r"residual tilt ([\d.]+)", run["stdout"])
    dist = re.search(r"distance to truth median ([\d.]+) mm, p99 ([\d.]+) mm", run["stdout"])
    return [
        {
            "row": "preprocess",
            "figure": f"{int(total.group(4).replace(',', '')) / 1e3:.0f} k points/s ({float(total.group(2)):.1f} s"
            + (f", {float(cpu.group(1)):.1f} s CPU" if cpu else "")
            + (f", peak {float(rss.group(1)):.2f} GiB)" if rss else ")"),
            "accuracy": (f"residual tilt {tilt.group(1)} deg" if tilt else "")
            + (f", to the true surfaces median {dist.group(1)} mm, p99 {dist.group(2)} mm" if dist else ""),
            "input": f"{n:,} points",
            "load": run["load"],
        }
    ]


def row_walls_survey(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    """The preprocess stage's accuracy figure: `bench.walls_survey` (preprocess then walls with the default
    configuration on the generator's buildings) on the tuning and the held-out split, mean wall figures
    per sensor."""
    rows = []
    for split in ("tune", "heldout"):
        args = ["-m", "bench.walls_survey", "--split", split]
        for s in sets:
            args += ["--set", s]
        run = child(args, 3600)
        why = _failed(run)
        if why:
            rows.append({"row": f"walls_survey {split}", "error": why})
            continue
        for sensor in ("kinect_v1", "tls"):
            m = _search(
                rf"{sensor}\s+rooms\s+(\d+) \(errors (\d+)\): mean completeness ([\d.]+), correctness ([\d.]+), "
                r"accuracy ([\d.]+) mm, corner F1 ([\d.]+).*?CPU ([\d.]+) s/room\); meet all targets: (\d+/\d+)",
                run["stdout"],
            )
            rows.append(
                {
                    "row": f"walls_survey {split}",
                    "figure": f"{float(m.group(7)):.2f} s CPU/room (preprocess + walls)",
                    "accuracy": f"{sensor}: completeness {m.group(3)}, correctness {m.group(4)}, accuracy "
                    f"{m.group(5)} mm, corner F1 {m.group(6)}, targets met {m.group(8)}",
                    "input": f"{m.group(1)} rooms ({m.group(2)} errors), {split} buildings",
                    "load": run["load"],
                }
            )
    return rows


def row_walls(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    seeds = size["walls_seeds"]
    run = child(["-m", "bench.walls", "--seeds", str(seeds), "--sensors", "kinect_v1"], 3600)
    why = _failed(run)
    if why:
        return [{"row": "walls", "error": why}]
    m = _search(
        r"10 m x 10 m room at [\d.]+ m grid: ([\d.]+) s mean.*?\(CPU ([\d.]+) s mean.*?completeness min ([\d.]+), "
        r"correctness min ([\d.]+), accuracy mean max ([\d.]+) mm",
        run["stdout"],
    )
    return [
        {
            "row": "walls",
            "figure": f"{float(m.group(1)):.2f} s ({float(m.group(2)):.2f} s CPU)",
            "accuracy": f"all rooms: completeness min {m.group(3)}, correctness min {m.group(4)}, "
            f"accuracy mean max {m.group(5)} mm",
            "input": f"10 m x 10 m room at 1 cm, {seeds} seed(s), Kinect v1 noise",
            "load": run["load"],
        }
    ]


def row_mini(size: dict[str, int], quick: bool, sets: list[str]) -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory() as tmp:
        args = ["-m", "flows.cli", "run", str(REPO / "data" / "mini"), "--work", str(Path(tmp) / "work")]
        for s in sets:
            args += ["--set", s]
        run = child(args, 3600)
        metrics_path = Path(tmp) / "work" / "outputs" / "metrics.json"
        metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    why = _failed(run)
    if why:
        return [{"row": "data/mini cold", "error": why}]
    return [
        {
            "row": "data/mini cold",
            "figure": f"{run['wall_s']:.0f} s ({run['cpu_s']:.0f} s CPU)",
            "accuracy": mini_accuracy(metrics),
            "input": "6 rooms, fresh work dir",
            "load": run["load"],
            "data": metrics,
        }
    ]


def mini_accuracy(metrics: dict[str, Any]) -> str:
    """The summary of metrics.json: mean wall completeness, correctness, accuracy, corner F1 and ATE."""
    summary = metrics.get("summary") or {}
    parts = []
    for key, label, scale, unit in (
        ("mean_completeness", "completeness", 1, ""),
        ("mean_correctness", "correctness", 1, ""),
        ("mean_accuracy_mean_m", "accuracy", 1000, " mm"),
        ("mean_corner_f1", "corner F1", 1, ""),
        ("mean_ate_2d_rmse_m", "ATE", 100, " cm"),
    ):
        if isinstance(summary.get(key), int | float):
            parts.append(f"{label} {scale * summary[key]:.3g}{unit}")
    return "means over rooms: " + ", ".join(parts) if parts else "no summary in metrics.json"


ROWS: dict[str, Callable[[dict[str, int], bool, list[str]], list[dict[str, Any]]]] = {
    "sfm": row_sfm,
    "register": row_register,
    "preprocess": row_preprocess,
    "walls_survey": row_walls_survey,
    "walls": row_walls,
    "mini": row_mini,
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.all", description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="smaller inputs, no yardstick, no walls_survey or data/mini run"
    )
    ap.add_argument(
        "--only", default=",".join(ROWS), help=f"rows to run, comma separated (default all: {','.join(ROWS)})"
    )
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="STAGE.KEY=VALUE",
        help="config override for the SfM rows and data/mini",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the table to this file")
    args = ap.parse_args(argv)
    chosen = [r.strip() for r in args.only.split(",") if r.strip()]
    unknown = [r for r in chosen if r not in ROWS]
    if unknown:
        ap.error(f"--only: unknown rows {unknown}; choose from {', '.join(ROWS)}")
    if args.quick and args.only == ",".join(ROWS):
        chosen = [r for r in chosen if r not in ("mini", "walls_survey")]
    size = QUICK if args.quick else FULL
    print(f"{os.cpu_count()} cores; {'quick' if args.quick else 'full'} sizes {size}", flush=True)
    table: list[dict[str, Any]] = []
    for name in chosen:
        try:
            rows = ROWS[name](size, args.quick, args.sets)
        except (ValueError, KeyError, OSError) as exc:
            rows = [{"row": name, "error": f"could not read its figures: {exc}"}]
        for r in rows:
            table.append(r)
            if "error" in r:
                print(f"{r['row']:<15} {r['error']}", flush=True)
            else:
                print(
                    f"{r['row']:<15} {r['figure']:<42} {r['accuracy']}  [{r['input']}; load {r['load']:.1f}]",
                    flush=True,
                )
    if args.json:
        args.json.write_text(json.dumps(table, indent=2, default=str))
    return 1 if any("error" in r for r in table) else 0


if __name__ == "__main__":
    sys.exit(main())
