"""A damaged input never becomes a wrong model, a crash or lost deliverables (issue #21).

The sweep: bad inputs of every kind a new user can give the CLI, each generated small in a folder (a
damaged cloud, plan, MCAP recording, survey.yaml, config or work dir), with what the CLI must answer:
the exit code, one line naming the file or key, no traceback, and the earlier results left byte for byte
as they were. `CASES` maps a case's name to its builder. Then the runs: a damaged capture in a survey
keeps the room's earlier deliverables, a run killed with SIGKILL leaves no process behind, and the
embedded server of a dead run is reaped."""

from __future__ import annotations

import hashlib
import json
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from flows.cli import main
from tasks.artefacts import write_ply_points
from tests.captures import (
    box_room_points,
    rgbd_mcap,
    write_box_room_ply,
    write_survey,
)

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Case:
    """One bad input: the CLI's arguments and what it must answer."""

    argv: list[str]
    code: int
    """The exit code (README: 2 bad input or invocation, 1 a stage failed)."""
    names: tuple[str, ...]
    """What the one error line must name (the file, the key or the option)."""
    watch: Path | None = None
    """A folder of earlier results that must be byte for byte the same afterwards."""
    subprocess: bool = False
    """Run in a child process with a memory limit (inputs that once aborted the process or grew it)."""


CASES: dict[str, Callable[[Path], Case]] = {}


def case(fn: Callable[[Path], Case]) -> Callable[[Path], Case]:
    CASES[fn.__name__] = fn
    return fn


# --------------------------------------------------------------------------------------------- helpers


def earlier_outputs(folder: Path, *names: str) -> Path:
    """A folder holding what an earlier good run left (files whose bytes must survive)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(len(str(folder)))
    for name in names or ("walls.parquet", "plan.geojson", "model.ply", "preview.png"):
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(rng.bytes(64))
    return folder


def earlier_work(work: Path) -> Path:
    """A work dir with earlier deliverables, metrics and a run's record."""
    earlier_outputs(work / "outputs" / "rooms" / "a")
    earlier_outputs(work / "outputs", "metrics.json", "rooms.parquet", "runs/x/config.yaml")
    earlier_outputs(work / "runs" / "20000101T000000", "config.yaml")
    return work


