"""One typed config tree: defaults in code <- configs/default.yaml <- --config FILE <- --set stage.key=value.

Each stage owns a frozen dataclass (defined beside its code) with a one-line doc per field; this module
assembles them and merges overrides strictly: an unknown section or key is an error naming the file (or
the --set argument), and a value of the wrong type too. The survey description (survey.yaml) is read here
as well, since its errors must be as clear as the config's.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tasks.artefacts import check_room_id
from tasks.stages import config_sections, load_class

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
DEFAULT_YAML = CONFIG_DIR / "default.yaml"
SENSOR_DIR = CONFIG_DIR / "sensors"


class ConfigError(ValueError):
    """A config or survey file that cannot be used; one line naming the file or key."""


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader reading floats as YAML 1.2 does: `1e-3` is a number (YAML 1.1 wants `1.0e-3`
    and reads `1e-3` as text, which a config value of type float then refuses)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def _yaml(text: str) -> Any:
    return yaml.load(text, Loader=_Loader)  # a SafeLoader: no arbitrary objects


@dataclass(frozen=True)
class FlowConfig:
    """How the flows run (not part of any stage's cache key)."""

    max_workers: int = 2
    """Stage runs (of different rooms) processed at once by the thread-pool task runner."""


def _pipeline_config_class() -> type:
    """The whole configuration: `flow`, then one section per config section of the stage table (a
    stage's own, and the extra ones a stage reads), each the stage's frozen dataclass."""
    fields: list[tuple[str, type, Any]] = [("flow", FlowConfig, field(default_factory=FlowConfig))]
    for name, target in config_sections().items():
        cls = load_class(target)
        fields.append((name, cls, field(default_factory=cls)))
    cls = dataclasses.make_dataclass("PipelineConfig", fields, frozen=True)
    cls.__module__ = __name__  # picklable as tasks.config.PipelineConfig
    return cls


PipelineConfig = _pipeline_config_class()

STAGE_SECTIONS = tuple(f.name for f in dataclasses.fields(PipelineConfig) if f.name != "flow")


# --------------------------------------------------------------------------------------------- building


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    """`value` checked against a field's annotation (after `from __future__ import annotations`, the
    annotation may be a string: resolved by the caller)."""
    origin = typing.get_origin(annotation)
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {type(value).__name__}")
        return _build(annotation, value, where)
    if origin in (typing.Union, types.UnionType):
        errors = []
        for arg in typing.get_args(annotation):
            if arg is type(None) and value is None:
                return None
            try:
                return _coerce(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is typing.Literal:
        if value not in typing.get_args(annotation):
            raise ConfigError(f"{where}: {value!r} is not one of {list(typing.get_args(annotation))}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(annotation)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
            items = [_coerce(v, a, where) for v, a in zip(value, args, strict=True)]
        else:
            inner = args[0] if args else Any
            items = [_coerce(v, inner, where) for v in value]
        return tuple(items) if origin is tuple else items
    if origin is dict or annotation is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}")
        return dict(value)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected a whole number, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected text, got {value!r}")
        return value
    return value


def _build(cls: type, data: dict[str, Any], where: str, base: Any = None) -> Any:
    """An instance of dataclass `cls` from `base` (or the defaults) updated by `data`, strictly."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"unknown key {'.'.join(filter(None, [where, unknown[0]]))!r}")
    current = base if base is not None else cls()
    updates = {}
    for name, value in data.items():
        sub_where = f"{where}.{name}" if where else name
        if dataclasses.is_dataclass(hints[name]) and isinstance(value, dict):
            updates[name] = _build(hints[name], value, sub_where, getattr(current, name))
        else:
            updates[name] = _coerce(value, hints[name], sub_where)
    try:
        return dataclasses.replace(current, **updates)
    except (ValueError, TypeError) as exc:  # a section's own check of its values (__post_init__)
        message = " ".join(str(exc).split())
        raise ConfigError(message if where and message.startswith(where) else f"{where}: {message}") from None


def _merge_layer(cfg: PipelineConfig, layer: dict[str, Any], source: str) -> PipelineConfig:
    if not isinstance(layer, dict):
        raise ConfigError(f"{source}: expected a mapping of sections, got {type(layer).__name__}")
    for section in layer:
        if section not in {f.name for f in dataclasses.fields(PipelineConfig)}:
            raise ConfigError(
                f"{source}: unknown section {section!r} (known: flow, {', '.join(STAGE_SECTIONS)})"
            )
    updates = {}
    for section, values in layer.items():
        if values is None:
            continue
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: section {section!r} must be a mapping")
        try:
            updates[section] = _build(type(getattr(cfg, section)), values, section, getattr(cfg, section))
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    return dataclasses.replace(cfg, **updates)


def read_yaml(path: Path) -> Any:
    """A YAML file's content; a one-line error naming the file when it is missing or malformed."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a YAML text file (byte {exc.start} is not UTF-8)") from None
    if "\x00" in text:
        raise ConfigError(f"{path}: not a YAML text file (it holds NUL bytes)")
    try:
        return _yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or "malformed YAML"
        raise ConfigError(f"{path}:{where} {problem}") from exc


def parse_set(item: str) -> dict[str, Any]:
    """`stage.key=value` (value in YAML syntax: 0.03, true, [1, 2]) as a nested mapping."""
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected stage.key=value")
    dotted, raw = item.split("=", 1)
    keys = dotted.strip().split(".")
    if len(keys) < 2 or not all(keys):
        raise ConfigError(f"--set {item!r}: expected stage.key=value")
    try:
        value = _yaml(raw) if raw.strip() else ""
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: value is not valid YAML") from exc
    nested: dict[str, Any] = {keys[-1]: value}
    for key in reversed(keys[:-1]):
        nested = {key: nested}
    return nested


def load_config(
    files: list[Path] | tuple[Path, ...] = (), sets: list[str] | tuple[str, ...] = ()
) -> PipelineConfig:
    """Defaults <- configs/default.yaml <- each file <- each --set, strictly merged."""
    cfg = PipelineConfig()
    if DEFAULT_YAML.is_file():
        cfg = _merge_layer(cfg, read_yaml(DEFAULT_YAML) or {}, str(DEFAULT_YAML))
    for path in files:
        cfg = _merge_layer(cfg, read_yaml(path) or {}, str(path))
    for item in sets:
        cfg = _merge_layer(cfg, parse_set(item), f"--set {item}")
    return cfg


def section(cfg: PipelineConfig, name: str) -> dict[str, Any]:
    """A section as plain data (what a stage's cache key hashes and its manifest records)."""
    return dataclasses.asdict(getattr(cfg, name))


def to_yaml(cfg: PipelineConfig) -> str:
    """The resolved config as YAML, saved with every run."""
    return yaml.safe_dump(_plain(dataclasses.asdict(cfg)), sort_keys=False)


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    return obj


# -------------------------------------------------------------------------------------------- sensors


def sensor_profiles() -> list[str]:
    return sorted(p.stem for p in SENSOR_DIR.glob("*.yaml"))


def load_sensor_profile(name: str) -> dict[str, Any]:
    """A sensor profile from configs/sensors/<name>.yaml as plain data."""
    path = SENSOR_DIR / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown sensor profile {name!r} (known: {', '.join(sensor_profiles())})")
    data = read_yaml(path)
    if not isinstance(data, dict) or "kind" not in data:
        raise ConfigError(f"{path}: a sensor profile needs at least 'name' and 'kind'")
    return data


# --------------------------------------------------------------------------------------------- surveys


@dataclass(frozen=True)
class RoomSpec:
    id: str
    capture: Path
    plan_room: str | None = None


@dataclass(frozen=True)
class PlanSpec:
    image: Path
    m_per_px: float | None = None
    known_distance: tuple[float, float, float, float, float] | None = None
    outline_length_m: float | None = None


@dataclass(frozen=True)
class Survey:
    """A survey folder's description (survey.yaml), paths resolved against the folder."""

    root: Path
    name: str
    sensor: str
    rooms: tuple[RoomSpec, ...]
    plan: PlanSpec | None = None
    calibration: Path | None = None
    track: Path | None = None
    truth: Path | None = None

    def room(self, room_id: str) -> RoomSpec:
        for room in self.rooms:
            if room.id == room_id:
                return room
        raise ConfigError(
            f"{self.root / 'survey.yaml'}: no room {room_id!r} (rooms: {', '.join(self.room_ids)})"
        )

    @property
    def room_ids(self) -> list[str]:
        return [r.id for r in self.rooms]

    def outside_inputs(self) -> list[tuple[str, Path]]:
        """(what, resolved path) of every input that lies outside the survey folder (`../`, an absolute
        path, or a symbolic link out of it): allowed, but a run says so."""
        root = self.root.resolve()
        given = [(f"room {r.id}: capture", r.capture) for r in self.rooms]
        given += [("plan image", self.plan.image)] if self.plan is not None else []
        given += [(name, p) for name, p in (("calibration", self.calibration), ("track", self.track)) if p]
        return [(what, p.resolve()) for what, p in given if not p.resolve().is_relative_to(root)]


_SURVEY_KEYS = {"name", "sensor", "plan", "calibration", "track", "rooms", "truth", "description"}


def load_survey(folder: Path) -> Survey:
    """Read and check `folder/survey.yaml`; every problem is one line naming the file and the key."""
    folder = Path(folder).resolve()
    path = folder / "survey.yaml" if folder.is_dir() else folder
    if path.name == "survey.yaml" and path.parent != folder:
        folder = path.parent
    if not path.is_file():
        raise ConfigError(f"{path}: no survey.yaml in {folder}")
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping with name, sensor and rooms")
    unknown = sorted(set(data) - _SURVEY_KEYS)
    if unknown:
        raise ConfigError(f"{path}: unknown key {unknown[0]!r} (known: {', '.join(sorted(_SURVEY_KEYS))})")
    sensor = data.get("sensor", "kinect_v1")
    if not isinstance(sensor, str):
        raise ConfigError(f"{path}: 'sensor' must be a profile name")
    try:
        load_sensor_profile(sensor)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    rooms_data = data.get("rooms")
    if not isinstance(rooms_data, list) or not rooms_data:
        raise ConfigError(f"{path}: 'rooms' must be a non-empty list of {{id, capture}}")
    rooms, seen = [], set()
    for index, item in enumerate(rooms_data):
        if not isinstance(item, dict) or "id" not in item or "capture" not in item:
            raise ConfigError(f"{path}: rooms[{index}] needs 'id' and 'capture'")
        extra = sorted(set(item) - {"id", "capture", "plan_room"})
        if extra:
            raise ConfigError(f"{path}: rooms[{index}] has unknown key {extra[0]!r}")
        try:
            room_id = check_room_id(str(item["id"]) if isinstance(item["id"], int) else item["id"])
        except ValueError as exc:
            raise ConfigError(f"{path}: rooms[{index}]: {exc}") from None
        if room_id in seen:
            raise ConfigError(f"{path}: duplicate room id {room_id!r}")
        seen.add(room_id)
        plan_room = item.get("plan_room")
        rooms.append(
            RoomSpec(room_id, folder / str(item["capture"]), None if plan_room is None else str(plan_room))
        )
    plan = None
    if data.get("plan") is not None:
        plan = _plan_spec(data["plan"], folder, path)

    def optional_path(key: str) -> Path | None:
        value = data.get(key)
        if value is None:
            return None
        if not isinstance(value, str):
            raise ConfigError(f"{path}: {key!r} must be a path relative to the survey")
        return folder / value

    return Survey(
        root=folder,
        name=str(data.get("name", folder.name)),
        sensor=sensor,
        rooms=tuple(rooms),
        plan=plan,
        calibration=optional_path("calibration"),
        track=optional_path("track"),
        truth=optional_path("truth"),
    )


def _plan_spec(data: Any, folder: Path, path: Path) -> PlanSpec:
    if not isinstance(data, dict) or "image" not in data:
        raise ConfigError(
            f"{path}: 'plan' needs 'image' (and at most one scale: m_per_px, known_distance, outline_length_m)"
        )
    extra = sorted(set(data) - {"image", "m_per_px", "known_distance", "outline_length_m"})
    if extra:
        raise ConfigError(f"{path}: plan has unknown key {extra[0]!r}")
    scales = [k for k in ("m_per_px", "known_distance", "outline_length_m") if data.get(k) is not None]
    if len(scales) > 1:  # none: the stage reads the scale bar printed on the plan
        raise ConfigError(
            f"{path}: plan takes at most one scale (m_per_px, known_distance or outline_length_m), "
            f"got {', '.join(scales)}"
        )
    m_per_px = data.get("m_per_px")
    if m_per_px is not None and (not _is_number(m_per_px) or not 1e-4 <= m_per_px <= 1.0):
        raise ConfigError(
            f"{path}: plan.m_per_px {m_per_px!r} is implausible (metres per pixel, 0.0001 to 1; wrong units?)"
        )
    known = data.get("known_distance")
    if known is not None and (
        not isinstance(known, list) or len(known) != 5 or not all(_is_number(v) for v in known)
    ):
        raise ConfigError(
            f"{path}: plan.known_distance must be five numbers [x0, y0, x1, y1, metres] (pixels, then "
            f"metres), got {known!r}"
        )
    if known is not None and (known[4] <= 0 or (known[0], known[1]) == (known[2], known[3])):
        raise ConfigError(
            f"{path}: plan.known_distance needs two different pixels and a positive distance, got {known!r}"
        )
    outline = data.get("outline_length_m")
    if outline is not None and (not _is_number(outline) or outline <= 0):
        raise ConfigError(
            f"{path}: plan.outline_length_m must be the outline's length in metres (a positive number), "
            f"got {outline!r}"
        )
    if not isinstance(data["image"], str) or not data["image"]:
        raise ConfigError(f"{path}: plan.image must be a path relative to the survey")
    return PlanSpec(
        image=folder / data["image"],
        m_per_px=None if m_per_px is None else float(m_per_px),
        known_distance=None if known is None else tuple(float(v) for v in known),  # type: ignore[arg-type]
        outline_length_m=None if outline is None else float(outline),
    )


def _is_number(value: Any) -> bool:
    """A finite int or float (not a bool, not text)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def build_section(cls: type, data: dict[str, Any]) -> Any:
    """A stage's config dataclass from its plain-data form (as `section` returns it)."""
    return _build(cls, data, "")


def hash_profile(profile: dict[str, Any]) -> str:
    """Content hash of a sensor profile (part of ingest's cache key)."""
    from tasks.artefacts import hash_json

    return hash_json(profile)
