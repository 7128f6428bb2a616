"""The one-off verbs (`calibrate`, `parse-plan`, `register-room`, `model-room`) as the same stages `run`
uses, through the same load-or-compute path, in a private work dir (OUT/.cache unless told otherwise):
what the verb is given is laid out as a survey would give it, and the stage's files are copied to OUT.
A verb and a pipeline stage therefore cannot drift apart, and repeating a verb recomputes nothing.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from flows import planning
from tasks import config as cfgmod
from tasks.cloud import DegenerateInputError
from tasks.stages import STAGES


def _glob(pattern: str, what: str) -> list[Path]:
    """Sorted files matching a CLI glob (`~` expanded, `**` recursive); ValueError naming the option if none."""
    files = sorted(f for f in glob.glob(os.path.expanduser(pattern), recursive=True) if os.path.isfile(f))
    if not files:
        raise ValueError(f"no files match {what} {pattern!r}")
    return [Path(f).resolve() for f in files]


def _link_all(files: list[Path], folder: Path, what: str) -> list[str]:
    """Symbolic links to `files` in `folder` under their own names (the calibrate stage pairs IR and RGB
    views by the numbers in them); a folder left by an earlier call is replaced."""
    names = [f.name for f in files]
    if len(set(names)) != len(names):
        raise ValueError(
            f"{what}: two files share a name ({', '.join(sorted({n for n in names if names.count(n) > 1}))})"
        )
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    for f in files:
        (folder / f.name).symlink_to(f)
    return names


def calibration_folder(
    root: Path,
    ir_glob: str,
    rgb_glob: str | None,
    pattern: str,
    flat_glob: str | None = None,
    known_distances: Sequence[float] | None = None,
) -> Path:
    """A survey-style calibration folder (ir/, rgb/, flat/ + flat.yaml, target.yaml) of links to the files
    the CLI globs name."""
    from tasks.calibrate.targets import parse_pattern

    folder = root / "calibration"
    _link_all(_glob(ir_glob, "--ir"), folder / "ir", "--ir")
    rgb = _glob(rgb_glob, "--rgb") if rgb_glob else []
    _link_all(rgb, folder / "rgb", "--rgb")
    for name in ("flat.yaml", "target.yaml"):
        (folder / name).unlink(missing_ok=True)
    (folder / "target.yaml").write_text(yaml.safe_dump({"pattern": str(parse_pattern(pattern))}))
    if flat_glob:
        flats = _link_all(_glob(flat_glob, "--flat"), folder / "flat", "--flat")
        if known_distances is None or len(known_distances) != len(flats):
            raise ValueError(f"--flat matches {len(flats)} files: give as many --distances")
        meta = {"distances_m": [float(d) for d in known_distances], "files": flats}
        (folder / "flat.yaml").write_text(yaml.safe_dump(meta))
    else:
        _link_all([], folder / "flat", "--flat")
    return folder


def calibrate(
    out: Path,
    ir_glob: str,
    rgb_glob: str | None,
    pattern: str,
    flat_glob: str | None = None,
    known_distances: Sequence[float] | None = None,
    work: Path | None = None,
    cfg: cfgmod.PipelineConfig | None = None,
) -> Path:
    """`indoor-survey calibrate`: OUT/calibration.json and OUT/calibration_residuals.json; returns the
    path of calibration.json."""
    work = Path(work or Path(out) / ".cache")
    folder = calibration_folder(work / "inputs", ir_glob, rgb_glob, pattern, flat_glob, known_distances)
    cfg = cfg or cfgmod.load_config()
    results = planning.run_chain(
        work,
        cfg,
        cfgmod.load_sensor_profile("kinect_v1"),
        ["calibrate"],
        raw_inputs={"calibration": str(folder)},
    )
    return planning.export(results["calibrate"], ["calibration.json", "calibration_residuals.json"], out)[0]


def parse_plan(
    image: Path,
    out: Path,
    m_per_px: float | None = None,
    known_distance: Sequence[float] | None = None,
    outline_length_m: float | None = None,
    work: Path | None = None,
    cfg: cfgmod.PipelineConfig | None = None,
) -> dict[str, Any]:
    """`indoor-survey parse-plan`: OUT/plan_walls.parquet, rooms.geojson, plan_preview.png; returns the
    stage's metrics."""
    image = Path(image)
    if not image.is_file():
        raise ValueError(f"{image}: no such image file")
    work = Path(work or Path(out) / ".cache")
    params = {
        "m_per_px": m_per_px,
        "known_distance": list(known_distance) if known_distance else None,
        "outline_length_m": outline_length_m,
    }
    results = planning.run_chain(
        work,
        cfg or cfgmod.load_config(),
        {},
        ["plan"],
        raw_inputs={"plan": str(image.resolve())},
        params=params,
    )
    planning.export(results["plan"], STAGES["plan"].deliverables, out)
    return results["plan"].manifest.get("metrics", {})


def register_room(
    capture: Path,
    out: Path,
    sensor: str = "kinect_v1",
    calibration: Path | None = None,
    work: Path | None = None,
    cfg: cfgmod.PipelineConfig | None = None,
) -> dict[str, Any]:
    """`indoor-survey register-room`: ingest -> (calibration) -> register on one RGB-D capture; writes
    OUT/poses.parquet, cloud.ply and scale.json and returns the register stage's metrics."""
    capture = Path(capture).resolve()
    if not capture.exists():
        raise ValueError(f"{capture}: no such capture")
    if planning.capture_kind(capture) == "cloud":
        raise ValueError(f"{capture}: a registered cloud needs no registration")
    work = Path(work or Path(out) / ".cache")
    stages = ["ingest", "register"]
    raw: dict[str, str] = {}
    if calibration is not None:
        calibration = Path(calibration).resolve()
        if not calibration.is_file():
            raise ValueError(f"{calibration}: no such calibration file")
        stages.insert(0, "calibrate")
        raw["calibration"] = str(calibration)
    room = cfgmod.RoomSpec("room", capture)
    results = planning.run_chain(
        work, cfg or cfgmod.load_config(), cfgmod.load_sensor_profile(sensor), stages, room, raw_inputs=raw
    )
    planning.export(results["register"], ["poses.parquet", "cloud.ply", "scale.json"], out)
    return {
        "ingest": results["ingest"].manifest.get("metrics", {}),
        **results["register"].manifest.get("metrics", {}),
    }


def model_room(
    cloud: Path, out: Path, work: Path | None = None, cfg: cfgmod.PipelineConfig | None = None
) -> dict[str, Any]:
    """`indoor-survey model-room`: ingest -> preprocess -> walls on one registered cloud; the room's
    deliverables and its levelling transform go to OUT; returns the preprocess and walls metrics."""
    cloud = Path(cloud).resolve()
    if not cloud.is_file():
        raise ValueError(f"{cloud}: no such file")
    room = cfgmod.RoomSpec("room", cloud)
    work = Path(work or Path(out) / ".cache")
    try:
        results = planning.run_chain(
            work,
            cfg or cfgmod.load_config(),
            cfgmod.load_sensor_profile("tls"),
            planning.room_stages(cloud),
            room,
        )
    except ValueError as exc:  # bad input (DegenerateInputError, IngestError...): name the file
        message = " ".join(str(exc).split())
        raise DegenerateInputError(message if str(cloud) in message else f"{cloud}: {message}") from exc
    planning.export(results["walls"], STAGES["walls"].deliverables, out)
    planning.export(results["preprocess"], ["levelling.json"], out)
    return {
        "preprocess": results["preprocess"].manifest.get("metrics", {}),
        "walls": results["walls"].manifest.get("metrics", {}),
    }
