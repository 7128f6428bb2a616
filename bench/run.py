"""Growth benchmark of the whole workflow: cold run, no-op rerun and walls-only rerun of synthetic surveys
of several sizes, as a user runs them (`indoor-survey run` / `rerun` in a child process).

    python -m bench.run                          # TLS rooms: 5, 10 and 20 rooms
    python -m bench.run --sizes 5                # a quick check
    python -m bench.run --kind rgbd --sizes 5,10 # RGB-D rooms (registration included)
    python -m bench.run --sizes 5,10 --json bench-run.json

Run from the repository root. The surveys are made of the survey generator's rooms: with `--kind tls` (the
default) its TLS rooms (`indoor-survey synth --profile tls`: every room a registered two-station cloud, so
a room costs ingest + preprocess + walls and no registration); with `--kind rgbd` its miniature Kinect
surveys (`indoor-survey synth`, as data/mini: five rooms recorded as RGB-D frames, so a room also costs
its registration, and one room a TLS cloud, with the survey's calibration target images). The generator
draws one building of five rooms and a hallway per seed, so a survey of N rooms takes the rooms of seeds
0, 1, 2, ... in turn (ids `r1`.. for seed 0, `s<seed>-r1`.. for the others) and the plan, IMU track (and
calibration images) of seed 0. Rooms of other seeds have no plan room: fusion matches them by shape or
leaves them unplaced, and reports the differences as changes, as it would for a building the plan does
not show. No truth/ is copied (no metrics.json: the benchmark times the workflow, not its accuracy).

For each size it prints: the cold time (a fresh work dir); the no-op rerun (`run` again: nothing changed)
the walls-only rerun (`rerun --stage walls`: every room's walls recomputed, then what reads them where
they changed) and one room's walls (`rerun --stage walls --room r1`) as ratios of the cold time; the CPU
seconds of each (user + system of the whole process tree: the CLI, Prefect's server, any Dask worker),
which the machine's load inflates far less than the wall time; each stage's share of the cold run's stage
time (the run summary's seconds per stage, summed over rooms); the peak resident memory of the whole
process tree, sampled every 0.1 s with psutil, and how it splits between the run's own process, Prefect's
server and the rest at that moment; and the largest over the smallest size's cold time. The machine's
load average is printed with each run: the figures are wall-clock times.

With `--prefect-server` every command uses one Prefect server that the benchmark starts first and that
outlives them (as `PREFECT_API_URL` naming a running server, or a `serve`d schedule): no command starts
its own, and the CPU seconds the shared server spends while a command runs (and its memory) count as
that command's; the server's own start is printed apart.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
ROOMS_PER_SEED = ("r1", "r2", "r3", "r4", "r5", "hall")


def _part(proc: Any) -> str:
    """Which part of a run a process is: "server" (Prefect's), "run" (the CLI) or "other" (a worker)."""
    try:
        cmdline = " ".join(proc.cmdline())
    except Exception:
        return "other"
    if "prefect.server.api.server" in cmdline:
        return "server"
    return "run" if "flows.cli" in cmdline else "other"


def _peak_rss_sampler(
    pid: int, stop: threading.Event, out: dict[str, Any], server_pid: int | None = None
) -> None:
    """Sample the RSS of process `pid` and all its descendants (and of the shared server `server_pid`)
    until `stop`: the largest total goes to out["peak"], its split by part (run, server, other) to
    out["parts"], its time after the start to out["at_s"]."""
    import psutil

    try:
        root = psutil.Process(pid)
        shared = [psutil.Process(server_pid)] if server_pid else []
    except psutil.Error:
        return
    started = time.perf_counter()
    while not stop.is_set():
        parts: dict[str, int] = defaultdict(int)
        try:
            procs = [root, *root.children(recursive=True), *shared]
        except psutil.Error:
            break
        for proc in procs:
            try:
                rss = proc.memory_info().rss
            except psutil.Error:
                continue
            parts[_part(proc)] += rss  # each time: a child is the CLI's copy until it execs
        total = sum(parts.values())
        if total > out["peak"]:
            out.update(peak=total, parts=dict(parts), at_s=time.perf_counter() - started)
        stop.wait(0.1)


def _children_cpu() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def process_cpu(pid: int) -> float:
    """CPU seconds (user + system) that process `pid` has used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def timed(command: list[str], log: Path, server: tuple[str, int] | None = None) -> dict[str, Any]:
    """Run `command` (output to `log`): wall and CPU seconds, peak RSS of its process tree (bytes) and
    its split; a command that fails stops the benchmark. With `server` (the URL and pid of a Prefect
    server that outlives the commands, see `shared_server`) the command uses it, and the CPU seconds it
    spent meanwhile and its RSS count as the command's."""
    env = {
        # on a busy machine Prefect's server may take minutes to start: a benchmark waits for it
        "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "900",
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
    }
    if server is not None:
        env["PREFECT_API_URL"] = server[0]
    server_cpu_start = process_cpu(server[1]) if server else 0.0
    peak: dict[str, Any] = {"peak": 0, "parts": {}, "at_s": None}
    stop = threading.Event()
    load = os.getloadavg()[0]
    wall_start = time.time()
    cpu_start = _children_cpu()
    started = time.perf_counter()
    with log.open("w") as out:
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        try:
            import psutil  # noqa: F401

            sampler = threading.Thread(
                target=_peak_rss_sampler,
                args=(proc.pid, stop, peak, server[1] if server else None),
                daemon=True,
            )
            sampler.start()
        except ImportError:
            sampler = None
        code = proc.wait()
        seconds = time.perf_counter() - started
        cpu = _children_cpu() - cpu_start  # the whole tree: each process is reaped by its parent
        server_cpu = process_cpu(server[1]) - server_cpu_start if server else 0.0
        stop.set()
        if sampler is not None:
            sampler.join()
    if sampler is None:  # no psutil: the largest child's peak (a lower bound of the tree's)
        import resource

        peak["peak"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    if code != 0:
        raise SystemExit(f"{' '.join(command)} exited with {code}; see {log}")
    return {
        "seconds": seconds,
        "cpu_s": cpu + server_cpu,
        "shared_server_cpu_s": server_cpu,
        "peak_rss": peak["peak"],
        "peak_rss_parts": peak["parts"],
        "peak_at_s": peak["at_s"],
        "load": load,
        "load_after": os.getloadavg()[0],
        "log": str(log),
        "first_stage_s": first_stage_after(log, wall_start),
    }


def first_stage_after(log: Path, wall_start: float) -> float | None:
    """Seconds from the command's start to its first stage ("HH:MM:SS [room] stage: computing" in its
    log): the start-up (imports, checks, Prefect's server) before any stage work; None if none ran."""
    for line in log.read_text().splitlines():
        if line.endswith(": computing") and line[:2].isdigit():
            h, m, sec = (int(v) for v in line[:8].split(":"))
            day = time.localtime(wall_start)
            stamp = time.mktime((day.tm_year, day.tm_mon, day.tm_mday, h, m, sec, 0, 0, -1))
            if stamp < wall_start - 1:  # past midnight
                stamp += 86400
            return max(0.0, stamp - wall_start)
    return None


def stage_seconds(log: Path) -> dict[str, float]:
    """Seconds per stage name, summed over rooms, from a run's summary table (computed stages only)."""
    totals: dict[str, float] = defaultdict(float)
    for line in log.read_text().splitlines():
        parts = line.split()
        if len(parts) >= 4 and parts[2] == "computed":
            try:
                totals[parts[1]] += float(parts[3])
            except ValueError:
                continue
    return dict(totals)


KINDS = {"tls": "tls", "rgbd": "kinect_v1"}
"""--kind -> the generator's sensor profile of the rooms."""


def source_survey(cache: Path, seed: int, kind: str = "tls") -> Path:
    """The generator's survey of `seed` (all five rooms and the hallway) of `kind`, made once."""
    folder = cache / f"{kind}-seed{seed}"
    if not (folder / "survey.yaml").is_file():
        from tasks.synth.survey import generate_survey

        generate_survey(folder, seed=seed, profile=KINDS[kind], size="mini", overwrite=True)
    return folder


def _link_or_copy(source: Path, dest: Path) -> None:
    dest.parent.mkdir(parents=True, exist_ok=True)
    if source.stat().st_dev == dest.parent.stat().st_dev:
        os.link(source, dest)
    else:
        shutil.copy2(source, dest)


def compose_survey(cache: Path, rooms: int, out: Path, kind: str = "tls") -> Path:
    """A survey of `rooms` rooms of `kind` (seed 0's first, then seed 1's...), seed 0's plan and track,
    and for RGB-D rooms seed 0's calibration images."""
    if out.exists():
        shutil.rmtree(out)
    base = source_survey(cache, 0, kind)
    spec = yaml.safe_load((base / "survey.yaml").read_text())
    shutil.copytree(base / "plan", out / "plan")
    entries: list[dict[str, Any]] = []
    if spec.get("track"):
        shutil.copytree(base / Path(spec["track"]).parent, out / Path(spec["track"]).parent)
    if kind == "rgbd" and spec.get("calibration"):
        shutil.copytree(base / spec["calibration"], out / spec["calibration"])
    else:
        spec.pop("calibration", None)
    seed = 0
    while len(entries) < rooms:
        src = source_survey(cache, seed, kind)
        by_id = {r["id"]: r for r in yaml.safe_load((src / "survey.yaml").read_text())["rooms"]}
        for room in ROOMS_PER_SEED:
            if len(entries) == rooms:
                break
            entry = dict(by_id[room])
            rid = room if seed == 0 else f"s{seed}-{room}"
            capture = src / entry["capture"]
            _link_or_copy(capture, out / "rooms" / rid / capture.name)
            entry.update(id=rid, capture=f"rooms/{rid}/{capture.name}")
            if seed != 0:
                entry.pop("plan_room", None)
            entries.append(entry)
        seed += 1
    spec.update(name=f"bench-{kind}-{rooms}-rooms", rooms=entries)
    spec.pop("truth", None)
    (out / "survey.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return out


@contextlib.contextmanager
def shared_server(root: Path) -> Iterator[tuple[str, int, dict[str, float]]]:
    """One Prefect API server for every command of the benchmark, as when a server outlives the runs
    (the server a run would start, with the same settings; it dies with the benchmark): its URL, its
    pid and what its start cost (wall and CPU seconds until it answered)."""
    from flows import prefect_env

    if os.environ.get("PREFECT_API_URL"):
        raise SystemExit("--prefect-server: PREFECT_API_URL is set already; unset it to time a shared server")
    prefect_env.apply()
    work = root / "prefect-server"
    started = time.perf_counter()
    with prefect_env.embedded_server(work) as url:
        assert url is not None
        pid = int(json.loads((work / prefect_env.SERVER_RECORD).read_text())["server_pid"])
        start = {"seconds": time.perf_counter() - started, "cpu_s": process_cpu(pid)}
        print(
            f"shared Prefect server {url}: answered after {start['seconds']:.1f} s, {start['cpu_s']:.1f} CPU s"
        )
        yield url, pid, start


def bench_size(
    rooms: int,
    root: Path,
    sets: list[str],
    kind: str = "tls",
    server: tuple[str, int, dict[str, float]] | None = None,
) -> dict[str, Any]:
    survey = compose_survey(root / "sources", rooms, root / f"survey-{kind}-{rooms}", kind)
    work = root / f"work-{kind}-{rooms}"
    if work.exists():
        shutil.rmtree(work)
    api = server[:2] if server else None
    cli = [sys.executable, "-m", "flows.cli"]
    extra = [a for s in sets for a in ("--set", s)]
    cold = timed(
        [*cli, "run", str(survey), "--work", str(work), *extra], root / f"cold-{kind}-{rooms}.log", api
    )
    noop = timed(
        [*cli, "run", str(survey), "--work", str(work), *extra], root / f"noop-{kind}-{rooms}.log", api
    )
    walls = timed(
        [*cli, "rerun", str(survey), "--work", str(work), "--stage", "walls", *extra],
        root / f"walls-{kind}-{rooms}.log",
        api,
    )
    # the users' other rerun: one stage of one room (after tuning it); its readers stay current when the
    # stage writes the same bytes, so this is the floor of any targeted rerun
    one = timed(
        [*cli, "rerun", str(survey), "--work", str(work), "--stage", "walls", "--room", "r1", *extra],
        root / f"walls-r1-{kind}-{rooms}.log",
        api,
    )
    stages = stage_seconds(Path(cold["log"]))
    total = sum(stages.values()) or 1.0
    runs = {"cold": cold, "noop": noop, "walls": walls, "one_room_walls": one}
    peak = max(runs.values(), key=lambda r: r["peak_rss"])
    return {
        "kind": kind,
        "rooms": rooms,
        "shared_server": server[2] if server else None,
        "cold_s": cold["seconds"],
        "noop_s": noop["seconds"],
        "walls_s": walls["seconds"],
        "noop_ratio": noop["seconds"] / cold["seconds"],
        "walls_ratio": walls["seconds"] / cold["seconds"],
        "one_room_walls_s": one["seconds"],
        "one_room_walls_ratio": one["seconds"] / cold["seconds"],
        "cpu_s": {name: r["cpu_s"] for name, r in runs.items()},
        "shared_server_cpu_s": {name: r["shared_server_cpu_s"] for name, r in runs.items()},
        "stage_seconds": stages,
        "stage_share": {name: s / total for name, s in sorted(stages.items(), key=lambda kv: -kv[1])},
        "walls_stage_seconds": stage_seconds(Path(walls["log"])),
        "cold_first_stage_s": cold["first_stage_s"],
        "walls_first_stage_s": walls["first_stage_s"],
        "peak_rss_mb": peak["peak_rss"] / 2**20,
        "peak_rss_parts_mb": {k: v / 2**20 for k, v in sorted(peak["peak_rss_parts"].items())},
        "peak_rss_at_s": peak["peak_at_s"],
        "peak_rss_command": next(name for name, r in runs.items() if r is peak),
        "cold_peak_rss_mb": cold["peak_rss"] / 2**20,
        "load": {name: [r["load"], r["load_after"]] for name, r in runs.items()},
    }


def _s(seconds: float | None) -> str:
    return "n/a" if seconds is None else f"{seconds:.0f} s"


def _print(r: dict[str, Any]) -> None:
    rooms = r["rooms"]
    shares = ", ".join(f"{k} {100 * v:.0f}%" for k, v in r["stage_share"].items())
    cpu = r["cpu_s"]
    parts = ", ".join(f"{k} {v:.0f}" for k, v in r["peak_rss_parts_mb"].items())
    load = ", ".join(f"{k} {a:.1f}-{b:.1f}" for k, (a, b) in r["load"].items())
    print(
        f"{rooms:3d} rooms: cold {r['cold_s']:6.1f} s | no-op {r['noop_s']:5.1f} s = "
        f"{100 * r['noop_ratio']:4.1f}% | walls-only {r['walls_s']:5.1f} s = {100 * r['walls_ratio']:4.1f}% | "
        f"r1's walls {r['one_room_walls_s']:5.1f} s = {100 * r['one_room_walls_ratio']:4.1f}% | "
        f"peak RSS {r['peak_rss_mb']:.0f} MB\n"
        f"           CPU s: cold {cpu['cold']:.1f}, no-op {cpu['noop']:.1f}, walls-only {cpu['walls']:.1f} "
        f"= {100 * cpu['walls'] / cpu['cold']:.1f}%, r1's walls {cpu['one_room_walls']:.1f}\n"
        f"           peak RSS in {r['peak_rss_command']} at {r['peak_rss_at_s'] or 0:.0f} s: {parts} MB\n"
        f"           load average (start-end): {load}\n"
        f"           stage shares: {shares}\n"
        f"           start-up before the first stage: cold {_s(r['cold_first_stage_s'])}, "
        f"walls-only {_s(r['walls_first_stage_s'])}; walls-only stage time "
        f"{sum(r['walls_stage_seconds'].values()):.1f} s",
        flush=True,
    )
    if r["shared_server"]:
        used = ", ".join(f"{k} {v:.1f}" for k, v in r["shared_server_cpu_s"].items())
        print(f"           of those CPU s, the shared Prefect server's: {used}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default="5,10,20", help="room counts, comma separated (default 5,10,20)")
    parser.add_argument(
        "--root",
        type=Path,
        default=Path("/tmp/indoor-survey-bench/run"),
        help="surveys, work dirs and logs (the generated rooms are kept for the next time)",
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="STAGE.KEY=VALUE", help="config override"
    )
    parser.add_argument(
        "--kind",
        choices=sorted(KINDS),
        default="tls",
        help="the rooms: tls (registered clouds, the default) or rgbd (Kinect recordings, as data/mini)",
    )
    parser.add_argument(
        "--prefect-server",
        action="store_true",
        help="one Prefect server for every command (as a server that outlives the runs): each command "
        "uses it instead of starting its own, and the CPU seconds it spends meanwhile count as the "
        "command's; its own start is printed apart",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the figures to this file")
    args = parser.parse_args(argv)
    try:
        sizes = sorted({int(s) for s in args.sizes.split(",") if s.strip()})
    except ValueError:
        parser.error(f"--sizes {args.sizes!r}: expected room counts such as 5,10,20")
    if not sizes or min(sizes) < 1:
        parser.error(f"--sizes {args.sizes!r}: room counts must be at least 1")
    args.root.mkdir(parents=True, exist_ok=True)
    print(f"{os.cpu_count()} cores; {args.kind} rooms; root {args.root}", flush=True)
    results = []
    with contextlib.ExitStack() as stack:
        server = stack.enter_context(shared_server(args.root)) if args.prefect_server else None
        for rooms in sizes:
            results.append(bench_size(rooms, args.root, args.set, args.kind, server))
            if args.json:  # after each size: a later size that fails keeps the earlier figures
                args.json.write_text(json.dumps(results, indent=2))
            _print(results[-1])
    if len(results) > 1:
        small, large = results[0], results[-1]
        print(
            f"growth: {large['rooms']}/{small['rooms']} rooms = {large['cold_s'] / small['cold_s']:.2f}x cold time, "
            f"{large['cpu_s']['cold'] / small['cpu_s']['cold']:.2f}x cold CPU time (rooms ratio "
            f"{large['rooms'] / small['rooms']:.1f}x); peak RSS {small['peak_rss_mb']:.0f} -> "
            f"{large['peak_rss_mb']:.0f} MB ({100 * (large['peak_rss_mb'] / small['peak_rss_mb'] - 1):+.0f}%)"
        )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
