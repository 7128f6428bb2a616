"""`indoor-survey model-room` and `evaluate-walls` on a tilted, shifted box room with a known answer."""

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation

from flows.cli import main
from tasks.artefacts import write_ply_points
from tests.captures import box_room_points

pytestmark = pytest.mark.slow


def test_model_room_walls_in_the_input_frame(tmp_path, capsys):
    rng = np.random.default_rng(7)
    pts = box_room_points(rng, size_m=(5.0, 3.5, 2.6), spacing_m=0.02, noise_m=0.002)
    # a 2 degree tilt about the room's centre and an offset: walls must come back in this frame
    centre = pts.mean(axis=0)
    rot = Rotation.from_rotvec(np.radians(2.0) * np.array([0.6, 0.8, 0.0])).as_matrix()
    moved = (pts - centre) @ rot.T + centre + np.array([10.0, -4.0, 0.3])
    write_ply_points(tmp_path / "room.ply", moved)
    assert main(["model-room", str(tmp_path / "room.ply"), "--out", str(tmp_path / "out")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["walls"] == 4 and summary["closed"]
    assert summary["height_m"] == pytest.approx(2.6, abs=0.02)

    walls = pq.read_table(tmp_path / "out" / "walls.parquet")
    assert walls.column_names == ["x0", "y0", "x1", "y1", "height", "origin", "support"]
    # the truth: the box's inner faces carried through the same transform, at the levelling pivot height
    corners = np.array([[0, 0], [5.0, 0], [5.0, 3.5], [0, 3.5]])
    truth = []
    for i in range(4):
        a, b = corners[i], corners[(i + 1) % 4]
        ends = np.array([[*a, centre[2]], [*b, centre[2]]])
        ends = (ends - centre) @ rot.T + centre + np.array([10.0, -4.0, 0.3])
        truth.append([*ends[0, :2], *ends[1, :2]])
    truth_path = tmp_path / "truth.parquet"
    pq.write_table(
        __import__("pyarrow").table(
            {k: np.array(truth)[:, i] for i, k in enumerate(["x0", "y0", "x1", "y1"])}
        ),
        truth_path,
    )
    assert main(["evaluate-walls", str(tmp_path / "out" / "walls.parquet"), str(truth_path)]) == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["completeness"] > 0.97 and metrics["correctness"] > 0.97
    assert metrics["accuracy_mean_m"] < 0.01
    for name in ("plan.geojson", "model.ply", "preview.png", "levelling.json"):
        assert (tmp_path / "out" / name).is_file()


@pytest.mark.parametrize("count", [0, 10])
def test_model_room_degenerate_cloud_is_one_line(tmp_path, capsys, count):
    write_ply_points(tmp_path / "few.ply", np.random.default_rng(0).random((count, 3)))
    code = main(["model-room", str(tmp_path / "few.ply"), "--out", str(tmp_path / "out")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert code == 2
    assert len(err) == 1 and "few.ply" in err[0]


@pytest.mark.parametrize(("scale", "unit"), [(1000.0, "millimetres"), (100.0, "centimetres")])
def test_model_room_cloud_in_the_wrong_unit_is_one_line(tmp_path, capsys, scale, unit):
    """A 5 m x 3.5 m x 2.6 m room written in millimetres or centimetres: one line naming the file and the
    unit it looks like, and nothing written."""
    pts = box_room_points(np.random.default_rng(3), size_m=(5.0, 3.5, 2.6), spacing_m=0.1, noise_m=0.0)
    write_ply_points(tmp_path / "room.ply", pts * scale)
    code = main(["model-room", str(tmp_path / "room.ply"), "--out", str(tmp_path / "out")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error:")]
    assert code == 2
    assert len(err) == 1 and "room.ply" in err[0] and unit in err[0], err
    assert not (tmp_path / "out" / "walls.parquet").exists()
