"""The synthetic survey: IMU track drift, survey folder format, truth schemas, determinism."""

from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pyarrow as pa
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from shapely.geometry import LineString, Point

from tasks.artefacts import read_cloud, read_table
from tasks.config import load_sensor_profile, load_survey
from tasks.synth.building import generate_building
from tasks.synth.survey import SurveyConfig, generate_survey, select_rooms
from tasks.synth.track import (
    TrackConfig,
    TrackLeg,
    dead_reckon,
    shortest_path,
    survey_track,
    walk_time_ns,
    walkable_area,
)

SMALL = SurveyConfig(frames_mini=4, tls_step_deg_mini=3.0)


@pytest.fixture(scope="module")
def building():
    return generate_building(0)


def test_shortest_path_stays_in_the_walkable_area_and_goes_through_doors(building):
    area = walkable_area(building, 0.3)
    a = np.asarray(area.intersection(building.room("r1").polygon).representative_point().coords[0])
    b = np.asarray(area.intersection(building.room("r5").polygon).representative_point().coords[0])
    path = shortest_path(area, building.you_are_here, a)
    path2 = shortest_path(area, a, b)
    assert area.buffer(1e-5).covers(LineString(path2))
    # a start outside the area (the plan hangs on the wall) is first joined to the area's nearest point
    assert area.buffer(1e-5).covers(LineString(path[1:]))
    assert path[0] == pytest.approx(building.you_are_here) and path[-1] == pytest.approx(a)
    # r1 to r5 crosses the corridor: through r1's door and r5's door
    line = LineString(path2)
    for rid in ("r1", "r5"):
        d = building.room(rid).door
        assert line.distance(Point(d.centre)) < d.width_m / 2
    assert LineString(path2).length >= math.dist(a, b)


def test_dead_reckoning_drift_grows_and_scale_error_shows():
    # a straight 100 m walk east, one stride per second
    n = 101
    t = np.arange(n, dtype=np.int64) * 1_000_000_000
    xy = np.stack([np.linspace(0, 100, n), np.zeros(n)], axis=1)
    cfg = TrackConfig(
        initial_heading_sigma_deg=0.0, gyro_bias_sigma_deg_s=0.0, gyro_bias_walk_deg_s_sqrt_s=0.0
    )
    meas, scale, psi0 = dead_reckon(t, xy, np.random.default_rng(3), cfg)
    assert psi0 == 0.0
    assert meas[0] == pytest.approx(xy[0])
    # only the scale error (and 1 cm stride noise) remains
    assert meas[-1, 0] == pytest.approx(100 * (1 + scale), abs=0.2)
    # heading errors: the lateral error grows with the distance walked, on average over many draws
    full = TrackConfig()
    errs = np.array([np.abs(dead_reckon(t, xy, np.random.default_rng(s), full)[0][:, 1]) for s in range(200)])
    mean = errs.mean(axis=0)
    assert mean[10] < mean[50] < mean[100]
    # initial heading sigma 1.5 deg: about 100 m * 1.5 deg * sqrt(2/pi) = 2.1 m lateral error after 100 m
    assert 1.0 < mean[100] < 4.0


def test_survey_track_passes_legs_and_starts_at_you_are_here(building):
    area = walkable_area(building, 0.3)
    t0 = 1_000_000_000_000
    here = np.asarray(building.you_are_here)
    legs = []
    t = t0
    for rid in ("r1", "r3"):
        p = np.asarray(building.room(rid).free_space.representative_point().coords[0])
        t += walk_time_ns(area, here, p) + 2_000_000_000
        leg_t = t + np.arange(3, dtype=np.int64) * 1_000_000_000
        legs.append(TrackLeg(rid, leg_t, np.array([p, p + 0.2, p + 0.4])))
        here, t = p + 0.4, int(leg_t[-1])
    track = survey_track(building, legs, t0, np.random.default_rng(0))
    assert np.all(np.diff(track.t_ns) > 0)
    assert track.xy_true[0] == pytest.approx(here * 0 + np.asarray(building.you_are_here))
    assert track.xy[0] == pytest.approx(track.xy_true[0])
    for leg in legs:
        for tt, p in zip(leg.t_ns, leg.xy, strict=True):
            k = np.flatnonzero(track.t_ns == tt)
            assert len(k) == 1 and track.xy_true[k[0]] == pytest.approx(p)
    # strides are at most a stride long while walking
    steps = np.linalg.norm(np.diff(track.xy_true, axis=0), axis=1)
    assert steps.max() <= TrackConfig().stride_length_m + 1e-6
    with pytest.raises(ValueError, match="before the walk"):
        survey_track(
            building, [TrackLeg("r1", np.array([t0 + 1]), legs[0].xy[:1])], t0, np.random.default_rng(0)
        )


def test_select_rooms_keeps_one_of_each_capture_kind(building):
    kinds = [r.capture for r in select_rooms(building, 2)]
    assert sorted(kinds) == ["hallway", "rgbd", "tls"]
    assert [r.id for r in select_rooms(building, 1)] == ["r1", "hall"]
    assert [r.id for r in select_rooms(building, None)] == ["r1", "r2", "r3", "r4", "r5", "hall"]
    with pytest.raises(ValueError, match=r"must be within 1\.\.5"):
        select_rooms(building, 6)


def _hashes(folder):
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def small_survey(tmp_path_factory):
    a = generate_survey(tmp_path_factory.mktemp("a") / "survey", seed=5, rooms=2, cfg=SMALL)
    b = generate_survey(tmp_path_factory.mktemp("b") / "survey", seed=5, rooms=2, cfg=SMALL)
    return a, b


