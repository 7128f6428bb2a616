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
import logging
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

ROOM_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


class ArtefactError(RuntimeError):
    """An artefact that cannot be read as what it claims to be (one line, names the file)."""


DEBUG_VARIABLE = "INDOOR_SURVEY_DEBUG"
"""Set to 1 for the traceback of an unexpected error (otherwise one line)."""


class StageError(RuntimeError):
    """A stage that failed with an unexpected exception (a bug, or an input no check foresaw), as one line
    naming the room, the stage and its inputs."""

    def __init__(self, message: str, room: str = "", stage: str = "") -> None:
        super().__init__(message)
        self.room = room
        self.stage = stage


def one_line(exc: BaseException) -> str:
    """An exception's message on one line."""
    return " ".join(str(exc).split()) or type(exc).__name__


def is_input_error(exc: BaseException) -> bool:
    """Whether an exception is a checked, one-line report of a bad input (a value, file or artefact that
    cannot be used), as opposed to an unexpected failure."""
    return isinstance(exc, ValueError | ArtefactError | FileNotFoundError) and not isinstance(exc, StageError)


def stage_error(room: str, stage: str, inputs: dict[str, Any], exc: Exception) -> StageError:
    """The one line an unexpected exception inside a stage becomes: room, stage, inputs, the exception's
    type and message, and how to see the traceback."""
    named = ", ".join(f"{name} {value}" for name, value in inputs.items()) or "none"
    return StageError(
        f"unexpected {type(exc).__name__} (inputs: {named}): {one_line(exc)[:300]} "
        f"(set {DEBUG_VARIABLE}=1 for the traceback)",
        room,
        stage,
    )


