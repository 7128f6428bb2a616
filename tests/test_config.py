from pathlib import Path

import pytest
import yaml

from tasks import config as cfgmod
from tasks.config import ConfigError, load_config, load_survey, parse_set
from tests.captures import write_survey


def _leaves(data: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(_leaves(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_code_defaults_are_the_production_values_of_default_yaml():
    """configs/default.yaml documents values (thesis table 6.3 with its selection criteria); the dataclass
    defaults are what runs, so the unit tests run the pipeline's configuration: every key must agree."""
    data = yaml.safe_load(cfgmod.DEFAULT_YAML.read_text())
    assert set(data) <= {"flow", *cfgmod.STAGE_SECTIONS}
    code = cfgmod.to_yaml(cfgmod.PipelineConfig())
    defaults = _leaves(yaml.safe_load(code))
    for key, value in _leaves(data).items():
        assert key in defaults, key
        assert defaults[key] == value, f"{key}: code default {defaults[key]!r}, default.yaml {value!r}"
    cfg = load_config()
    assert cfg.preprocess.outlier_neighbours == 20  # thesis table 6.3
    assert cfg.preprocess.slice_min_m == 1.5 and cfg.preprocess.slice_max_m == 2.5


def test_config_sections_come_from_the_stage_table():
    from tasks.stages import STAGES, config_sections

    assert list(cfgmod.STAGE_SECTIONS) == list(config_sections())
    for stage in STAGES.values():
        assert stage.name in cfgmod.STAGE_SECTIONS


def test_set_overrides_file_overrides_default(tmp_path):
    override = tmp_path / "o.yaml"
    override.write_text("preprocess:\n  voxel_size_m: 0.04\n  mls_radius_m: 0.2\n")
    cfg = load_config([override], ["preprocess.voxel_size_m=0.03"])
    assert cfg.preprocess.voxel_size_m == 0.03
    assert cfg.preprocess.mls_radius_m == 0.2


def test_unknown_key_names_file_and_key(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("preprocess:\n  voxl_size_m: 0.03\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*preprocess\.voxl_size_m"):
        load_config([bad])
    with pytest.raises(ConfigError, match=r"--set preprocess\.nope=1.*preprocess\.nope"):
        load_config([], ["preprocess.nope=1"])
    with pytest.raises(ConfigError, match="unknown section 'prepro'"):
        load_config([], ["prepro.voxel_size_m=1"])


def test_wrong_types_and_malformed_set():
    with pytest.raises(ConfigError, match="expected a number"):
        load_config([], ["preprocess.voxel_size_m=abc"])
    with pytest.raises(ConfigError, match=r"expected stage\.key=value"):
        parse_set("voxel_size_m")
    assert parse_set("a.b=[1, 2]") == {"a": {"b": [1, 2]}}


def test_resolved_config_round_trips():
    cfg = load_config([], ["preprocess.voxel_size_m=0.05"])
    text = cfgmod.to_yaml(cfg)
    assert yaml.safe_load(text)["preprocess"]["voxel_size_m"] == 0.05


def test_sensor_profiles_present():
    assert {"kinect_v1", "kinect_v2", "realsense_d435", "tls"} <= set(cfgmod.sensor_profiles())
    k1 = cfgmod.load_sensor_profile("kinect_v1")
    assert k1["ir"]["K"][0][0] == pytest.approx(585.7)  # thesis table 6.1
    with pytest.raises(ConfigError, match="unknown sensor profile 'nope'"):
        cfgmod.load_sensor_profile("nope")


def test_survey_loads(tmp_path):
    root = write_survey(tmp_path / "s", {"a": "rooms/a.ply"}, plan={"image": "plan/p.png", "m_per_px": 0.02})
    survey = load_survey(root)
    assert survey.room_ids == ["a"]
    assert survey.rooms[0].capture == root / "rooms" / "a.ply"
    assert survey.plan.m_per_px == 0.02


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("rooms: [a, b", "survey.yaml: line"),  # malformed YAML
        ("- just a list", "expected a mapping"),
        ("name: x\nrooms: []", "non-empty list"),
        ("rooms:\n - {id: a, capture: a.ply}\n - {id: a, capture: b.ply}", "duplicate room id 'a'"),
        ("rooms:\n - {id: ../x, capture: a.ply}", "room id '../x' is not a plain name"),
        ("rooms:\n - {id: a/b, capture: a.ply}", "room id 'a/b' is not a plain name"),
        ("rooms:\n - {id: a}", r"rooms\[0\] needs 'id' and 'capture'"),
        ("sensor: kinect_v9\nrooms:\n - {id: a, capture: a.ply}", "unknown sensor profile 'kinect_v9'"),
        ("roms: []", "unknown key 'roms'"),
        ("rooms:\n - {id: a, capture: a.ply}\nplan: {image: p.png, m_per_px: 20}", "implausible"),
        ('rooms:\n - {id: "a\\n", capture: a.ply}', r"rooms\[0\]: room id 'a\\n' is not a plain name"),
        (
            "rooms:\n - {id: a, capture: a.ply}\nplan: {image: p.png, known_distance: [a, 0, 9, 0, 1]}",
            r"plan\.known_distance must be five numbers",
        ),
        (
            "rooms:\n - {id: a, capture: a.ply}\nplan: {image: p.png, known_distance: [0, 0, 0, 0, 1]}",
            r"plan\.known_distance needs two different pixels",
        ),
        (
            "rooms:\n - {id: a, capture: a.ply}\nplan: {image: p.png, outline_length_m: long}",
            r"plan\.outline_length_m must be .*a positive number\), got 'long'",
        ),
        ("rooms:\n - {id: a, capture: a.ply}\nplan: {image: p.png, m_per_px: true}", "implausible"),
    ],
)
def test_bad_surveys_give_one_line_naming_the_file(tmp_path, content, message):
    (tmp_path / "survey.yaml").write_text(content)
    with pytest.raises(ConfigError, match=message) as err:
        load_survey(tmp_path)
    text = str(err.value)
    assert "\n" not in text
    assert str(Path(tmp_path) / "survey.yaml") in text


def test_binary_files_are_named(tmp_path):
    (tmp_path / "survey.yaml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    with pytest.raises(ConfigError, match=r"survey\.yaml: not a YAML text file"):
        load_survey(tmp_path)
    (tmp_path / "nul.yaml").write_bytes(b"preprocess:\x00\n")
    with pytest.raises(ConfigError, match=r"nul\.yaml: not a YAML text file \(it holds NUL bytes\)"):
        load_config([tmp_path / "nul.yaml"])


def test_exponent_floats_are_numbers(tmp_path):
    """YAML 1.1 reads 1e-3 as text (it wants 1.0e-3): --set x=1e-3 was refused."""
    assert load_config([], ["preprocess.voxel_size_m=1e-3"]).preprocess.voxel_size_m == 0.001
    (tmp_path / "o.yaml").write_text("preprocess:\n  voxel_size_m: 2e-2\n")
    assert load_config([tmp_path / "o.yaml"]).preprocess.voxel_size_m == 0.02
    assert parse_set("a.b=1e3") == {"a": {"b": 1000.0}} and parse_set("a.b=x1e3") == {"a": {"b": "x1e3"}}


def test_a_sections_own_check_names_the_key_and_the_source(tmp_path):
    with pytest.raises(ConfigError, match=r"^--set ingest\.max_frames=-5: ingest\.max_frames must be 0"):
        load_config([], ["ingest.max_frames=-5"])
    (tmp_path / "o.yaml").write_text("ingest:\n  frame_stride: 0\n")
    with pytest.raises(ConfigError, match=r"o\.yaml: ingest\.frame_stride must be 1 or more"):
        load_config([tmp_path / "o.yaml"])


def test_inputs_outside_the_survey_folder_are_listed(tmp_path):
    outside = tmp_path / "elsewhere.ply"
    outside.write_bytes(b"")
    root = write_survey(
        tmp_path / "s",
        {"in": "rooms/a.ply", "up": "../elsewhere.ply", "abs": str(outside), "link": "rooms/link.ply"},
    )
    (root / "rooms").mkdir()
    (root / "rooms" / "link.ply").symlink_to(outside)
    found = load_survey(root).outside_inputs()
    assert [what for what, _ in found] == ["room up: capture", "room abs: capture", "room link: capture"]
    assert {path for _, path in found} == {outside.resolve()}
