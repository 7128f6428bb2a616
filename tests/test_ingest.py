import numpy as np
import pyarrow.parquet as pq
import pytest

from tasks.artefacts import read_json
from tasks.config import load_sensor_profile
from tasks.ingest.capture import capture_kind, ingest_capture
from tasks.ingest.config import IngestConfig
from tasks.ingest.errors import IngestError
from tasks.ingest.frames import decode_depth_m, decode_rgb, iter_frames
from tests.captures import write_box_room_ply, write_rgbd_mcap


@pytest.fixture
def profile():
    return load_sensor_profile("kinect_v1")


def _rows(out):
    return list(iter_frames(out / "frames.parquet"))


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_mcap_frames_depth_in_metres_and_nearest_colour(tmp_path, profile, encoding):
    write_rgbd_mcap(tmp_path / "c.mcap", n_frames=6, depth_encoding=encoding)
    out = tmp_path / "out"
    out.mkdir()
    metrics = ingest_capture(tmp_path / "c.mcap", out, profile, IngestConfig())
    assert metrics["frames"] == 6 and metrics["frames_with_colour"] == 6
    rows = _rows(out)
    for i, row in enumerate(rows):
        depth = decode_depth_m(row)
        assert depth.shape == (48, 64)
        assert depth.mean() == pytest.approx(1.0 + 0.1 * i, abs=1e-3)
        assert row["rgb_t_ns"] - row["t_ns"] == 3_000_000  # its own colour image, not the previous one
        assert decode_rgb(row)[..., 0].mean() == pytest.approx((40 * i) % 256, abs=3)
    info = read_json(out / "camera_info.json")
    assert info["depth"]["source"] == "camera_info" and info["depth"]["K"][0][0] == 60.0
    assert info["rgb"]["source"] == "profile"
    assert pq.read_table(out / "imu.parquet").num_rows == 6
    assert pq.read_table(out / "device_poses.parquet").column("tx").to_pylist()[-1] == pytest.approx(0.5)


def test_mcap_stride_and_limit(tmp_path, profile):
    write_rgbd_mcap(tmp_path / "c.mcap", n_frames=10)
    out = tmp_path / "out"
    out.mkdir()
    ingest_capture(tmp_path / "c.mcap", out, profile, IngestConfig(frame_stride=2, max_frames=3))
    assert [round(float(decode_depth_m(r).mean()), 2) for r in _rows(out)] == [1.0, 1.2, 1.4]


def test_truncated_mcap_is_named(tmp_path, profile):
    write_rgbd_mcap(tmp_path / "c.mcap")
    data = (tmp_path / "c.mcap").read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(IngestError, match=r"cut\.mcap: truncated or corrupt MCAP"):
        ingest_capture(tmp_path / "cut.mcap", tmp_path, profile, IngestConfig())


def test_mcap_without_depth_topic(tmp_path, profile):
    write_rgbd_mcap(tmp_path / "c.mcap", depth=False)
    with pytest.raises(IngestError, match=r"c\.mcap: no depth topic /camera/depth/image_raw"):
        ingest_capture(tmp_path / "c.mcap", tmp_path, profile, IngestConfig())


def test_topic_override(tmp_path, profile):
    write_rgbd_mcap(tmp_path / "c.mcap")
    with pytest.raises(IngestError, match="no depth topic /other"):
        ingest_capture(tmp_path / "c.mcap", tmp_path, profile, IngestConfig(depth_topic="/other"))


def test_cloud_capture(tmp_path, profile, rng):
    write_box_room_ply(tmp_path / "room.ply", rng)
    out = tmp_path / "out"
    out.mkdir()
    metrics = ingest_capture(tmp_path / "room.ply", out, profile, IngestConfig())
    assert metrics["capture_kind"] == "cloud" and metrics["points"] > 10_000
    assert (out / "cloud.ply").is_file()


def test_unknown_capture_kinds(tmp_path):
    (tmp_path / "x.obj").write_bytes(b"")
    with pytest.raises(IngestError, match=r"x\.obj: unknown capture format"):
        capture_kind(tmp_path / "x.obj")
    with pytest.raises(IngestError, match="no such capture"):
        capture_kind(tmp_path / "missing.mcap")
    with pytest.raises(IngestError, match="neither a TUM"):
        capture_kind(tmp_path)


def test_real_tum_frame_as_tum_folder(tmp_path, profile, realdata):
    frames = realdata("rgbd_single_frames")
    folder = tmp_path / "tum"
    folder.mkdir()
    # A TUM folder whose lists point at the real frame (absolute paths; the data is not copied).
    (folder / "rgb.txt").write_text(f"# color\n1305031102.175304 {frames / 'TUM_color.png'}\n")
    (folder / "depth.txt").write_text(f"# depth\n1305031102.160407 {frames / 'TUM_depth.png'}\n")
    out = tmp_path / "out"
    out.mkdir()
    metrics = ingest_capture(folder, out, profile, IngestConfig())
    assert metrics["frames"] == 1 and metrics["frames_with_colour"] == 1
    row = _rows(out)[0]
    depth = decode_depth_m(row)
    valid = depth[depth > 0]
    assert 0.3 < np.median(valid) < 5.0  # a desk scene: metres, not TUM units
    assert decode_rgb(row).shape == (480, 640, 3)


def test_real_7scenes_folder(tmp_path, profile, realdata):
    folder = realdata("rgbd_7scenes_redkitchen")
    out = tmp_path / "out"
    out.mkdir()
    metrics = ingest_capture(folder, out, profile, IngestConfig(max_frames=4))
    assert metrics["frames"] == 4 and metrics["device_poses"] == 4
    depth = decode_depth_m(_rows(out)[0])
    assert depth.max() < 10.0  # 65535 "no return" became 0
    assert read_json(out / "camera_info.json")["depth"]["K"][0][0] == 585.0