def check_room_id(room_id: object) -> str:
    """The id itself if it is a plain name that can be a folder name; else a clear error. Ids become
    folder names under the work dir, so '..', '/' and the like must never pass."""
    # fullmatch: `$` of `match` also matches before a trailing newline ("r5\n" would pass)
    if not isinstance(room_id, str) or not ROOM_ID.fullmatch(room_id) or ".." in room_id:
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
    """A registered point cloud from PLY or PCD (metres), with colours when the file has them.

    Nothing is trusted before it is checked: the header is parsed here (it is small), the element counts
    times their record sizes must account for the file's size exactly, and only then is the body read with
    numpy from the known layout, so a file can never make the reader allocate more than its own size
    justifies. ASCII bodies are parsed strictly (one record per line, every value a number). Empty,
    damaged or non-finite clouds raise a one-line error naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ArtefactError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in {".ply", ".pcd"}:
        raise ArtefactError(f"{path}: unsupported cloud format {suffix!r} (PLY or PCD expected)")
    if path.stat().st_size == 0:
        raise DegenerateInputError(f"{path}: empty file")
    points, colors = _read_ply(path) if suffix == ".ply" else _read_pcd(path)
    if len(points) == 0:
        raise DegenerateInputError(f"{path}: the cloud has no points")
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():
        raise DegenerateInputError(
            f"{path}: {int((~finite).sum())} of {len(points)} points are NaN or infinite"
        )
    return Cloud(points, colors)


MAX_HEADER_BYTES = 1 << 20
"""A PLY or PCD header longer than this is not a header (a real one is a few hundred bytes; comments
may make it a few kilobytes)."""

ASCII_CHUNK_ROWS = 1 << 13
"""ASCII records parsed at a time (bounded working memory whatever the file's size)."""

BINARY_CHUNK_RECORDS = 1 << 18
"""Binary records read at a time (a few MB of working memory beside the cloud itself)."""

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


@dataclass
class _Element:
    """One `element` of a PLY header: its name, record count and properties (name, numpy type code,
    and the list-length type code for a list property, else None)."""

    name: str
    count: int
    props: list[tuple[str, str, str | None]] = field(default_factory=list)

    @property
    def has_lists(self) -> bool:
        return any(count is not None for _, _, count in self.props)

    def dtype(self, endian: str) -> np.dtype:
        return np.dtype([(name, endian + code) for name, code, _ in self.props])

    def min_bytes(self) -> int:
        """Bytes of one binary record at least (a list property counts its length field only)."""
        return sum(np.dtype(count or code).itemsize for _, code, count in self.props)


def _header_lines(path: Path, end_marker: bytes) -> tuple[list[str], int]:
    """The header's lines up to and including the line that starts with `end_marker`, and the byte offset
    where the body starts; one-line errors for a header that is not text or never ends."""
    with open(path, "rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
    lines: list[str] = []
    offset = 0
    while True:
        newline = head.find(b"\n", offset)
        if newline < 0:
            raise ArtefactError(
                f"{path}: the header has no {end_marker.decode()!r} line"
                + (f" in its first {MAX_HEADER_BYTES} bytes" if len(head) == MAX_HEADER_BYTES else "")
                + " (not a cloud file, or cut short)"
            )
        raw = head[offset:newline].rstrip(b"\r")
        try:
            line = raw.decode("ascii")
        except UnicodeDecodeError:
            raise ArtefactError(
                f"{path}: header line {len(lines) + 1} is not text (not a {path.suffix[1:].upper()} file?)"
            ) from None
        lines.append(line)
        offset = newline + 1
        if line.split()[:1] == [end_marker.decode()]:
            return lines, offset


def _read_ply(path: Path) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    fmt, elements, body, header_lines = _ply_header(path)
    size = path.stat().st_size
    index = next(i for i, e in enumerate(elements) if e.name == "vertex")
    vertex = elements[index]
    names = [name for name, _, _ in vertex.props]
    if vertex.has_lists:
        raise ArtefactError(f"{path}: the vertex element has a list property (not a point cloud)")
    if fmt == "ascii":
        return _read_ply_ascii(path, elements, index, body, header_lines, size)
    endian = "<" if fmt == "binary_little_endian" else ">"
    before = elements[:index]
    if any(e.has_lists for e in before):
        raise ArtefactError(
            f"{path}: an element with list properties comes before the vertices (unsupported)"
        )
    offset = body + sum(e.count * e.dtype(endian).itemsize for e in before)
    record = vertex.dtype(endian)
    after = elements[index + 1 :]
    needed = offset - body + vertex.count * record.itemsize + sum(e.count * e.min_bytes() for e in after)
    exact = not any(e.has_lists for e in after)
    held = size - body
    if held < needed or (exact and held != needed):
        raise ArtefactError(
            f"{path}: {held} bytes follow the header, but its elements ({_counts(elements)}) need "
            f"{'' if exact else 'at least '}{needed}: the file is "
            + (
                "truncated or its header's counts are wrong"
                if held < needed
                else "longer than its header says"
            )
        )
    # Read in slices into the result: memory is the cloud's own (points and colours) plus one slice.
    points = np.empty((vertex.count, 3), dtype=np.float64)
    coloured = {"red", "green", "blue"} <= set(names)
    colors = np.empty((vertex.count, 3), dtype=np.uint8) if coloured else None
    with open(path, "rb") as fh:
        fh.seek(offset)
        for start in range(0, vertex.count, BINARY_CHUNK_RECORDS):
            want = min(BINARY_CHUNK_RECORDS, vertex.count - start)
            rec = np.fromfile(fh, dtype=record, count=want)
            if len(rec) != want:  # the file changed while being read
                raise ArtefactError(f"{path}: {start + len(rec)} of {vertex.count} vertices could be read")
            stop = start + want
            for axis, name in enumerate("xyz"):
                points[start:stop, axis] = rec[name]
            if colors is not None:
                colors[start:stop] = _colour_bytes(
                    np.column_stack([rec[c] for c in ("red", "green", "blue")])
                )
    return points, colors


def _colour_bytes(values: NDArray[Any]) -> NDArray[np.uint8]:
    """Colour values as uint8, rounded as Open3D's readers do (value / 255 stored, times 255 read back),
    so that a cloud read here and one read by Open3D are the same bytes."""
    values = np.asarray(values)
    if values.dtype == np.uint8:  # the round trip is exact for bytes: no float copies of the colours
        return np.ascontiguousarray(values)
    scaled = values.astype(np.float64) / 255.0
    return np.clip(scaled * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _counts(elements: list[_Element]) -> str:
    return ", ".join(f"{e.count} {e.name}" for e in elements)


def _ply_header(path: Path) -> tuple[str, list[_Element], int, int]:
    """(format, elements, body offset, header lines) of a PLY file, every line checked."""
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic.rstrip(b"\r\n") != b"ply":
        raise ArtefactError(f"{path}: not a PLY file (it does not start with 'ply')")
    lines, body = _header_lines(path, b"end_header")
    fmt = ""
    elements: list[_Element] = []
    for number, line in enumerate(lines[1:-1], 2):
        words = line.split()
        where = f"{path}: header line {number}"
        if not words or words[0] in {"comment", "obj_info"}:
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in {"ascii", "binary_little_endian", "binary_big_endian"}:
                raise ArtefactError(f"{where}: unknown format {' '.join(words[1:2])!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ArtefactError(f"{where}: expected 'element NAME COUNT'")
            elements.append(_Element(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise ArtefactError(f"{where}: a property before any element")
            if len(words) == 5 and words[1] == "list":
                count_type, value_type, name = _PLY_TYPES.get(words[2]), _PLY_TYPES.get(words[3]), words[4]
                if count_type is None or value_type is None or count_type[0] == "f":
                    raise ArtefactError(f"{where}: bad list property types {words[2]!r} {words[3]!r}")
                elements[-1].props.append((name, value_type, count_type))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1].props.append((words[2], _PLY_TYPES[words[1]], None))
            else:
                raise ArtefactError(f"{where}: bad property {' '.join(words[1:])!r}")
            if [p[0] for p in elements[-1].props].count(elements[-1].props[-1][0]) > 1:
                raise ArtefactError(f"{where}: property {elements[-1].props[-1][0]!r} given twice")
        else:
            raise ArtefactError(f"{where}: unknown keyword {words[0][:40]!r}")
    if not fmt:
        raise ArtefactError(f"{path}: the PLY header has no format line")
    vertex = [e for e in elements if e.name == "vertex"]
    if len(vertex) != 1:
        raise ArtefactError(f"{path}: the PLY header has {len(vertex)} vertex elements (1 expected)")
    missing = [c for c in "xyz" if c not in {p[0] for p in vertex[0].props}]
    if missing:
        raise ArtefactError(f"{path}: the vertices have no {', '.join(missing)} property")
    return fmt, elements, body, len(lines)


def _read_ply_ascii(
    path: Path, elements: list[_Element], index: int, body: int, header_lines: int, size: int
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """The vertices of an ASCII PLY, every line checked: as many values as properties, each a number (a
    whole number in range for an integer property)."""
    vertex = elements[index]
    # Every record takes at least two bytes per value (a digit and a separator): a header claiming more
    # records than the body can hold is refused before anything is allocated.
    needed = sum(e.count * 2 * max(1, len(e.props)) for e in elements)
    if needed > size - body:
        raise ArtefactError(
            f"{path}: its header's elements ({_counts(elements)}) cannot fit in the {size - body} bytes "
            "after the header: the file is truncated or its header's counts are wrong"
        )
    names = [name for name, _, _ in vertex.props]
    codes = [np.dtype(code) for _, code, _ in vertex.props]
    reader = _AsciiRows(path, body, header_lines)
    for element in elements[:index]:
        reader.skip(element.count, element.name)
    columns = [names.index(c) for c in ("x", "y", "z")]
    colour_cols = (
        [names.index(c) for c in ("red", "green", "blue")] if {"red", "green", "blue"} <= set(names) else []
    )
    points = np.empty((vertex.count, 3), dtype=np.float64)  # the header's count fits the file: checked
    colours = np.empty((vertex.count, 3), dtype=np.uint8) if colour_cols else None
    start = 0
    for values in reader.rows(vertex.count, len(names), codes, "vertex"):
        points[start : start + len(values)] = values[:, columns]
        if colours is not None:
            colours[start : start + len(values)] = _colour_bytes(values[:, colour_cols])
        start += len(values)
    for element in elements[index + 1 :]:
        reader.skip(element.count, element.name)
    reader.end()
    return points, colours


class _AsciiRows:
    """Lines of an ASCII cloud body read strictly, with the file's line numbers for messages."""

    def __init__(self, path: Path, offset: int, lines_before: int) -> None:
        self.path = path
        self.offset = offset
        self.line = lines_before

    def _lines(self, count: int, what: str, total: int, done: int) -> list[bytes]:
        with open(self.path, "rb") as fh:
            fh.seek(self.offset)
            lines = []
            for _ in range(count):
                line = fh.readline()
                if not line:
                    raise ArtefactError(
                        f"{self.path}: the file ends after {done + len(lines)} of the header's {total} "
                        f"{what} records (truncated, or the count is wrong)"
                    )
                if not line.strip():
                    raise ArtefactError(f"{self.path}: line {self.line + len(lines) + 1} is empty")
                lines.append(line)
            self.offset = fh.tell()
        return lines

    def skip(self, count: int, what: str) -> None:
        for start in range(0, count, ASCII_CHUNK_ROWS):
            n = min(ASCII_CHUNK_ROWS, count - start)
            self._lines(n, what, count, start)
            self.line += n

    def rows(self, count: int, width: int, codes: list[np.dtype], what: str) -> Iterator[NDArray[np.float64]]:
        """(n, width) float64 blocks of `count` records of `width` values each."""
        integer = np.array([c.kind in "iu" for c in codes])
        low = np.array([np.iinfo(c).min if c.kind in "iu" else -np.inf for c in codes])
        high = np.array([np.iinfo(c).max if c.kind in "iu" else np.inf for c in codes])
        for start in range(0, count, ASCII_CHUNK_ROWS):
            n = min(ASCII_CHUNK_ROWS, count - start)
            tokens = [line.split() for line in self._lines(n, what, count, start)]
            for i, row in enumerate(tokens):
                if len(row) != width:
                    raise ArtefactError(
                        f"{self.path}: line {self.line + i + 1} has {len(row)} values, the header's "
                        f"{what} has {width} properties"
                    )
            try:
                values = np.array([t for row in tokens for t in row], dtype=np.float64).reshape(n, width)
            except ValueError:
                for i, row in enumerate(tokens):
                    for token in row:
                        try:
                            float(token)
                        except ValueError:
                            raise ArtefactError(
                                f"{self.path}: line {self.line + i + 1}: {token.decode(errors='replace')[:40]!r} "
                                "is not a number"
                            ) from None
                raise
            if integer.any():
                ints = values[:, integer]
                bad = (ints != np.round(ints)) | (ints < low[integer]) | (ints > high[integer])
                if bad.any():
                    i = int(np.nonzero(bad.any(axis=1))[0][0])
                    raise ArtefactError(
                        f"{self.path}: line {self.line + i + 1}: a value is not a whole number in its "
                        "property's range"
                    )
            self.line += n
            yield values

    def end(self) -> None:
        """Only blank space may follow the last record."""
        with open(self.path, "rb") as fh:
            fh.seek(self.offset)
            while block := fh.read(1 << 20):
                if block.strip():
                    raise ArtefactError(
                        f"{self.path}: data after the header's last record (line {self.line + 1}): "
                        "the header's counts are wrong"
                    )


_PCD_TYPES = {
    ("F", 4): "f4",
    ("F", 8): "f8",
    **{(t, s): f"{t.lower()}{s}" for t in "IU" for s in (1, 2, 4, 8)},
}

LZF_MAX_RATIO = 100
"""LZF expands at most 264 bytes from a 3-byte back reference: an uncompressed size claimed beyond this
multiple of the compressed size is a damaged header, not data."""


def _read_pcd(path: Path) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """A PCD file (ascii, binary or binary_compressed), its header checked against the file's size."""
    lines, body = _header_lines(path, b"DATA")
    header: dict[str, list[str]] = {}
    for number, line in enumerate(lines, 1):
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        key = words[0].upper()
        if key not in {
            "VERSION",
            "FIELDS",
            "SIZE",
            "TYPE",
            "COUNT",
            "WIDTH",
            "HEIGHT",
            "VIEWPOINT",
            "POINTS",
            "DATA",
        }:
            raise ArtefactError(f"{path}: header line {number}: unknown PCD keyword {words[0][:40]!r}")
        header[key] = words[1:]
    fields = header.get("FIELDS", [])
    sizes = header.get("SIZE", [])
    types = header.get("TYPE", [])
    counts = header.get("COUNT", ["1"] * len(fields))
    if not fields or not (len(fields) == len(sizes) == len(types) == len(counts)):
        raise ArtefactError(
            f"{path}: PCD header FIELDS ({len(fields)}), SIZE ({len(sizes)}), TYPE ({len(types)}) and "
            f"COUNT ({len(counts)}) do not match"
        )
    try:
        width = int(header.get("WIDTH", ["-1"])[0])
        height = int(header.get("HEIGHT", ["1"])[0])
        points_n = int(header.get("POINTS", [str(width * height)])[0])
        layout = []
        for name, s, t, c in zip(fields, sizes, types, counts, strict=True):
            code = _PCD_TYPES.get((t.upper(), int(s)))
            if code is None or int(c) < 1:
                raise ValueError(f"field {name}: type {t} of {s} bytes, count {c}")
            layout.append((name, "<" + code, int(c)))
    except (ValueError, IndexError) as exc:
        raise ArtefactError(f"{path}: bad PCD header ({' '.join(str(exc).split())})") from None
    if width < 0 or height < 1 or points_n != width * height:
        raise ArtefactError(
            f"{path}: PCD header POINTS {points_n} is not WIDTH x HEIGHT ({width} x {height})"
        )
    missing = [c for c in "xyz" if c not in fields]
    if missing:
        raise ArtefactError(f"{path}: the PCD has no {', '.join(missing)} field")
    if [c for name, _, c in layout if name in "xyz" and c != 1]:
        raise ArtefactError(f"{path}: PCD fields x y z must have COUNT 1")
    mode = (header.get("DATA") or [""])[0].lower()
    record = np.dtype([(name, code, (c,)) if c > 1 else (name, code) for name, code, c in layout])
    size = path.stat().st_size
    if mode == "binary":
        if size - body != points_n * record.itemsize:
            raise ArtefactError(
                f"{path}: {size - body} bytes follow the header, but its {points_n} points of "
                f"{record.itemsize} bytes need {points_n * record.itemsize}: the file is "
                + (
                    "truncated or POINTS is wrong"
                    if size - body < points_n * record.itemsize
                    else "longer than its header says"
                )
            )
        with open(path, "rb") as fh:
            fh.seek(body)
            rec = np.fromfile(fh, dtype=record, count=points_n)
        columns = {name: rec[name] for name in record.names}
    elif mode == "ascii":
        width_values = sum(c for _, _, c in layout)
        if points_n * 2 * width_values > size - body:
            raise ArtefactError(
                f"{path}: its header's {points_n} points cannot fit in the {size - body} bytes after the "
                "header: the file is truncated or POINTS is wrong"
            )
        codes = [np.dtype(code) for _, code, c in layout for _ in range(c)]
        reader = _AsciiRows(path, body, len(lines))
        values = np.empty((points_n, width_values), dtype=np.float64)
        start = 0
        for block in reader.rows(points_n, width_values, codes, "point"):
            values[start : start + len(block)] = block
            start += len(block)
        reader.end()
        starts = np.cumsum([0] + [c for _, _, c in layout])
        columns = {name: values[:, starts[i]] for i, (name, _, _) in enumerate(layout)}
    elif mode == "binary_compressed":
        return _read_pcd_compressed(path, body, size, points_n, record)
    else:
        raise ArtefactError(f"{path}: unknown PCD DATA {mode!r} (ascii, binary or binary_compressed)")
    points = np.column_stack([np.asarray(columns[c], dtype=np.float64) for c in "xyz"]).reshape(-1, 3)
    colors = None
    colour_field = next((f for f in ("rgb", "rgba") if f in fields), None)
    if colour_field and record[colour_field].itemsize == 4:
        # PCL packs colour as 0x00RRGGBB in a 4-byte field, typed float (its bits) or unsigned
        packed = np.asarray(columns[colour_field]).astype(record[colour_field].base).view("<u4")
        colors = _colour_bytes(np.column_stack([(packed >> shift) & 0xFF for shift in (16, 8, 0)]))
    return points, colors


def _read_pcd_compressed(
    path: Path, body: int, size: int, points_n: int, record: np.dtype
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """binary_compressed: its two size fields checked against the file and the header, then decoded by
    Open3D (LZF), which then allocates no more than the checked sizes."""
    import open3d as o3d

    with open(path, "rb") as fh:
        fh.seek(body)
        sizes = np.frombuffer(fh.read(8), "<u4")
    if len(sizes) != 2:
        raise ArtefactError(f"{path}: the compressed PCD body is cut short")
    packed, unpacked = (int(v) for v in sizes)
    if body + 8 + packed > size:
        raise ArtefactError(
            f"{path}: the compressed body claims {packed} bytes, the file holds {size - body - 8}"
        )
    if unpacked != points_n * record.itemsize or unpacked > LZF_MAX_RATIO * max(packed, 1):
        raise ArtefactError(
            f"{path}: the compressed body unpacks to {unpacked} bytes, the header's {points_n} points "
            f"need {points_n * record.itemsize}"
        )
    pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(pcd.points, dtype=np.float64)
    if len(points) != points_n:
        raise ArtefactError(
            f"{path}: the compressed body could not be decoded ({len(points)} of {points_n} points)"
        )
    colors = None
    if pcd.has_colors():
        colors = np.clip(np.asarray(pcd.colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return points, colors


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
        features = data.get("features") if isinstance(data, dict) else None
        if not isinstance(features, list):
            raise ArtefactError(f"{path}: not a GeoJSON FeatureCollection (no 'features' list)")
        segs = []
        for index, feat in enumerate(features):
            if not isinstance(feat, dict):
                raise ArtefactError(f"{path}: features[{index}] is not a GeoJSON Feature")
            geom = feat.get("geometry")
            if not isinstance(geom, dict | None):
                raise ArtefactError(f"{path}: features[{index}].geometry is not a GeoJSON geometry")
            if geom and geom.get("type") == "LineString":
                coords = geom.get("coordinates")
                if not (
                    isinstance(coords, list)
                    and all(
                        isinstance(c, list)
                        and len(c) >= 2
                        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in c[:2])
                        for c in coords
                    )
                ):
                    raise ArtefactError(
                        f"{path}: features[{index}]: a LineString's coordinates must be [x, y] numbers"
                    )
                segs += [[*coords[i][:2], *coords[i + 1][:2]] for i in range(len(coords) - 1)]
        seg = np.asarray(segs, dtype=np.float64).reshape(-1, 4)
        if not np.isfinite(seg).all():
            raise ArtefactError(f"{path}: wall coordinates that are not finite")
        return seg, pa.table({})
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
        self.read_only = False
        """Set by callers that only read (`status`): the store then writes nothing."""

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
            try:
                extra = write(tmp) or {}
            except Exception as exc:  # the stage's error boundary: one line, whatever went wrong
                if is_input_error(exc):
                    raise
                if os.environ.get(DEBUG_VARIABLE):
                    logging.getLogger("indoor_survey").exception("[%s] %s failed", room, stage)
                inputs = {
                    name: entry.get("path") if isinstance(entry, dict) else entry
                    for name, entry in (manifest.get("raw_inputs") or {}).items()
                }
                inputs.update({name: "result" for name in manifest.get("inputs") or {}})
                if manifest.get("rooms") or manifest.get("failed_rooms"):  # a building-after stage
                    read = sorted({*(manifest.get("rooms") or {}), *(manifest.get("failed_rooms") or {})})
                    inputs["rooms"] = " ".join(read)
                raise stage_error(room, stage, inputs, exc) from exc
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
        if self.outputs.is_dir():  # copies a killed publish left (atomic_path's `.<name>.<hex>.tmp`)
            for tmp in self.outputs.rglob(".*.tmp"):
                if tmp.is_file():
                    tmp.unlink(missing_ok=True)
                    count += 1
        if not self.cache.is_dir():
            return count
        for tmp in self.cache.glob("*/*/.tmp-*"):
            shutil.rmtree(tmp, ignore_errors=True)
            count += 1
        for tmp in self.cache.glob("*/*/.old-*"):
            shutil.rmtree(tmp, ignore_errors=True)
        return count

    # ---- raw inputs

    def input_hash(self, path: Path) -> str:
        """Content hash of a raw input file or folder (a folder's files under this work dir left out: a
        work dir inside an input folder must not change that input), memoised by what the file system
        says of the file: (device, inode, size, mtime_ns, ctime_ns). A file replaced by one of the same
        size and mtime (`cp -p`, `rsync -t`, bytes fixed in place and the time set back) still has a new
        ctime, which no user tool can set back, so it is hashed again; so is a file whose ctime is within
        `RACY_SECONDS` of when it was hashed (a write in the same clock tick leaves every time as it was)."""
        path = Path(path).resolve()
        if path.is_dir():
            parts = {
                str(p.relative_to(path)): self.input_hash(p)
                for p in sorted(path.rglob("*"))
                if p.is_file() and not p.resolve().is_relative_to(self.work)
            }
            return hash_json(parts)
        if not path.is_file():
            raise ArtefactError(f"{path}: no such file")
        stat = path.stat()
        memo = self._load_memo()
        tag = f"{stat.st_dev}:{stat.st_ino}:{stat.st_size}:{stat.st_mtime_ns}:{stat.st_ctime_ns}"
        entry = memo.get(str(path))
        if entry and entry[0] == tag and len(entry) > 2 and entry[2]:
            return entry[1]
        hashed_at = time.time_ns()
        digest = sha256_file(path)
        settled = hashed_at - max(stat.st_ctime_ns, stat.st_mtime_ns) > self.RACY_SECONDS * 1e9
        memo[str(path)] = [tag, digest, settled]
        return digest

    RACY_SECONDS = 2.0
    """A memo entry is trusted only for a file last changed this long before it was hashed."""

    def _load_memo(self) -> dict[str, Any]:
        if self._hash_memo is None:
            try:
                self._hash_memo = json.loads(self._hash_memo_path.read_text())
            except (OSError, ValueError):
                self._hash_memo = {}
            if not isinstance(self._hash_memo, dict):
                self._hash_memo = {}
        return self._hash_memo

    def save_memo(self) -> None:
        """Write the input-hash memo (not for a read-only store: `status` only reads)."""
        if self._hash_memo is not None and not self.read_only:
            write_json(self._hash_memo_path, self._hash_memo)

    # ---- deliverables

    def publish(self, src: Path, *relative: str) -> Path:
        """Copy a committed artefact to `outputs/<relative...>` atomically (a stable path for users)."""
        dest = self.outputs.joinpath(*relative)
        with atomic_path(dest) as tmp:
            shutil.copyfile(src, tmp)
        return dest

    def publish_all(self, files: dict[tuple[str, ...], Path]) -> list[Path]:
        """Copy several committed artefacts to `outputs/<relative...>` in two phases: every copy is made
        beside its destination under a temporary name first, then all are renamed into place. A failure
        while copying (a full disk) removes the copies and leaves outputs/ exactly as it was; a run killed
        meanwhile leaves only temporaries, which no reader takes for deliverables and the next run
        sweeps."""
        staged: list[tuple[Path, Path]] = []
        try:
            for relative, src in files.items():
                dest = self.outputs.joinpath(*relative)
                dest.parent.mkdir(parents=True, exist_ok=True)
                tmp = dest.with_name(f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp")
                staged.append((tmp, dest))
                shutil.copyfile(src, tmp)
        except BaseException:
            for tmp, _ in staged:
                tmp.unlink(missing_ok=True)
            raise
        for tmp, dest in staged:
            os.replace(tmp, dest)
        return [dest for _, dest in staged]


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


__all__ = [
    "BUILDING",
    "CHANGES_SCHEMA",
    "FRAMES_SCHEMA",
    "PLAN_WALLS_SCHEMA",
    "POSES_SCHEMA",
    "WALLS_SCHEMA",
    "ArtefactError",
    "ArtefactStore",
    "StageError",
    "StageResult",
    "atomic_path",
    "check_room_id",
    "encode_png",
    "hash_json",
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