def good_ply(path: Path, seed: int = 0, colours: bool = True) -> Path:
    """A small box room (metres): about 9 000 points."""
    rng = np.random.default_rng(seed)
    pts = box_room_points(rng, size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    cols = np.full((len(pts), 3), 180, np.uint8) if colours else None
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_ply_points(path, pts, cols)


def ply_parts(path: Path) -> tuple[str, bytes]:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode(), data[end:]


def ascii_ply(path: Path, rows: list[str], count: int | None = None) -> Path:
    head = (
        f"ply\nformat ascii 1.0\nelement vertex {len(rows) if count is None else count}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    path.write_text(head + "\n".join(rows) + "\n")
    return path


def box_rows(n: int = 2000, seed: int = 0) -> list[str]:
    pts = box_room_points(np.random.default_rng(seed), size_m=(3.0, 2.5, 2.5), spacing_m=0.08)[:n]
    return [f"{x:.5f} {y:.5f} {z:.5f}" for x, y, z in pts]


def pcd(path: Path, points: np.ndarray, data: str = "binary", header: dict | None = None) -> Path:
    """A PCD file of float32 x y z (the layout Open3D and PCL write)."""
    fields = {
        "VERSION": "0.7",
        "FIELDS": "x y z",
        "SIZE": "4 4 4",
        "TYPE": "F F F",
        "COUNT": "1 1 1",
        "WIDTH": str(len(points)),
        "HEIGHT": "1",
        "VIEWPOINT": "0 0 0 1 0 0 0",
        "POINTS": str(len(points)),
        "DATA": data,
    }
    fields.update(header or {})
    head = "".join(f"{k} {v}\n" for k, v in fields.items()).encode()
    pts = np.asarray(points, "<f4")
    body = pts.tobytes() if data == "binary" else "".join(f"{x} {y} {z}\n" for x, y, z in pts).encode()
    path.write_bytes(head + body)
    return path


def model_room(tmp: Path, cloud: Path, names: tuple[str, ...] = (), **kw: object) -> Case:
    out = earlier_outputs(tmp / "out")
    return Case(["model-room", str(cloud), "--out", str(out)], 2, names or (cloud.name,), out, **kw)


def register_room(tmp: Path, capture: Path, *extra: str, names: tuple[str, ...] = ()) -> Case:
    out = earlier_outputs(tmp / "out", "poses.parquet", "cloud.ply", "scale.json")
    return Case(["register-room", str(capture), "--out", str(out), *extra], 2, names or (capture.name,), out)


def survey_run(tmp: Path, data: dict | str | bytes, *extra: str, names: tuple[str, ...] = ()) -> Case:
    """`run` on a survey folder whose survey.yaml is `data` (a box-room cloud at rooms/a/cloud.ply)."""
    root = tmp / "s"
    good_ply(root / "rooms" / "a" / "cloud.ply")
    (root / "plan").mkdir()
    cv2.imwrite(str(root / "plan" / "plan.png"), np.full((40, 60), 255, np.uint8))
    path = root / "survey.yaml"
    if isinstance(data, bytes):
        path.write_bytes(data)
    elif isinstance(data, str):
        path.write_text(data)
    else:
        path.write_text(yaml.safe_dump(data, sort_keys=False))
    work = earlier_work(tmp / "w")
    return Case(["run", str(root), "--work", str(work), *extra], 2, names or ("survey.yaml",), work)


def good_survey(tmp: Path, **extra: object) -> Path:
    root = tmp / "s"
    good_ply(root / "rooms" / "a" / "cloud.ply")
    return write_survey(root, {"a": "rooms/a/cloud.ply"}, **extra)


GOOD = {"name": "s", "sensor": "kinect_v1", "rooms": [{"id": "a", "capture": "rooms/a/cloud.ply"}]}


# ------------------------------------------------------------------------------------------- clouds


@case
def ply_truncated_at_25_percent(tmp: Path) -> Case:
    path = good_ply(tmp / "cut25.ply")
    head, body = ply_parts(path)
    path.write_bytes(head.encode() + body[: len(body) // 4])
    return model_room(tmp, path)


@case
def ply_truncated_at_50_percent(tmp: Path) -> Case:
    path = good_ply(tmp / "cut50.ply")
    head, body = ply_parts(path)
    path.write_bytes(head.encode() + body[: len(body) // 2])
    return model_room(tmp, path)


def _claims(tmp: Path, factor: int) -> Case:
    path = good_ply(tmp / f"claims{factor}x.ply")
    head, body = ply_parts(path)
    n = int(re.search(r"element vertex (\d+)", head).group(1))  # type: ignore[union-attr]
    path.write_bytes(head.replace(f"vertex {n}", f"vertex {factor * n}").encode() + body)
    return model_room(tmp, path)


@case
def ply_header_claims_twice_the_vertices(tmp: Path) -> Case:
    return _claims(tmp, 2)


@case
def ply_header_claims_three_times_the_vertices(tmp: Path) -> Case:
    return _claims(tmp, 3)


@case
def ply_header_claims_a_billion_vertices(tmp: Path) -> Case:
    """2.9 kB that once grew to 22 GB: run in a child process under a memory limit."""
    path = good_ply(tmp / "billion.ply")
    head, body = ply_parts(path)
    n = int(re.search(r"element vertex (\d+)", head).group(1))  # type: ignore[union-attr]
    path.write_bytes(head.replace(f"vertex {n}", "vertex 1000000000").encode() + body[:2800])
    return model_room(tmp, path, subprocess=True)


@case
def ply_ascii_text_token_at_40_percent(tmp: Path) -> Case:
    rows = box_rows()
    rows[int(0.4 * len(rows))] = "0.1 abc 0.3"
    path = ascii_ply(tmp / "token.ply", rows)
    return model_room(tmp, path, names=("token.ply", "line", "'abc'"))


@case
def ply_ascii_row_with_a_value_missing(tmp: Path) -> Case:
    rows = box_rows()
    rows[700] = "0.1 0.2"
    return model_room(tmp, ascii_ply(tmp / "short.ply", rows))


@case
def ply_ascii_fewer_rows_than_the_header_says(tmp: Path) -> Case:
    rows = box_rows()
    return model_room(tmp, ascii_ply(tmp / "rows.ply", rows, count=len(rows) + 500))


@case
def ply_coordinate_1e200(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(1), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    pts[17] = [1e200, 0.0, 1.0]
    return model_room(tmp, write_ply_points(tmp / "e200.ply", pts))


@case
def ply_coordinate_1e308(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(1), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    pts[17] = [1.0, -1e308, 1.0]
    return model_room(tmp, write_ply_points(tmp / "e308.ply", pts))


@case
def ply_coordinate_infinite(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(1), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    pts[5] = [np.inf, 0.0, 1.0]
    return model_room(tmp, write_ply_points(tmp / "inf.ply", pts))


@case
def ply_empty_file(tmp: Path) -> Case:
    (tmp / "empty.ply").write_bytes(b"")
    return model_room(tmp, tmp / "empty.ply")


@case
def ply_without_vertices(tmp: Path) -> Case:
    return model_room(tmp, write_ply_points(tmp / "none.ply", np.zeros((0, 3))))


@case
def ply_of_random_bytes(tmp: Path) -> Case:
    (tmp / "noise.ply").write_bytes(np.random.default_rng(3).bytes(5000))
    return model_room(tmp, tmp / "noise.ply")


@case
def ply_header_never_ends(tmp: Path) -> Case:
    path = good_ply(tmp / "endless.ply")
    head, _body = ply_parts(path)
    path.write_bytes(head.replace("end_header\n", "").encode() + b"comment x\n" * 10)
    return model_room(tmp, path)


@case
def ply_unknown_format(tmp: Path) -> Case:
    path = good_ply(tmp / "middle.ply")
    head, body = ply_parts(path)
    path.write_bytes(head.replace("binary_little_endian", "binary_middle_endian").encode() + body)
    return model_room(tmp, path)


@case
def ply_without_z(tmp: Path) -> Case:
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty double x\nproperty double y\nend_header\n"
    (tmp / "flat.ply").write_bytes(head.encode() + np.zeros(200).tobytes())
    return model_room(tmp, tmp / "flat.ply")


@case
def ply_with_trailing_bytes(tmp: Path) -> Case:
    path = good_ply(tmp / "tail.ply")
    path.write_bytes(path.read_bytes() + b"\x00" * 1000)
    return model_room(tmp, path)


@case
def ply_property_of_unknown_type(tmp: Path) -> Case:
    path = good_ply(tmp / "type.ply")
    head, body = ply_parts(path)
    path.write_bytes(head.replace("property double z", "property quad z").encode() + body)
    return model_room(tmp, path)


@case
def pcd_truncated(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(2), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    path = pcd(tmp / "cut.pcd", pts)
    path.write_bytes(path.read_bytes()[: -len(pts) * 6])
    return model_room(tmp, path)


@case
def pcd_header_claims_more_points(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(2), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    n = 3 * len(pts)
    return model_room(tmp, pcd(tmp / "more.pcd", pts, header={"WIDTH": str(n), "POINTS": str(n)}))


@case
def pcd_ascii_text_token(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(2), size_m=(3.0, 2.5, 2.5), spacing_m=0.08)
    path = pcd(tmp / "token.pcd", pts, data="ascii")
    lines = path.read_text().splitlines()
    lines[len(lines) // 2] = "1.0 x 2.0"
    path.write_text("\n".join(lines) + "\n")
    return model_room(tmp, path, names=("token.pcd", "line"))


@case
def pcd_sizes_do_not_match_fields(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(2), size_m=(3.0, 2.5, 2.5), spacing_m=0.06)
    return model_room(tmp, pcd(tmp / "sizes.pcd", pts, header={"SIZE": "4 4"}))


@case
def cloud_in_millimetres(tmp: Path) -> Case:
    pts = box_room_points(np.random.default_rng(2), size_m=(3.0, 2.5, 2.5), spacing_m=0.06) * 1000
    return model_room(tmp, write_ply_points(tmp / "mm.ply", pts), names=("mm.ply", "millimetres"))


@case
def cloud_that_does_not_exist(tmp: Path) -> Case:
    return model_room(tmp, tmp / "nowhere.ply")


# --------------------------------------------------------------------------------------------- plans


@case
def plan_image_of_random_bytes(tmp: Path) -> Case:
    (tmp / "plan.png").write_bytes(np.random.default_rng(5).bytes(3000))
    out = earlier_outputs(tmp / "out", "plan_walls.parquet", "rooms.geojson", "plan_preview.png")
    return Case(
        ["parse-plan", str(tmp / "plan.png"), "--out", str(out), "--m-per-px", "0.02"], 2, ("plan.png",), out
    )


@case
def plan_known_distance_with_text(tmp: Path) -> Case:
    plan = {"image": "plan/plan.png", "known_distance": ["a", 0, 100, 0, 2.0]}
    return survey_run(tmp, {**GOOD, "plan": plan}, names=("survey.yaml", "plan.known_distance"))


@case
def plan_outline_length_as_text(tmp: Path) -> Case:
    plan = {"image": "plan/plan.png", "outline_length_m": "long"}
    return survey_run(tmp, {**GOOD, "plan": plan}, names=("survey.yaml", "plan.outline_length_m"))


@case
def plan_scale_implausible(tmp: Path) -> Case:
    plan = {"image": "plan/plan.png", "m_per_px": 20}
    return survey_run(tmp, {**GOOD, "plan": plan}, names=("survey.yaml", "m_per_px"))


@case
def plan_image_missing(tmp: Path) -> Case:
    plan = {"image": "plan/none.png", "m_per_px": 0.02}
    return survey_run(tmp, {**GOOD, "plan": plan}, names=("survey.yaml", "none.png"))


# ---------------------------------------------------------------------------------------------- MCAP


@case
def mcap_depth_image_of_0x0(tmp: Path) -> Case:
    path = rgbd_mcap(tmp / "zero.mcap", sizes=[(64, 48), (0, 0), (64, 48), (64, 48)])
    return register_room(tmp, path)


@case
def mcap_corrupt_compressed_colour(tmp: Path) -> Case:
    path = rgbd_mcap(tmp / "jpeg.mcap", jpeg=lambda i: b"\xff\xd8\xff\xe0" + bytes(range(256)) * 4)
    return register_room(tmp, path)


@case
def mcap_16bit_depth_labelled_32fc1(tmp: Path) -> Case:
    path = rgbd_mcap(
        tmp / "label.mcap",
        encoding="32FC1",
        depth_bytes=lambda i, w, h: np.full((h, w), 1500, "<u2").tobytes(),
    )
    return register_room(tmp, path)


@case
def mcap_frames_of_mixed_sizes(tmp: Path) -> Case:
    path = rgbd_mcap(tmp / "mixed.mcap", sizes=[(64, 48), (64, 48), (80, 60), (64, 48)])
    return register_room(tmp, path)


@case
def mcap_depth_all_zero(tmp: Path) -> Case:
    path = rgbd_mcap(tmp / "nodepth.mcap", depth_bytes=lambda i, w, h: bytes(2 * w * h))
    return register_room(tmp, path)


@case
def mcap_truncated(tmp: Path) -> Case:
    path = rgbd_mcap(tmp / "cut.mcap")
    path.write_bytes(path.read_bytes()[:3000])
    return register_room(tmp, path)


@case
def mcap_of_random_bytes(tmp: Path) -> Case:
    (tmp / "noise.mcap").write_bytes(np.random.default_rng(6).bytes(4000))
    return register_room(tmp, tmp / "noise.mcap")


# --------------------------------------------------------------------------------------- survey.yaml


@case
def survey_yaml_binary(tmp: Path) -> Case:
    return survey_run(tmp, b"\x89PNG\r\n\x1a\n\x00\x00\xff\xfe" + bytes(range(256)))


@case
def survey_room_id_with_trailing_newline(tmp: Path) -> Case:
    data = {**GOOD, "rooms": [{"id": "a\n", "capture": "rooms/a/cloud.ply"}]}
    return survey_run(tmp, data, names=("survey.yaml", "rooms[0]"))


@case
def survey_duplicate_room_ids(tmp: Path) -> Case:
    room = {"id": "a", "capture": "rooms/a/cloud.ply"}
    return survey_run(tmp, {**GOOD, "rooms": [room, room]}, names=("survey.yaml", "'a'"))


@case
def survey_unknown_key(tmp: Path) -> Case:
    return survey_run(tmp, {**GOOD, "romos": []}, names=("survey.yaml", "romos"))


@case
def survey_capture_missing(tmp: Path) -> Case:
    data = {**GOOD, "rooms": [{"id": "a", "capture": "rooms/a/gone.ply"}]}
    return survey_run(tmp, data, names=("survey.yaml", "gone.ply"))


@case
def survey_capture_of_unknown_format(tmp: Path) -> Case:
    (tmp / "s" / "rooms" / "a").mkdir(parents=True)
    (tmp / "s" / "rooms" / "a" / "room.obj").write_text("v 0 0 0\n")
    data = {**GOOD, "rooms": [{"id": "a", "capture": "rooms/a/room.obj"}]}
    return survey_run(tmp, data, names=("room.obj",))


@case
def survey_not_a_mapping(tmp: Path) -> Case:
    return survey_run(tmp, "- just\n- a list\n")


@case
def survey_without_rooms(tmp: Path) -> Case:
    return survey_run(tmp, {**GOOD, "rooms": []}, names=("survey.yaml", "rooms"))


@case
def survey_unknown_sensor(tmp: Path) -> Case:
    return survey_run(tmp, {**GOOD, "sensor": "kinect_v9"}, names=("survey.yaml", "kinect_v9"))


@case
def survey_unknown_room_requested(tmp: Path) -> Case:
    return survey_run(tmp, GOOD, "--rooms", "zz", names=("survey.yaml", "'zz'"))


# -------------------------------------------------------------------------------------------- config


def _config_run(tmp: Path, *extra: str, names: tuple[str, ...]) -> Case:
    return survey_run(tmp, GOOD, *extra, names=names)


@case
def config_file_binary(tmp: Path) -> Case:
    (tmp / "bin.yaml").write_bytes(b"\x00\x01\xff\xfe" * 50)
    return _config_run(tmp, "--config", str(tmp / "bin.yaml"), names=("bin.yaml",))


@case
def config_max_frames_negative(tmp: Path) -> Case:
    return _config_run(tmp, "--set", "ingest.max_frames=-5", names=("ingest.max_frames",))


@case
def config_frame_stride_zero(tmp: Path) -> Case:
    return _config_run(tmp, "--set", "ingest.frame_stride=0", names=("ingest.frame_stride",))


@case
def config_unknown_key(tmp: Path) -> Case:
    return _config_run(tmp, "--set", "preprocess.voxl_size_m=0.03", names=("preprocess.voxl_size_m",))


@case
def config_value_of_wrong_type(tmp: Path) -> Case:
    return _config_run(tmp, "--set", "preprocess.voxel_size_m=big", names=("preprocess.voxel_size_m",))


@case
def config_negative_voxel(tmp: Path) -> Case:
    return _config_run(tmp, "--set", "ingest.cloud_voxel_m=-1", names=("ingest", "cloud_voxel_m"))


@case
def calibration_file_not_json(tmp: Path) -> Case:
    (tmp / "calibration.json").write_text("{ir: [")
    capture = rgbd_mcap(tmp / "c.mcap")
    return register_room(
        tmp, capture, "--calibration", str(tmp / "calibration.json"), names=("calibration.json",)
    )


@case
def calibration_file_of_wrong_shape(tmp: Path) -> Case:
    (tmp / "calibration.json").write_text(json.dumps({"ir": 5}))
    capture = rgbd_mcap(tmp / "c.mcap")
    return register_room(
        tmp, capture, "--calibration", str(tmp / "calibration.json"), names=("calibration.json",)
    )


@case
def intrinsics_with_text(tmp: Path) -> Case:
    capture = rgbd_mcap(tmp / "c.mcap")
    return register_room(tmp, capture, "--intrinsics", "1,2,x", names=("--intrinsics",))


@case
def intrinsics_negative(tmp: Path) -> Case:
    capture = rgbd_mcap(tmp / "c.mcap")
    return register_room(tmp, capture, "--intrinsics=-500,500,32,24", names=("--intrinsics",))


@case
def calibration_given_as_json_text(tmp: Path) -> Case:
    capture = rgbd_mcap(tmp / "c.mcap")
    return register_room(tmp, capture, "--calibration", '{"ir":5}', names=("--calibration",))


@case
def rerun_of_a_building_stage_for_one_room(tmp: Path) -> Case:
    root = good_survey(tmp)
    work = earlier_work(tmp / "w")
    argv = ["rerun", str(root), "--work", str(work), "--stage", "plan", "--room", "a"]
    return Case(argv, 2, ("--room", "plan"), work)


@case
def rerun_of_an_unknown_stage(tmp: Path) -> Case:
    root = good_survey(tmp)
    work = earlier_work(tmp / "w")
    return Case(["rerun", str(root), "--work", str(work), "--stage", "wals"], 2, ("'wals'",), work)


# ----------------------------------------------------------------------------------------- work dirs


@case
def work_dir_is_a_file(tmp: Path) -> Case:
    root = good_survey(tmp)
    (tmp / "w").write_text("not a folder")
    return Case(["run", str(root), "--work", str(tmp / "w")], 2, (str(tmp / "w"),), tmp)


@case
def work_dir_below_a_file(tmp: Path) -> Case:
    root = good_survey(tmp)
    (tmp / "f").write_text("not a folder")
    return Case(["run", str(root), "--work", str(tmp / "f" / "w")], 2, (str(tmp / "f"),), tmp)


@case
def work_dir_not_writable(tmp: Path) -> Case:
    root = good_survey(tmp)
    if os.geteuid() == 0:  # root writes anywhere but in kernel file systems
        work = Path("/sys/kernel/indoor-survey-work")
    else:
        (tmp / "ro").mkdir()
        (tmp / "ro").chmod(0o555)
        work = tmp / "ro" / "w"
    return Case(["run", str(root), "--work", str(work)], 2, (str(work),), root)


@case
def status_work_dir_is_a_file(tmp: Path) -> Case:
    root = good_survey(tmp)
    (tmp / "w").write_text("not a folder")
    return Case(["status", str(root), "--work", str(tmp / "w")], 2, (str(tmp / "w"),), tmp)


@case
def model_room_out_is_a_file(tmp: Path) -> Case:
    cloud = good_ply(tmp / "room.ply")
    (tmp / "out").write_text("not a folder")
    return Case(["model-room", str(cloud), "--out", str(tmp / "out")], 2, (str(tmp / "out"),), tmp)


@case
def parse_plan_out_is_a_file(tmp: Path) -> Case:
    image = tmp / "plan.png"
    cv2.imwrite(str(image), np.full((50, 50), 255, np.uint8))
    (tmp / "out").write_text("not a folder")
    argv = ["parse-plan", str(image), "--out", str(tmp / "out"), "--m-per-px", "0.02"]
    return Case(argv, 2, (str(tmp / "out"),), tmp)


@case
def register_room_out_is_a_file(tmp: Path) -> Case:
    capture = rgbd_mcap(tmp / "c.mcap")
    (tmp / "out").write_text("not a folder")
    return Case(["register-room", str(capture), "--out", str(tmp / "out")], 2, (str(tmp / "out"),), tmp)


# -------------------------------------------------------------------------------------------- others


@case
def evaluate_walls_malformed_geojson(tmp: Path) -> Case:
    (tmp / "pred.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "features": [{"geometry": 5}]})
    )
    (tmp / "truth.geojson").write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [{"geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 0]]}}],
            }
        )
    )
    return Case(
        ["evaluate-walls", str(tmp / "pred.geojson"), str(tmp / "truth.geojson")], 2, ("pred.geojson",), tmp
    )


@case
def evaluate_walls_text_coordinates(tmp: Path) -> Case:
    line = {"geometry": {"type": "LineString", "coordinates": [["a", 0], [1, 0]]}}
    (tmp / "truth.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [line]}))
    good = {"geometry": {"type": "LineString", "coordinates": [[0, 0], [1, 0]]}}
    (tmp / "pred.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [good]}))
    return Case(
        ["evaluate-walls", str(tmp / "pred.geojson"), str(tmp / "truth.geojson")], 2, ("truth.geojson",), tmp
    )


@case
def synth_into_a_folder_with_files(tmp: Path) -> Case:
    out = earlier_outputs(tmp / "survey", "notes.txt", "survey.yaml")
    return Case(["synth", str(out), "--seed", "1"], 2, (str(out), "--overwrite"), out)


# ------------------------------------------------------------------------------------------- the sweep

MEMORY_LIMIT = 6 << 30
"""Address space of a child that runs a case once known to grow without bound (22 GB before)."""


def snapshot(folder: Path | None) -> dict[str, str]:
    """Relative path -> sha256 of every file under `folder`, caches aside (a failed stage may leave an
    empty stage folder there; what it holds is verified by hash on every lookup)."""
    if folder is None or not folder.exists():
        return {}
    skip = {"cache", ".cache", "prefect-results"}
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not skip & set(p.relative_to(folder).parts)
    }


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_cli(argv: list[str], in_child: bool, capfd: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of the CLI, in this process or in a child under a memory limit."""
    if in_child:
        done = subprocess.run(
            [sys.executable, "-m", "flows.cli", "-q", *argv],
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
            capture_output=True,
            text=True,
            timeout=300,
            preexec_fn=_limit_memory,
        )
        return done.returncode, done.stdout, done.stderr
    code = main(["-q", *argv])
    out, err = capfd.readouterr()
    return code, out, err


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_refused_in_one_line(name, tmp_path, capfd):
    """Exit code, one line naming the file or key, no traceback, earlier outputs unchanged."""
    bad = CASES[name](tmp_path)
    before = snapshot(bad.watch)
    capfd.readouterr()
    code, out, err = run_cli(bad.argv, bad.subprocess, capfd)
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in out + err, err
    assert code == bad.code, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for needle in bad.names:
        assert needle in lines[0], f"{needle!r} not named in: {lines[0]}"
    assert snapshot(bad.watch) == before


def test_the_sweep_covers_every_kind_of_input():
    kinds = {name.split("_")[0] for name in CASES}
    assert len(CASES) >= 40
    assert {"ply", "pcd", "plan", "mcap", "survey", "config", "work"} <= kinds, kinds


# ----------------------------------------------------------------------------------- valid after all


def test_a_long_comment_and_a_late_vertex_line_are_read(tmp_path):
    """A header line of 5 kB (it aborted the process inside Open3D) and an `element vertex` line past
    byte 4096 (it was 'not a PLY file') are valid PLY: read, in a child that would show an abort."""
    good = good_ply(tmp_path / "good.ply")
    head, body = ply_parts(good)
    long = tmp_path / "long.ply"
    long.write_bytes(head.replace("1.0\n", "1.0\ncomment " + "x" * 5000 + "\n", 1).encode() + body)
    late = tmp_path / "late.ply"
    late.write_bytes(head.replace("1.0\n", "1.0\n" + "comment a survey note\n" * 400, 1).encode() + body)
    script = (
        "import sys, numpy as np; from tasks.artefacts import read_cloud; "
        "a, b, c = (read_cloud(p) for p in sys.argv[1:]); "
        "assert np.array_equal(a.points, b.points) and np.array_equal(a.points, c.points); print(len(a))"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(good), str(long), str(late)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) > 5000


def test_a_header_claiming_a_billion_vertices_costs_no_memory(tmp_path):
    """Limits come from the file's real size: the 2.9 kB file is refused having allocated about the
    header buffer, not 27 GB."""
    case = CASES["ply_header_claims_a_billion_vertices"](tmp_path)
    path = Path(case.argv[1])
    script = (
        "import sys, tracemalloc; from tasks.artefacts import read_cloud, ArtefactError\n"
        "tracemalloc.start()\n"
        "try:\n    read_cloud(sys.argv[1])\nexcept ArtefactError as exc:\n    print(exc, file=sys.stderr)\n"
        "print(tracemalloc.get_traced_memory()[1])"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(path)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_limit_memory,
    )
    assert done.returncode == 0, done.stderr
    assert "1000000000 vertex" in done.stderr
    peak = int(done.stdout)
    assert peak < 2 * path.stat().st_size + (1 << 20) + 200_000, peak  # the header read: at most 1 MiB


# --------------------------------------------------------------------------------------------- runs


@pytest.mark.slow
def test_a_damaged_capture_keeps_the_rooms_earlier_deliverables(tmp_path):
    """Issue #21 item 1: a truncated room cloud on a rerun fails that room (exit 3: the survey's hallway
    still finishes; one line naming the file); its outputs/rooms/<id>/ keep their bytes and metrics.json keeps its figures, marked as the
    earlier run's."""
    survey, work = tmp_path / "s", tmp_path / "w"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cli = [sys.executable, "-m", "flows.cli", "-q"]
    subprocess.run(
        [*cli, "synth", str(survey), "--seed", "3", "--rooms", "1", "--profile", "tls"],
        cwd=REPO,
        env=env,
        check=True,
    )
    first = subprocess.run(
        [*cli, "run", str(survey), "--work", str(work)], cwd=REPO, env=env, capture_output=True
    )
    assert first.returncode == 0, first.stderr
    room = work / "outputs" / "rooms" / "r1"
    kept = snapshot(room)
    assert set(kept) >= {"walls.parquet", "plan.geojson", "model.ply", "preview.png"}

    cloud = survey / "rooms" / "r1" / "cloud.ply"
    head, body = ply_parts(cloud)
    cloud.write_bytes(head.encode() + body[: len(body) // 2])
    again = subprocess.run(
        [*cli, "run", str(survey), "--work", str(work)], cwd=REPO, env=env, capture_output=True, text=True
    )
    assert again.returncode == 3
    errors = [line for line in again.stderr.splitlines() if line.strip()]
    assert errors == [errors[0]] and "room r1, stage ingest" in errors[0] and str(cloud) in errors[0]
    assert "Traceback" not in again.stderr
    assert snapshot(room) == kept
    metrics = json.loads((work / "outputs" / "metrics.json").read_text())
    r1 = next(r for r in metrics["rooms"] if r["room"] == "r1")
    assert r1["earlier_run"] is True and r1["completeness"] > 0.5


def _children(pid: int) -> list[int]:
    """Every descendant of a process (from /proc)."""
    found, frontier = [], [pid]
    while frontier:
        parent = frontier.pop()
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == parent:
                found.append(int(stat.parent.name))
                frontier.append(int(stat.parent.name))
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_no_process_of_a_killed_run_survives(tmp_path):
    """Issue #21 item 5: SIGKILL a run once its embedded Prefect server is up; a few seconds later
    nothing it started is alive (the server had outlived 22 of 22 killed runs)."""
    survey = tmp_path / "s"
    write_box_room_ply(survey / "a.ply", np.random.default_rng(4), size_m=(6.0, 5.0, 2.7), spacing_m=0.012)
    write_survey(survey, {"a": "a.ply"})
    env = {k: v for k, v in os.environ.items() if k != "PREFECT_API_URL"}
    work = tmp_path / "w"
    proc = subprocess.Popen(
        [sys.executable, "-m", "flows.cli", "-q", "run", str(survey), "--work", str(work)],
        cwd=REPO,
        env={**env, "PYTHONPATH": str(REPO)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 180
        while time.time() < deadline and not any((work / "cache" / "a").glob("*/.tmp-*")):
            assert proc.poll() is None, "the run ended before its first stage"
            time.sleep(0.1)
        started = _children(proc.pid)
        assert started, "the run started no server"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    deadline = time.time() + 10
    while time.time() < deadline and any(Path(f"/proc/{pid}").exists() for pid in started):
        time.sleep(0.2)
    alive = [pid for pid in started if Path(f"/proc/{pid}").exists()]
    assert not alive, f"still alive after the run was killed: {alive}"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_a_new_run_reaps_the_server_a_dead_run_left(tmp_path):
    """The record of a dead run's server makes the next run in the work dir stop it (a live run's
    server, and a process that is not a Prefect server, are left alone)."""
    from flows import prefect_env

    orphan = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)", "prefect.server.api.server:create_app"]
    )
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    try:
        record = {
            "server_pid": orphan.pid,
            "server_started": prefect_env._start_time(orphan.pid),
            "run_pid": dead.pid,
            "run_started": 1,
        }
        (tmp_path / prefect_env.SERVER_RECORD).write_text(json.dumps(record))
        live = {**record, "run_pid": os.getpid(), "run_started": prefect_env._start_time(os.getpid())}
        (tmp_path / "live").mkdir()
        (tmp_path / "live" / prefect_env.SERVER_RECORD).write_text(json.dumps(live))
        assert not prefect_env.reap_stale_server(tmp_path / "live")
        assert orphan.poll() is None
        assert prefect_env.reap_stale_server(tmp_path)
        assert orphan.wait(timeout=5) == -signal.SIGKILL
        assert not (tmp_path / prefect_env.SERVER_RECORD).exists()
    finally:
        orphan.kill()
        orphan.wait()


# ---------------------------------------------------------------------------------------- single items


def _no_prefect_run(monkeypatch, seen: list) -> None:
    """`run` answered from the store: all_current records the request and reports nothing to do."""
    from flows import planning

    monkeypatch.setattr(planning, "all_current", lambda req: seen.append(req) or [])


def test_rooms_given_twice_run_once(tmp_path, monkeypatch, capsys):
    seen: list = []
    _no_prefect_run(monkeypatch, seen)
    root = good_survey(tmp_path)
    assert main(["-q", "run", str(root), "--work", str(tmp_path / "w"), "--rooms", "a", "a", "a"]) == 0
    assert seen[0].rooms == ("a",)


def test_inputs_outside_the_survey_are_said_in_the_summary(tmp_path, monkeypatch, capsys):
    seen: list = []
    _no_prefect_run(monkeypatch, seen)
    outside = good_ply(tmp_path / "elsewhere" / "room.ply")
    root = write_survey(tmp_path / "s", {"a": "../elsewhere/room.ply"})
    assert main(["-q", "run", str(root), "--work", str(tmp_path / "w")]) == 0
    out = capsys.readouterr().out
    assert f"note: room a: capture {outside} lies outside the survey folder" in out


def test_an_unexpected_error_in_a_stage_is_one_line_naming_room_stage_and_input(tmp_path, monkeypatch, capfd):
    """The stage's error boundary: an exception nobody foresaw becomes one line and exit 1; the debug
    variable brings the traceback back."""
    import tasks.preprocess.stage

    def crash(ctx, cfg, out):
        raise KeyError("levels")

    monkeypatch.setattr(tasks.preprocess.stage, "run", crash)
    cloud = good_ply(tmp_path / "room.ply")
    out = earlier_outputs(tmp_path / "out")
    before = snapshot(out)
    monkeypatch.delenv("INDOOR_SURVEY_DEBUG", raising=False)
    assert main(["-q", "model-room", str(cloud), "--out", str(out)]) == 1
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith("error: room room, stage preprocess: unexpected KeyError")
    assert "ingest result" in lines[0] and "INDOOR_SURVEY_DEBUG=1" in lines[0]
    assert snapshot(out) == before
    monkeypatch.setenv("INDOOR_SURVEY_DEBUG", "1")
    shutil.rmtree(out / ".cache")
    assert main(["-q", "model-room", str(cloud), "--out", str(out)]) == 1
    assert "Traceback" in capfd.readouterr().err


def test_an_unexpected_error_outside_the_stages_is_one_line(tmp_path, monkeypatch, capfd):
    from flows import cli

    monkeypatch.setattr(cli, "cmd_config", lambda args: {}["boom"])
    monkeypatch.delenv("INDOOR_SURVEY_DEBUG", raising=False)
    assert main(["config"]) == 1
    err = capfd.readouterr().err
    assert (
        err.strip()
        == "error: config: unexpected KeyError: 'boom' (set INDOOR_SURVEY_DEBUG=1 for the traceback)"
    )


def _done_room(tmp_path: Path) -> tuple[Path, Path]:
    """A survey whose room 'a' is computed (ingest, preprocess, walls) into a work dir, without Prefect."""
    from flows import planning
    from tasks import config as cfgmod

    root = good_survey(tmp_path)
    survey = cfgmod.load_survey(root)
    work = tmp_path / "w"
    room = survey.rooms[0]
    profile = cfgmod.load_sensor_profile(survey.sensor)
    planning.run_chain(work, cfgmod.load_config(), profile, planning.room_stages(room.capture), room)
    return root, work


def _status(root: Path, work: Path, capsys) -> dict[tuple[str, str], str]:
    assert main(["status", str(root), "--work", str(work)]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    return {(r[0], r[1]): r[2] for r in rows}


def test_status_only_reads_the_work_dir(tmp_path, capsys):
    """Issue #21 item 7: status wrote _file_hashes.json into a work dir it only needed to read."""
    root, work = _done_room(tmp_path)
    (work / "cache" / "_file_hashes.json").unlink()
    before = {str(p): p.read_bytes() for p in work.rglob("*") if p.is_file()}
    assert _status(root, work, capsys)[("a", "walls")] == "done"
    assert {str(p): p.read_bytes() for p in work.rglob("*") if p.is_file()} == before


def test_a_capture_replaced_with_the_same_size_and_mtime_is_stale(tmp_path, capsys, monkeypatch):
    """Issue #21 item 2: `cp -p` of another capture of the same size was 'every stage is current'."""
    from tasks.artefacts import ArtefactStore

    monkeypatch.setattr(ArtefactStore, "RACY_SECONDS", -1e9)  # the memo trusted as long as its key holds
    root, work = _done_room(tmp_path)
    assert _status(root, work, capsys)[("a", "ingest")] == "done"
    capture = root / "rooms" / "a" / "cloud.ply"
    other = good_ply(tmp_path / "other.ply", seed=9)
    assert other.stat().st_size == capture.stat().st_size
    time.sleep(0.05)
    shutil.copy2(other, capture)  # cp -p: the other file's bytes and times
    os.utime(capture, ns=(capture.stat().st_atime_ns, other.stat().st_mtime_ns))
    assert _status(root, work, capsys)[("a", "ingest")] == "stale"


def test_a_profile_calibration_follows_the_frames_size():
    """Issue #21 item 10: without calibration data the sensor profile's 640x480 intrinsics met 320x240
    frames and every RGB-D room failed ('operands could not be broadcast together')."""
    from tasks.camera import profile_calibration
    from tasks.cloud import DegenerateInputError
    from tasks.config import load_sensor_profile
    from tasks.register.stage import fit_to_frames

    calib = profile_calibration(load_sensor_profile("kinect_v1"))
    sizes = {"depth": [320, 240], "rgb": [320, 240]}
    fitted = fit_to_frames(calib, sizes, from_profile=True)
    assert fitted.ir.size == (320, 240) and fitted.rgb is not None and fitted.rgb.size == (320, 240)
    assert fitted.ir.fx == pytest.approx(calib.ir.fx / 2)
    assert fit_to_frames(calib, {"depth": [640, 480]}, from_profile=False) is calib
    with pytest.raises(
        DegenerateInputError, match="IR camera is 640x480, the capture's depth frames are 320x240"
    ):
        fit_to_frames(calib, sizes, from_profile=False)  # a measured calibration is not rescaled
    with pytest.raises(DegenerateInputError, match="another aspect"):
        fit_to_frames(calib, {"depth": [320, 200]}, from_profile=True)
