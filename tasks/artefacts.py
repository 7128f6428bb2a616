"""The artefact store: the only code that knows where artefacts live and in which format they are written.

Layout under a work directory:

    <work>/cache/<room>/<stage>/<key>/...      one folder per cache key, with manifest.json written last
    <work>/cache/_building/<stage>/<key>/...   survey-wide stages (calibrate, plan, fuse...)
    <work>/outputs/...                         deliverables (PIPELINE.md "Deliverables"), stable paths
    <work>/runs/<timestamp>/config.yaml        the resolved config of every run

A stage's folder is built under a temporary name and renamed into place only when every file and the
manifest are written, so a killed run never leaves a folder a later run could take for whole. A lookup
re-hashes the files against the manifest: a missing or altered file means recompute, never trust.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from tasks.cloud import Cloud, DegenerateInputError

BUILDING = "_building"
"""The partition of survey-wide stages; room ids cannot start with '_' so it never collides."""

ROOM_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class ArtefactError(RuntimeError):
    """An artefact that cannot be read as what it claims to be (one line, names the file)."""


def check_room_id(room_id: object) -> str:
    """The id itself if it is a plain name that can be a folder name; else a clear error. Ids become
    folder names under the work dir, so '..', '/' and the like must never pass."""
    if not isinstance(room_id, str) or not ROOM_ID.match(room_id) or ".." in room_id:
        raise ValueError(
            f"room id {room_id!r} is not a plain name (letters, digits, '_', '-', '.'; no '/' or '..')"
        )
    return room_id


# --------------------------------------------------------------------------------------------- atomic I/O


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it replaces `path` in one rename, on failure it
    is removed and `path` is untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes(path: Path, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def write_json(path: Path, obj: Any) -> Path:
    """Write `obj` as indented JSON (numpy arrays and scalars allowed)."""
    return write_bytes(path, (json.dumps(obj, indent=2, default=_json_default) + "\n").encode())


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ArtefactError(f"{path}: not readable JSON ({exc})") from exc


def write_table(path: Path, columns: dict[str, Any] | pa.Table, schema: pa.Schema | None = None) -> Path:
    """Write a Parquet table (zstd). `columns` maps names to arrays or is a pyarrow Table; with a schema,
    columns are cast to it and extra or missing columns are an error."""
    table = columns if isinstance(columns, pa.Table) else pa.table(dict(columns))
    if schema is not None:
        if set(table.column_names) != set(schema.names):
            raise ValueError(f"{path}: columns {table.column_names} do not match schema {schema.names}")
        table = table.select(schema.names).cast(schema)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")
    return Path(path)


def read_table(path: Path) -> pa.Table:
    try:
        return pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise ArtefactError(f"{path}: not a readable Parquet file ({exc})") from exc


def encode_png(image: NDArray[Any]) -> bytes:
    """PNG bytes of an (H, W) grey (uint8 or uint16) or (H, W, 3) RGB uint8 image."""
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"cannot encode image of shape {img.shape} and type {img.dtype} as PNG")
    return buf.tobytes()


def write_png(path: Path, image: NDArray[Any]) -> Path:
    """Write an (H, W) or (H, W, 3) RGB image as PNG."""
    return write_bytes(path, encode_png(image))


def read_image(path: Path, unchanged: bool = False) -> NDArray[Any]:
    """An image file as (H, W, 3) RGB uint8, or as stored (e.g. uint16 depth) with `unchanged`."""
    import cv2

    flag = cv2.IMREAD_UNCHANGED if unchanged else cv2.IMREAD_COLOR
    img = cv2.imread(str(path), flag)
    if img is None:
        raise ArtefactError(f"{path}: not a readable image")
    if img.ndim == 3 and img.shape[2] >= 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
    return img


def write_ply_points(
    path: Path, points: NDArray[np.float64], colors: NDArray[np.uint8] | None = None
) -> Path:
    """Binary little-endian PLY of (N, 3) points (double) with optional (N, 3) uint8 colours."""
    pts = np.asarray(points, dtype="<f8")
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    props = ["property double x", "property double y", "property double z"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    rec = np.empty(len(pts), dtype=fields)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        col = np.asarray(colors, dtype=np.uint8)
        rec["red"], rec["green"], rec["blue"] = col[:, 0], col[:, 1], col[:, 2]
    head = "\n".join(
        ["ply", "format binary_little_endian 1.0", f"element vertex {len(pts)}", *props, "end_header", ""]
    )
    return write_bytes(path, head.encode() + rec.tobytes())


def write_ply_mesh(
    path: Path,
    vertices: NDArray[np.float64],
    triangles: NDArray[np.int32],
    colors: NDArray[np.uint8] | None = None,
) -> Path:
    """Binary PLY triangle mesh: (V, 3) vertices, (T, 3) vertex indices, optional (V, 3) uint8 colours."""
    verts = np.asarray(vertices, dtype="<f8")
    tris = np.asarray(triangles, dtype="<i4")
    vfields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    props = ["property double x", "property double y", "property double z"]
    if colors is not None:
        vfields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    vrec = np.empty(len(verts), dtype=vfields)
    vrec["x"], vrec["y"], vrec["z"] = verts[:, 0], verts[:, 1], verts[:, 2]
    if colors is not None:
        col = np.asarray(colors, dtype=np.uint8)
        vrec["red"], vrec["green"], vrec["blue"] = col[:, 0], col[:, 1], col[:, 2]
    frec = np.empty(len(tris), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    frec["n"] = 3
    frec["i"] = tris
    head = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            f"element vertex {len(verts)}",
            *props,
            f"element face {len(tris)}",
            "property list uchar int vertex_indices",
            "end_header",
            "",
        ]
    )
    return write_bytes(path, head.encode() + vrec.tobytes() + frec.tobytes())


def write_geojson(path: Path, features: list[dict[str, Any]], crs_note: str | None = None) -> Path:
    """A GeoJSON FeatureCollection. Coordinates are metres in a local frame (named in `crs_note`)."""
    collection: dict[str, Any] = {"type": "FeatureCollection", "features": features}
    if crs_note:
        collection["frame"] = crs_note
    return write_json(path, collection)


def read_cloud(path: Path) -> Cloud:
    """A registered point cloud from PLY or PCD (metres), with colours when the file has them. Empty,
    unreadable or non-finite clouds raise a one-line error naming the file."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise ArtefactError(f"{path}: no such file")
    if path.suffix.lower() not in {".ply", ".pcd"}:
        raise ArtefactError(f"{path}: unsupported cloud format {path.suffix!r} (PLY or PCD expected)")
    if path.stat().st_size == 0:
        raise DegenerateInputError(f"{path}: empty file")
    if path.suffix.lower() == ".ply" and ply_vertex_count(path) == 0:
        raise DegenerateInputError(f"{path}: the cloud has no points (empty or unreadable)")
    pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(pcd.points, dtype=np.float64)
    if len(points) == 0:
        raise DegenerateInputError(f"{path}: the cloud has no points (empty or unreadable)")
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        raise DegenerateInputError(
            f"{path}: {int((~finite).sum())} of {len(points)} points are NaN or infinite"
        )
    colors = None
    if pcd.has_colors():
        colors = np.clip(np.asarray(pcd.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return Cloud(points, colors)


def write_cloud(path: Path, cloud: Cloud) -> Path:
    return write_ply_points(path, cloud.points, cloud.colors)


# ----------------------------------------------------------------------------------------------- schemas

SEGMENT_FIELDS = [("x0", pa.float64()), ("y0", pa.float64()), ("x1", pa.float64()), ("y1", pa.float64())]

WALLS_SCHEMA = pa.schema(
    [*SEGMENT_FIELDS, ("height", pa.float64()), ("origin", pa.string()), ("support", pa.float64())]
)
"""walls.parquet: one row per wall of a room model (inner face), in the frame the manifest names."""

PLAN_WALLS_SCHEMA = pa.schema([*SEGMENT_FIELDS, ("thickness_m", pa.float64())])
"""plan_walls.parquet: wall centrelines of the coarse plan, metres, plan frame."""

CHANGES_SCHEMA = pa.schema([*SEGMENT_FIELDS, ("kind", pa.string()), ("room_id", pa.string())])

POSES_SCHEMA = pa.schema(
    [
        ("frame_id", pa.int32()),
        ("t_ns", pa.int64()),
        ("qw", pa.float64()),
        ("qx", pa.float64()),
        ("qy", pa.float64()),
        ("qz", pa.float64()),
        ("tx", pa.float64()),
        ("ty", pa.float64()),
        ("tz", pa.float64()),
        ("method", pa.string()),
    ]
)

FRAMES_SCHEMA = pa.schema(
    [
        ("frame_id", pa.int32()),
        ("t_ns", pa.int64()),
        ("rgb_t_ns", pa.int64()),
        ("rgb", pa.binary()),
        ("rgb_format", pa.string()),
        ("depth", pa.binary()),
        ("depth_kind", pa.string()),
        ("depth_units_per_m", pa.float64()),
    ]
)
"""frames.parquet: one row per depth frame with its nearest colour image. `rgb` is the encoded image as
received (jpeg/png bytes); `depth` is a 16-bit PNG: millimetres (kind "mm", 1000 units per metre), TUM
(kind "tum5000", 5000) or raw Kinect v1 disparity (kind "disparity", kept raw for calibration)."""


def segments_table(segments: NDArray[np.float64], **extra: Any) -> dict[str, Any]:
    """Columns x0 y0 x1 y1 of an (N, 4) array, plus any extra columns."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    return {"x0": seg[:, 0], "y0": seg[:, 1], "x1": seg[:, 2], "y1": seg[:, 3], **extra}


def read_segments(path: Path) -> tuple[NDArray[np.float64], pa.Table]:
    """(N, 4) x0 y0 x1 y1 from a Parquet table (plus the table) or a GeoJSON of LineStrings."""
    path = Path(path)
    if path.suffix.lower() in {".geojson", ".json"}:
        data = read_json(path)
        segs = []
        for feat in data.get("features", []):
            geom = feat.get("geometry") or {}
            if geom.get("type") == "LineString":
                coords = geom["coordinates"]
                segs += [[*coords[i][:2], *coords[i + 1][:2]] for i in range(len(coords) - 1)]
        return np.asarray(segs, dtype=np.float64).reshape(-1, 4), pa.table({})
    table = read_table(path)
    missing = {"x0", "y0", "x1", "y1"} - set(table.column_names)
    if missing:
        raise ArtefactError(f"{path}: missing columns {sorted(missing)}")
    seg = np.column_stack([table[c].to_numpy().astype(np.float64) for c in ("x0", "y0", "x1", "y1")])
    return seg.reshape(-1, 4), table


# ------------------------------------------------------------------------------------------------ hashing


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def hash_json(obj: Any) -> str:
    return sha256_text(json.dumps(obj, sort_keys=True, default=_json_default))


# -------------------------------------------------------------------------------------------------- store


@dataclass(frozen=True)
class StageResult:
    """A reference to one stage's committed output folder: what flows pass between tasks (small and
    picklable; the data stays on disk)."""

    room: str
    stage: str
    key: str
    path: str
    files: dict[str, str] = field(default_factory=dict)
    """File name -> sha256."""
    content_hash: str = ""
    """Hash of all file hashes: what downstream cache keys are built from."""

    def file(self, name: str) -> Path:
        if name not in self.files:
            raise ArtefactError(f"{self.path}: stage {self.stage} has no output {name!r}")
        return Path(self.path) / name

    def has(self, name: str) -> bool:
        return name in self.files

    @property
    def manifest(self) -> dict[str, Any]:
        return read_json(Path(self.path) / "manifest.json")


class ArtefactStore:
    """Paths, atomic commits and verified lookups of stage outputs under one work directory."""

    def __init__(self, work: Path) -> None:
        self.work = Path(work).resolve()
        self.cache = self.work / "cache"
        self.outputs = self.work / "outputs"
        self._hash_memo_path = self.cache / "_file_hashes.json"
        self._hash_memo: dict[str, Any] | None = None

    # ---- keys and folders

    def stage_root(self, room: str, stage: str) -> Path:
        if room != BUILDING:
            check_room_id(room)
        return self.cache / room / stage

    def stage_dir(self, room: str, stage: str, key: str) -> Path:
        return self.stage_root(room, stage) / key[:20]

    @staticmethod
    def cache_key(stage: str, code_version: str, config: Any, inputs: dict[str, str]) -> str:
        """Content address of a stage run: its inputs' content hashes, its own config section and its
        code version, nothing else (never a path)."""
        return hash_json({"stage": stage, "code": code_version, "config": config, "inputs": inputs})

    # ---- lookup

    def lookup(self, room: str, stage: str, key: str, verify: bool = True) -> StageResult | None:
        """The committed result for this key, or None when absent or when any file fails its hash."""
        folder = self.stage_dir(room, stage, key)
        manifest_path = folder / "manifest.json"
        if not manifest_path.is_file():
            return None
        try:
            manifest = read_json(manifest_path)
        except ArtefactError:
            return None
        files: dict[str, str] = manifest.get("files", {})
        if manifest.get("key") != key:
            return None
        if verify:
            for name, digest in files.items():
                path = folder / name
                if not path.is_file() or sha256_file(path) != digest:
                    return None
        return StageResult(room, stage, key, str(folder), dict(files), manifest.get("content_hash", ""))

    def latest(self, room: str, stage: str) -> StageResult | None:
        """The most recently committed result of a stage (for `status` and reports), verified."""
        root = self.stage_root(room, stage)
        best: tuple[float, StageResult] | None = None
        if not root.is_dir():
            return None
        for folder in root.iterdir():
            manifest_path = folder / "manifest.json"
            if folder.name.startswith(".") or not manifest_path.is_file():
                continue
            try:
                manifest = read_json(manifest_path)
            except ArtefactError:
                continue
            result = self.lookup(room, stage, manifest.get("key", ""))
            if result and (best is None or manifest.get("finished_at", 0) > best[0]):
                best = (manifest.get("finished_at", 0), result)
        return best[1] if best else None

    # ---- commit

    def commit(
        self,
        room: str,
        stage: str,
        key: str,
        write: Callable[[Path], dict[str, Any] | None],
        manifest: dict[str, Any],
    ) -> StageResult:
        """Run `write(tmp_dir)` to produce the stage's files in a private folder, hash them, write the
        manifest last and rename the folder into place. `write` may return metrics to merge into the
        manifest. Whatever fails, nothing visible changes."""
        root = self.stage_root(room, stage)
        root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{key[:12]}-", dir=root))
        try:
            started = time.time()
            extra = write(tmp) or {}
            files = {
                p.name: sha256_file(p)
                for p in sorted(tmp.iterdir())
                if p.is_file() and p.name != "manifest.json"
            }
            content_hash = hash_json(files)
            full = {
                **manifest,
                **extra,
                "room": room,
                "stage": stage,
                "key": key,
                "files": files,
                "content_hash": content_hash,
                "write_seconds": round(time.time() - started, 3),
                "finished_at": time.time(),
            }
            write_json(tmp / "manifest.json", full)
            final = self.stage_dir(room, stage, key)
            if final.exists():  # a stale or corrupt folder of the same key: move it aside, then swap
                trash = root / f".old-{uuid.uuid4().hex[:8]}"
                os.replace(final, trash)
                shutil.rmtree(trash, ignore_errors=True)
            os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return StageResult(room, stage, key, str(final), files, content_hash)

    def sweep_temporaries(self) -> int:
        """Remove temporary folders left by killed runs (never read by lookups); returns how many."""
        count = 0
        if not self.cache.is_dir():
            return 0
        for tmp in self.cache.glob("*/*/.tmp-*"):
            shutil.rmtree(tmp, ignore_errors=True)
            count += 1
        for tmp in self.cache.glob("*/*/.old-*"):
            shutil.rmtree(tmp, ignore_errors=True)
        return count

    # ---- raw inputs

    def input_hash(self, path: Path) -> str:
        """Content hash of a raw input file or folder, memoised by (path, size, mtime) so a warm rerun
        does not re-read large captures."""
        path = Path(path).resolve()
        if path.is_dir():
            parts = {
                str(p.relative_to(path)): self.input_hash(p) for p in sorted(path.rglob("*")) if p.is_file()
            }
            return hash_json(parts)
        if not path.is_file():
            raise ArtefactError(f"{path}: no such file")
        stat = path.stat()
        memo = self._load_memo()
        tag = f"{stat.st_size}:{stat.st_mtime_ns}"
        entry = memo.get(str(path))
        if entry and entry[0] == tag:
            return entry[1]
        digest = sha256_file(path)
        memo[str(path)] = [tag, digest]
        return digest

    def _load_memo(self) -> dict[str, Any]:
        if self._hash_memo is None:
            try:
                self._hash_memo = json.loads(self._hash_memo_path.read_text())
            except (OSError, ValueError):
                self._hash_memo = {}
        return self._hash_memo

    def save_memo(self) -> None:
        if self._hash_memo is not None:
            write_json(self._hash_memo_path, self._hash_memo)

    # ---- deliverables

    def publish(self, src: Path, *relative: str) -> Path:
        """Copy a committed artefact to `outputs/<relative...>` atomically (a stable path for users)."""
        dest = self.outputs.joinpath(*relative)
        with atomic_path(dest) as tmp:
            shutil.copyfile(src, tmp)
        return dest


def read_track(path: Path) -> NDArray[np.float64]:
    """(K, 3) t_ns, x, y of a foot-mounted IMU track CSV (header line allowed)."""
    try:
        data = np.loadtxt(path, delimiter=",", ndmin=2, skiprows=1 if not _starts_numeric(path) else 0)
    except ValueError as exc:
        raise ArtefactError(f"{path}: not a track CSV of t_ns,x,y ({exc})") from exc
    if data.shape[1] < 3:
        raise ArtefactError(f"{path}: a track needs three columns t_ns,x,y")
    return data[:, :3]


def _starts_numeric(path: Path) -> bool:
    """Whether the file's first field is a number (no header line)."""
    with open(path) as fh:
        first = fh.readline().split(",")[0].strip()
    try:
        float(first)
    except ValueError:
        return False
    return True


def ply_vertex_count(path: Path) -> int:
    """The vertex count declared in a PLY header (cheap check without loading the file)."""
    with open(path, "rb") as fh:
        head = fh.read(4096).split(b"end_header")[0].decode(errors="replace")
    for line in head.splitlines():
        if line.startswith("element vertex"):
            return int(line.split()[2])
    raise ArtefactError(f"{path}: not a PLY file")


__all__ = [
    "BUILDING",
    "CHANGES_SCHEMA",
    "FRAMES_SCHEMA",
    "PLAN_WALLS_SCHEMA",
    "POSES_SCHEMA",
    "WALLS_SCHEMA",
    "ArtefactError",
    "ArtefactStore",
    "StageResult",
    "atomic_path",
    "check_room_id",
    "encode_png",
    "hash_json",
    "ply_vertex_count",
    "read_cloud",
    "read_image",
    "read_json",
    "read_segments",
    "read_table",
    "read_track",
    "segments_table",
    "sha256_file",
    "write_bytes",
    "write_cloud",
    "write_geojson",
    "write_json",
    "write_ply_mesh",
    "write_ply_points",
    "write_png",
    "write_table",
]
