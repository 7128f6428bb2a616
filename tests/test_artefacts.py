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


@pytest.mark.parametrize("bad", ["../x", "a/b", "..", ".hidden", "", "a b", "_building", 3])
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