@pytest.mark.slow
def test_same_seed_gives_byte_identical_files(small_survey):
    a, b = small_survey
    ha, hb = _hashes(a), _hashes(b)
    assert len(ha) > 30
    assert ha == hb


def test_existing_output_is_kept_unless_overwrite(tmp_path):
    out = tmp_path / "survey"
    (out / "truth" / "poses").mkdir(parents=True)
    (out / "truth" / "poses" / "stale.parquet").write_bytes(b"x")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not empty"):
        generate_survey(out, seed=5, rooms=1, profile="tls", cfg=SMALL)
    generate_survey(out, seed=5, rooms=1, profile="tls", cfg=SMALL, overwrite=True)
    assert sorted(p.name for p in (out / "rooms").iterdir()) == ["hall", "r1"]
    assert not (out / "truth" / "poses" / "stale.parquet").exists()
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "rooms" / "r1" / "cloud.ply").is_file()  # every room is scanned with profile tls


@pytest.mark.slow
def test_small_survey_end_to_end(small_survey):
    root, _ = small_survey
    survey = load_survey(root)
    assert survey.sensor == "kinect_v1"
    assert survey.room_ids == ["r1", "r5", "hall"]
    doc = yaml.safe_load((root / "survey.yaml").read_text())
    assert doc["plan"] == {"image": "plan/plan.png", "m_per_px": 0.02}
    assert (root / "plan" / "plan.png").is_file()
    b = generate_building(5)
    # captures: ROS 2 messages on the profile's topics, mini size, one CameraInfo per stream
    prof = load_sensor_profile("kinect_v1")
    topics = prof["topics"]
    counts: dict[str, int] = {}
    with open(root / "rooms" / "r1" / "capture.mcap", "rb") as f:
        for _schema, channel, message, ros in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == topics["depth"]:
                assert ros.encoding == "16UC1" and (ros.width, ros.height) == (320, 240)
                depth = np.frombuffer(bytes(ros.data), dtype="<u2")
                assert (depth > 0).mean() > 0.3 and depth.max() < 7000
            if channel.topic == topics["rgb_compressed"]:
                assert ros.format == "jpeg"
            assert message.log_time > 0
    assert counts[topics["rgb_compressed"]] == counts[topics["depth"]] == SMALL.frames_mini
    assert counts[topics["rgb_info"]] == counts[topics["depth_info"]] == 1
    # the TLS room: a registered cloud around its stations, millimetre noise on flat walls
    cloud = read_cloud(root / "rooms" / "r5" / "cloud.ply")
    assert len(cloud.points) > 5000 and cloud.colors is not None
    fx0, _, _, fy1 = b.footprint.bounds
    assert (cloud.points[:, 0] > fx0 - 0.01).all() and (cloud.points[:, 1] < fy1 + 0.01).all()
    # truth schemas
    walls = read_table(root / "truth" / "walls.parquet")
    assert walls.schema.names == ["x0", "y0", "x1", "y1", "room_id"]
    assert all(walls.schema.field(c).type == pa.float64() for c in ("x0", "y0", "x1", "y1"))
    assert set(walls["room_id"].to_pylist()) == {"r1", "r5", "hall"}
    geo = json.loads((root / "truth" / "walls.geojson").read_text())
    assert len(geo["features"]) == walls.num_rows
    plan_walls = read_table(root / "truth" / "plan_walls.parquet")
    assert plan_walls.schema.names == ["x0", "y0", "x1", "y1", "thickness_m"]
    assert plan_walls.num_rows == len(b.built_walls)
    changes = read_table(root / "truth" / "changes.parquet")
    assert changes.schema.names == ["x0", "y0", "x1", "y1", "kind", "room_id"]
    assert set(changes["kind"].to_pylist()) == {"added", "removed"}
    rooms = json.loads((root / "truth" / "rooms.geojson").read_text())
    props = {f["properties"]["room_id"]: f["properties"] for f in rooms["features"]}
    assert all(f["geometry"]["type"] == "Polygon" for f in rooms["features"])
    assert 2.5 <= props["r1"]["height_m"] <= 3.2 and props["r1"]["plan_room"] == "101"
    poses = read_table(root / "truth" / "poses" / "r1.parquet")
    for c in ("t_ns", "qw", "qx", "qy", "qz", "tx", "ty", "tz"):
        assert c in poses.schema.names
    q = np.column_stack([poses[c].to_numpy() for c in ("qw", "qx", "qy", "qz")])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert poses.num_rows == SMALL.frames_mini
    assert b.room("r1").polygon.buffer(-0.4).contains(Point(poses["tx"][0].as_py(), poses["ty"][0].as_py()))
    stations = read_table(root / "truth" / "poses" / "r5.parquet")
    assert stations.num_rows == SMALL.tls_stations and set(stations["method"].to_pylist()) == {"tls_station"}
    calib = json.loads((root / "truth" / "calibration.json").read_text())
    assert {"ir", "rgb", "ir_to_rgb", "stereo_rms_px", "depth_model"} <= set(calib)
    assert calib["ir"]["size"] == [320, 240]
    assert len(list((root / "calibration" / "ir").glob("*.png"))) >= 8
    # the track: from "you are here", strictly increasing time, through every capture start
    track = np.loadtxt(root / "track" / "track.csv", delimiter=",", skiprows=1)
    assert (root / "track" / "track.csv").read_text().splitlines()[0] == "t_ns,x,y"
    t = np.array(
        [int(line.split(",")[0]) for line in (root / "track" / "track.csv").read_text().splitlines()[1:]]
    )
    assert np.all(np.diff(t) > 0)
    assert track[0, 1:] == pytest.approx(b.you_are_here, abs=1e-4)
    assert int(poses["t_ns"][0].as_py()) in set(t.tolist())
    assert (root / "truth" / "overview.png").stat().st_size > 10_000
