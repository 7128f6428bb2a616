"""Benchmark of ingesting a scanner's LAZ export: peak memory and points per second, in a child process.

    python -m bench.ingest                          # 50 M points: peak RSS, points/s, points kept
    python -m bench.ingest --points 5000000 --voxel 0.005

A box room (walls, floor and ceiling, 2 mm noise across the surface, 16-bit colour and intensity) is
written as LAZ in national-grid coordinates (LV95-like offsets) to /tmp/indoor-survey-bench/, chunk by chunk
so that making it stays in bounded memory too; the file is reused while its point count and room match.
The ingest runs in a fresh child process, so its peak resident set size is the ingest's alone (Python,
numpy and laspy included). Wall-clock figures depend on what else runs on the machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

GRID_OFFSET = (2_600_000.0, 1_200_000.0, 400.0)
"""A room placed in national-grid coordinates (Swiss LV95 easting, northing; height above sea level)."""

WKT_LV95 = 'PROJCRS["CH1903+ / LV95",BASEGEOGCRS["CH1903+",DATUM["CH1903+"]],ID["EPSG",2056]]'
"""A short WKT naming the national grid (enough for the reader, which keeps the text and the code)."""


def room_chunk(
    rng: np.random.Generator, n: int, room_m: tuple[float, float, float], noise_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, 3) points on the inner faces of a box room [0, room_m] (surfaces drawn by area), moved along
    each face's normal by Gaussian noise; (n, 3) uint16 colours (one hue per face) and (n,) uint16
    intensities."""
    sx, sy, sz = room_m
    # faces: (fixed axis, fixed value, the two free axes)
    faces = [
        (2, 0.0, (0, 1)),
        (2, sz, (0, 1)),
        (0, 0.0, (1, 2)),
        (0, sx, (1, 2)),
        (1, 0.0, (0, 2)),
        (1, sy, (0, 2)),
    ]
    areas = np.array([room_m[a] * room_m[b] for _, _, (a, b) in faces])
    face = rng.choice(len(faces), n, p=areas / areas.sum())
    pts = rng.random((n, 3)) * np.asarray(room_m)
    for i, (axis, value, _) in enumerate(faces):
        on = face == i
        pts[on, axis] = value + rng.normal(0.0, noise_m, int(on.sum()))
    hues = np.array(
        [[200, 180, 160], [250, 250, 250], [120, 140, 200], [120, 200, 140], [200, 120, 140], [90, 90, 90]]
    )
    colours = (hues[face] * 257).astype(np.uint16)
    intensity = rng.integers(500, 40000, n).astype(np.uint16)
    return pts, colours, intensity


def write_room_laz(
    path: Path,
    points: int,
    *,
    room_m: tuple[float, float, float] = (10.0, 8.0, 3.0),
    noise_m: float = 0.002,
    seed: int = 0,
    chunk: int = 1_000_000,
) -> Path:
    """Write a LAZ (LAS 1.4, point format 7: x y z, intensity, 16-bit colour) of `points` points on a box
    room in national-grid coordinates, `chunk` points at a time."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.asarray(GRID_OFFSET)
    header.vlrs.append(WktCoordinateSystemVlr(WKT_LV95))
    header.global_encoding.wkt = True
    path.parent.mkdir(parents=True, exist_ok=True)
    with laspy.open(str(path), mode="w", header=header) as writer:
        for index, start in enumerate(range(0, points, chunk)):
            n = min(chunk, points - start)
            pts, colours, intensity = room_chunk(np.random.default_rng([seed, index]), n, room_m, noise_m)
            record = laspy.ScaleAwarePointRecord.zeros(n, header=header)
            record.x = pts[:, 0] + GRID_OFFSET[0]
            record.y = pts[:, 1] + GRID_OFFSET[1]
            record.z = pts[:, 2] + GRID_OFFSET[2]
            record.red, record.green, record.blue = colours[:, 0], colours[:, 1], colours[:, 2]
            record.intensity = intensity
            writer.write_points(record)
    return path


def ingest_in_child(path: Path, voxel_m: float, chunk_points: int | None = None) -> dict[str, Any]:
    """Ingest `path` in a fresh Python process; its metrics plus its baseline and peak RSS (MiB)."""
    with tempfile.TemporaryDirectory(prefix="bench-ingest-") as out:
        command = [sys.executable, "-m", "bench.ingest", "--child", str(path), out, "--voxel", str(voxel_m)]
        if chunk_points:
            command += ["--chunk", str(chunk_points)]
        done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the ingest child failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _child(path: Path, out: Path, voxel_m: float, chunk_points: int | None) -> None:
    """The child's side: import, note the resident set, ingest, print metrics and the peak as JSON."""
    import laspy  # noqa: F401  (loaded before the baseline: the library is not the ingest's growth)

    from tasks.ingest.config import IngestConfig
    from tasks.ingest.scanners import CHUNK_POINTS, ingest_scanner_cloud

    baseline = _status_mib("VmRSS")
    started, cpu_started = time.perf_counter(), time.process_time()
    metrics = ingest_scanner_cloud(
        path, out, IngestConfig(cloud_voxel_m=voxel_m), None, chunk_points or CHUNK_POINTS
    )
    seconds = time.perf_counter() - started
    cpu = time.process_time() - cpu_started
    peak = _status_mib("VmHWM")
    print(
        json.dumps(
            {
                "baseline_rss_mib": round(baseline, 1),
                "peak_rss_mib": round(peak, 1),
                "seconds": round(seconds, 2),
                "cpu_seconds": round(cpu, 2),
                "points_read": metrics["points_read"],
                "points_kept": metrics["points"],
                "points_per_second": round(metrics["points_read"] / seconds),
                "points_per_cpu_second": round(metrics["points_read"] / max(cpu, 1e-9)),
                "local_origin_m": metrics["local_origin_m"],
                "crs": metrics["crs"],
            }
        )
    )


def _status_mib(field: str) -> float:
    """A memory figure of this process from /proc (MiB): VmRSS now, VmHWM its peak. The peak is read
    there, not from getrusage: ru_maxrss survives exec, so a child would report its parent's size at the
    fork when that was larger."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=50_000_000)
    parser.add_argument("--voxel", type=float, default=0.01, help="ingest.cloud_voxel_m (m)")
    parser.add_argument("--chunk", type=int, default=0, help="points read at a time (default: the reader's)")
    parser.add_argument("--dir", type=Path, default=Path("/tmp/indoor-survey-bench"))
    parser.add_argument("--child", nargs=2, type=Path, metavar=("FILE", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child[0], args.child[1], args.voxel, args.chunk or None)
        return
    path = args.dir / f"room_{args.points}.laz"
    if not path.is_file():
        started = time.perf_counter()
        write_room_laz(path, args.points)
        made = time.perf_counter() - started
        print(f"wrote {path} ({path.stat().st_size / 2**20:.0f} MiB) in {made:.1f} s")
    result = ingest_in_child(path, args.voxel, args.chunk or None)
    print(
        f"{result['points_read']:,} points read, {result['points_kept']:,} kept at a {args.voxel} m voxel, "
        f"in {result['seconds']} s: {result['points_per_second']:,} points/s "
        f"({result['cpu_seconds']} CPU s, all threads: {result['points_per_cpu_second']:,} points per CPU second)"
    )
    print(
        f"peak RSS {result['peak_rss_mib']:.0f} MiB (the child's VmHWM; {result['baseline_rss_mib']:.0f} MiB "
        "of it after the imports)"
    )
    print(f"local origin {result['local_origin_m']} m, CRS {result['crs']}")


if __name__ == "__main__":
    main()
