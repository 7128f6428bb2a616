from pathlib import Path

import cv2
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


def test_data_mini_cloud_artefact_is_byte_identical_to_open3ds_reading(tmp_path, profile):
    """Checking clouds changed no valid one: r5's cloud.ply artefact is what Open3D's reading made."""
    import open3d as o3d

    from tasks.artefacts import write_ply_points

    source = Path(__file__).resolve().parents[1] / "data" / "mini" / "rooms" / "r5" / "cloud.ply"
    metrics = ingest_capture(source, tmp_path, profile, IngestConfig())
    pcd = o3d.io.read_point_cloud(str(source), remove_nan_points=False, remove_infinite_points=False)
    colours = np.clip(np.asarray(pcd.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    write_ply_points(tmp_path / "open3d.ply", np.asarray(pcd.points), colours)
    assert (tmp_path / "cloud.ply").read_bytes() == (tmp_path / "open3d.ply").read_bytes()
    assert metrics["points"] == len(pcd.points)


def test_cloud_coordinates_beyond_1e7_m_are_refused(tmp_path, profile, rng):
    from tasks.artefacts import write_ply_points
    from tests.captures import box_room_points

    pts = box_room_points(rng, spacing_m=0.1)
    pts[3] = [2.0, 3e7, 1.0]  # one damaged value: the unit check sees the bulk only
    write_ply_points(tmp_path / "far.ply", pts)
    with pytest.raises(IngestError, match=r"far\.ply: 1 of \d+ points lie beyond ±1e\+07 m .*point 3"):
        ingest_capture(tmp_path / "far.ply", tmp_path, profile, IngestConfig())


def test_a_frame_whose_colour_does_not_decode_keeps_its_depth(tmp_path, profile):
    from tests.captures import rgbd_mcap

    def jpeg(i):
        _ok, buf = cv2.imencode(".jpg", np.full((48, 64, 3), 90, np.uint8))
        return b"not a jpeg" if i == 1 else buf.tobytes()

    rgbd_mcap(tmp_path / "c.mcap", jpeg=jpeg)
    out = tmp_path / "out"
    out.mkdir()
    metrics = ingest_capture(tmp_path / "c.mcap", out, profile, IngestConfig())
    assert metrics["frames"] == 4 and metrics["frames_with_colour"] == 3
    assert metrics["colour_undecodable"] == 1
    assert [bool(r["rgb"]) for r in _rows(out)] == [True, False, True, True]
    assert read_json(out / "camera_info.json")["frame_sizes"] == {"depth": [64, 48], "rgb": [64, 48]}


def test_padded_depth_rows_are_read(tmp_path, profile):
    from tests.captures import rgbd_mcap

    rgbd_mcap(tmp_path / "c.mcap", n=1)
    # the same frame with rows padded to 136 bytes (ROS `step`) reads as the same depth
    from mcap_ros2.writer import Writer

    from tasks import rosmsgs
    from tests.captures import TOPICS

    with open(tmp_path / "p.mcap", "wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef(rosmsgs.IMAGE, rosmsgs.definition(rosmsgs.IMAGE))
        rows = np.zeros((48, 68), "<u2")
        rows[:, :64] = 1500
        msg = {
            "header": rosmsgs.header(1_000_000_000, "depth"),
            "height": 48,
            "width": 64,
            "encoding": "16UC1",
            "is_bigendian": 0,
            "step": 136,
            "data": rows.tobytes(),
        }
        writer.write_message(TOPICS["depth"], schema, msg, 1_000_000_000)
        writer.finish()
    out = tmp_path / "out"
    out.mkdir()
    ingest_capture(tmp_path / "p.mcap", out, profile, IngestConfig())
    depth = decode_depth_m(_rows(out)[0])
    assert depth.shape == (48, 64) and np.all(depth == pytest.approx(1.5))


def test_profile_intrinsics_follow_the_frames_size(tmp_path, profile):
    """Issue #21 item 10: a recording without CameraInfo at 320x240 gets the 640x480 profile's
    intrinsics scaled (pixel centres kept), not applied as they are."""
    from tests.captures import rgbd_mcap

    rgbd_mcap(tmp_path / "c.mcap", size=(320, 240), camera_info=False)
    out = tmp_path / "out"
    out.mkdir()
    ingest_capture(tmp_path / "c.mcap", out, profile, IngestConfig())
    info = read_json(out / "camera_info.json")
    depth = info["depth"]
    assert depth["source"] == "profile" and depth["size"] == [320, 240] and depth["scaled_from"] == [640, 480]
    assert depth["K"][0][0] == pytest.approx(585.7 / 2)
    assert depth["K"][0][2] == pytest.approx((320.1 + 0.5) / 2 - 0.5)
    rgbd_mcap(tmp_path / "d.mcap", size=(320, 200), camera_info=False)
    with pytest.raises(
        IngestError, match=r"d\.mcap: the depth frames are 320x200, .* 640x480 \(another aspect\)"
    ):
        ingest_capture(tmp_path / "d.mcap", tmp_path, profile, IngestConfig())


@pytest.mark.parametrize(
    ("setting", "value"),
    [
        ("frame_stride", 0),
        ("max_frames", -5),
        ("max_sync_gap_ms", -1.0),
        ("tum_depth_units_per_m", 0.0),
        ("max_cloud_extent_m", float("nan")),
        ("intrinsics_px", (0.0, 500.0, 320.0, 240.0)),
    ],
)
def test_impossible_ingest_settings_are_refused(setting, value):
    with pytest.raises(ValueError, match=rf"ingest\.{setting} must be"):
        IngestConfig(**{setting: value})
