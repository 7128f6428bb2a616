import numpy as np
import pytest

from tasks import artefacts as art
from tasks.artefacts import ArtefactStore, atomic_path, check_room_id
from tasks.cloud import DegenerateInputError


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "a.json"
    art.write_json(target, {"v": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert art.read_json(target) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_commit_is_all_or_nothing_and_lookup_verifies(tmp_path):
    store = ArtefactStore(tmp_path)
    key = store.cache_key("s", "v1", {"a": 1}, {"in": "x"})

    def failing(out):
        (out / "half.bin").write_bytes(b"x")
        raise RuntimeError("crash")

    with pytest.raises(RuntimeError):
        store.commit("r1", "s", key, failing, {})
    assert store.lookup("r1", "s", key) is None
    assert not any(p.name.startswith(".tmp") for p in store.stage_root("r1", "s").iterdir())

    result = store.commit("r1", "s", key, lambda out: (out / "a.bin").write_bytes(b"abc") and None, {})
    assert store.lookup("r1", "s", key) == result
    (result.file("a.bin")).write_bytes(b"abd")  # corrupted behind the store's back
    assert store.lookup("r1", "s", key) is None
    result.file("a.bin").unlink()
    assert store.lookup("r1", "s", key) is None


def test_cache_key_depends_on_content_config_and_code():
    base = ArtefactStore.cache_key("s", "v1", {"a": 1}, {"in": "h1"})
    assert base == ArtefactStore.cache_key("s", "v1", {"a": 1}, {"in": "h1"})
    assert base != ArtefactStore.cache_key("s", "v2", {"a": 1}, {"in": "h1"})
    assert base != ArtefactStore.cache_key("s", "v1", {"a": 2}, {"in": "h1"})
    assert base != ArtefactStore.cache_key("s", "v1", {"a": 1}, {"in": "h2"})


@pytest.mark.parametrize("bad", ["../x", "a/b", "..", ".hidden", "", "a b", "_building", 3, "r5\n", "r5\r"])
def test_room_ids_never_escape(bad):
    with pytest.raises(ValueError, match="not a plain name"):
        check_room_id(bad)
    assert check_room_id("room-1.a_b") == "room-1.a_b"


def test_input_hash_follows_content(tmp_path):
    store = ArtefactStore(tmp_path / "w")
    f = tmp_path / "c.bin"
    f.write_bytes(b"one")
    h1 = store.input_hash(f)
    f.write_bytes(b"two!")
    assert store.input_hash(f) != h1


def test_ply_round_trip_and_bad_clouds(tmp_path, rng):
    pts = rng.normal(size=(50, 3))
    cols = rng.integers(0, 255, (50, 3)).astype(np.uint8)
    art.write_ply_points(tmp_path / "a.ply", pts, cols)
    cloud = art.read_cloud(tmp_path / "a.ply")
    np.testing.assert_allclose(cloud.points, pts)
    np.testing.assert_array_equal(cloud.colors, cols)

    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(DegenerateInputError, match=r"empty\.ply: empty file"):
        art.read_cloud(tmp_path / "empty.ply")
    art.write_ply_points(tmp_path / "none.ply", np.zeros((0, 3)))
    with pytest.raises(DegenerateInputError, match=r"none\.ply: the cloud has no points"):
        art.read_cloud(tmp_path / "none.ply")
    pts[3] = np.nan
    art.write_ply_points(tmp_path / "nan.ply", pts)
    with pytest.raises(DegenerateInputError, match=r"nan\.ply: 1 of 50 points are NaN"):
        art.read_cloud(tmp_path / "nan.ply")


def _open3d_cloud(path):
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    colours = None
    if pcd.has_colors():
        colours = np.clip(np.asarray(pcd.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return np.asarray(pcd.points), colours


@pytest.mark.parametrize(
    ("name", "options"),
    [
        ("ascii.ply", {"write_ascii": True}),
        ("binary.ply", {}),
        ("ascii.pcd", {"write_ascii": True}),
        ("binary.pcd", {}),
        ("compressed.pcd", {"compressed": True}),
    ],
)
def test_valid_clouds_read_exactly_as_open3d_reads_them(tmp_path, rng, name, options):
    """The checked reader changes no valid cloud: the same float64 points and uint8 colours as Open3D."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rng.uniform(-3, 3, (500, 3))))
    pcd.colors = o3d.utility.Vector3dVector(rng.uniform(0, 1, (500, 3)))
    o3d.io.write_point_cloud(str(tmp_path / name), pcd, **options)
    cloud = art.read_cloud(tmp_path / name)
    points, colours = _open3d_cloud(tmp_path / name)
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.colors, colours)


def test_big_endian_ply_and_a_mesh_ply(tmp_path, rng):
    pts = rng.uniform(0, 4, (300, 3))
    rec = np.empty(300, dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("nx", ">f4"), ("red", "u1")])
    rec["x"], rec["y"], rec["z"], rec["red"] = pts[:, 0], pts[:, 1], pts[:, 2], 7
    head = "ply\nformat binary_big_endian 1.0\nelement vertex 300\n" + "".join(
        f"property float {n}\n" for n in ("x", "y", "z", "nx")
    )
    (tmp_path / "be.ply").write_bytes((head + "property uchar red\nend_header\n").encode() + rec.tobytes())
    cloud = art.read_cloud(tmp_path / "be.ply")
    np.testing.assert_allclose(cloud.points, pts, atol=1e-6)
    assert cloud.colors is None  # red alone is no colour (as for Open3D)
    # a mesh: the faces (a list property) after the vertices are skipped, the vertices read
    art.write_ply_mesh(tmp_path / "mesh.ply", pts, np.array([[0, 1, 2], [2, 3, 4]]))
    np.testing.assert_array_equal(art.read_cloud(tmp_path / "mesh.ply").points, pts)


def test_ascii_values_are_checked_against_their_type(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
    head += "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    (tmp_path / "ok.ply").write_text(head + "1 2 3 255 0 9\n4 5 6 1 2 3\n\n")
    np.testing.assert_array_equal(art.read_cloud(tmp_path / "ok.ply").colors, [[255, 0, 9], [1, 2, 3]])
    (tmp_path / "over.ply").write_text(head + "1 2 3 300 0 9\n4 5 6 1 2 3\n")
    with pytest.raises(
        art.ArtefactError, match=r"over\.ply: line 11: .*whole number in its property's range"
    ):
        art.read_cloud(tmp_path / "over.ply")
    (tmp_path / "more.ply").write_text(head + "1 2 3 1 0 9\n4 5 6 1 2 3\n7 8 9 1 1 1\n")
    with pytest.raises(
        art.ArtefactError, match=r"more\.ply: data after the header's last record \(line 13\)"
    ):
        art.read_cloud(tmp_path / "more.ply")


def test_binary_sizes_must_account_for_the_file(tmp_path, rng):
    art.write_ply_points(tmp_path / "a.ply", rng.normal(size=(100, 3)))
    data = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-1])
    with pytest.raises(art.ArtefactError, match=r"cut\.ply: 2399 bytes follow the header, .*need 2400"):
        art.read_cloud(tmp_path / "cut.ply")
    (tmp_path / "long.ply").write_bytes(data + b"\n")
    with pytest.raises(art.ArtefactError, match="longer than its header says"):
        art.read_cloud(tmp_path / "long.ply")


def test_input_hash_sees_a_replacement_of_the_same_size_and_mtime(tmp_path, monkeypatch):
    """Issue #21 item 2: `cp -p`, `rsync -t` or bytes fixed in place with the time set back leave size and
    mtime as they were; the ctime in the memo's key still tells."""
    import os
    import time

    store = ArtefactStore(tmp_path / "w")
    monkeypatch.setattr(ArtefactStore, "RACY_SECONDS", -1e9)  # trust every entry: only the key tells
    capture = tmp_path / "c.bin"
    capture.write_bytes(b"good capture")
    first = store.input_hash(capture)
    stat = capture.stat()
    time.sleep(0.05)  # past the file system's clock tick
    capture.write_bytes(b"evil capture")
    os.utime(capture, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert (capture.stat().st_size, capture.stat().st_mtime_ns) == (stat.st_size, stat.st_mtime_ns)
    assert store.input_hash(capture) != first
    store.save_memo()
    assert ArtefactStore(tmp_path / "w").input_hash(capture) == art.sha256_file(capture)


def test_a_file_changed_just_before_it_was_hashed_is_hashed_again(tmp_path, monkeypatch):
    store = ArtefactStore(tmp_path / "w")
    capture = tmp_path / "c.bin"
    capture.write_bytes(b"x")
    store.input_hash(capture)
    calls = []
    monkeypatch.setattr(art, "sha256_file", lambda p: calls.append(p) or "h")
    store.input_hash(capture)  # written a moment ago: a change in the same clock tick is invisible
    assert calls


def test_a_work_dir_inside_an_input_folder_is_not_part_of_it(tmp_path):
    """Issue #21 item 13: a work dir inside calibration/ made every rerun recompute calibration."""
    folder = tmp_path / "calibration"
    (folder / "ir").mkdir(parents=True)
    (folder / "ir" / "00.png").write_bytes(b"png")
    store = ArtefactStore(folder / "work")
    before = store.input_hash(folder)
    (folder / "work" / "cache").mkdir(parents=True)
    (folder / "work" / "cache" / "x.json").write_text("{}")
    assert store.input_hash(folder) == before
    (folder / "ir" / "01.png").write_bytes(b"png")
    assert store.input_hash(folder) != before


def test_a_read_only_store_writes_no_memo(tmp_path):
    store = ArtefactStore(tmp_path / "w")
    (tmp_path / "c.bin").write_bytes(b"x")
    store.read_only = True
    store.input_hash(tmp_path / "c.bin")
    store.save_memo()
    assert not (tmp_path / "w").exists()


def test_a_stage_failure_is_one_line_naming_room_stage_and_inputs(tmp_path, monkeypatch):
    store = ArtefactStore(tmp_path)
    manifest = {"raw_inputs": {"capture": {"path": "/s/rooms/r5/cloud.ply"}}, "inputs": {"ingest": "h"}}

    def crash(out):
        np.zeros(3)[[5]]  # an IndexError deep in a stage

    monkeypatch.delenv(art.DEBUG_VARIABLE, raising=False)
    with pytest.raises(art.StageError) as caught:
        store.commit("r5", "preprocess", "k" * 64, crash, manifest)
    message = str(caught.value)
    assert (caught.value.room, caught.value.stage) == ("r5", "preprocess")
    assert "unexpected IndexError" in message and "capture /s/rooms/r5/cloud.ply" in message
    assert "ingest result" in message and f"{art.DEBUG_VARIABLE}=1" in message and "\n" not in message

    def refuse(out):
        raise DegenerateInputError("/s/rooms/r5/cloud.ply: empty file")

    with pytest.raises(DegenerateInputError, match="empty file"):  # a checked input error passes as it is
        store.commit("r5", "ingest", "k" * 64, refuse, manifest)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ({"type": "FeatureCollection"}, "no 'features' list"),
        ({"features": [5]}, r"features\[0\] is not a GeoJSON Feature"),
        ({"features": [{"geometry": 5}]}, r"features\[0\].geometry is not a GeoJSON geometry"),
        ({"features": [{"geometry": {"type": "LineString", "coordinates": [[0, "a"], [1, 1]]}}]}, "numbers"),
    ],
)
def test_malformed_geojson_walls_name_the_file(tmp_path, content, message):
    import json

    (tmp_path / "w.geojson").write_text(json.dumps(content))
    with pytest.raises(art.ArtefactError, match=rf"w\.geojson: .*{message}"):
        art.read_segments(tmp_path / "w.geojson")


@pytest.mark.parametrize("ascii_body", [False, True])
def test_reading_a_cloud_takes_at_most_twice_its_size(tmp_path, rng, ascii_body):
    """Memory follows the file's real size: the cloud itself plus a bounded slice."""
    import tracemalloc

    pts = rng.uniform(0, 4, (200_000 if not ascii_body else 60_000, 3))
    cols = rng.integers(0, 255, (len(pts), 3)).astype(np.uint8)
    path = art.write_ply_points(tmp_path / "a.ply", pts, cols)
    if ascii_body:
        head = "ply\nformat ascii 1.0\nelement vertex 60000\nproperty double x\nproperty double y\n"
        head += (
            "property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
        )
        rows = "".join(
            f"{x!r} {y!r} {z!r} {r} {g} {b}\n"
            for (x, y, z), (r, g, b) in zip(pts.tolist(), cols.tolist(), strict=True)
        )
        path.write_text(head + rows)
    tracemalloc.start()
    try:
        cloud = art.read_cloud(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.colors, cols)
    justified = cloud.points.nbytes + cloud.colors.nbytes
    slice_bytes = 6 << 20 if ascii_body else 1 << 20  # one slice of parsed lines, whatever the size
    assert peak < 2 * max(justified, path.stat().st_size) + slice_bytes, (peak, justified)
