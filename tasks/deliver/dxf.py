"""floor.dxf: the fused floor for CAD (ezdxf), DXF R2010 in metres, layers in the AIA/NCS style.

- A-WALL: each standing stretch of a wall, a closed outline of its two faces at its thickness (a door or
  a removed piece cuts it);
- A-WALL-NEWW / A-WALL-DEMO: added walls and removed pieces, closed outlines;
- A-DOOR: per door, its leaf (a line from the hinge, square to the wall) and its swing arc (the gap is
  the cut in A-WALL);
- A-AREA-IDEN: per room, its name, plan label and area (one MTEXT at shapely's representative point);
- A-ANNO-CHNG: per change, a circle around it and its kind;
- I-SCAN: the coarse plan underlay (its walls' outlines at the plan's thickness, its doors as lines).

The bytes are the same for the same floor: the header's time stamps and GUIDs are fixed.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path

import ezdxf
import numpy as np
from ezdxf import units

from tasks.deliver.floor import Floor, outline, standing_pieces

LAYERS = {
    "A-WALL": 7,
    "A-WALL-NEWW": 3,
    "A-WALL-DEMO": 1,
    "A-DOOR": 4,
    "A-AREA-IDEN": 2,
    "A-ANNO-CHNG": 6,
    "I-SCAN": 8,
}
"""Layer -> ACI colour (white, green, red, cyan, yellow, magenta, grey)."""
TEXT_HEIGHT_M = 0.20
FIXED_GUID = "{00000000-0000-0000-0000-000000000000}"


def _poly(msp, corners: np.ndarray, layer: str) -> None:
    msp.add_lwpolyline([tuple(map(float, p)) for p in corners], close=True, dxfattribs={"layer": layer})


def build(floor: Floor) -> ezdxf.document.Drawing:
    """The drawing (module doc)."""
    doc = ezdxf.new("R2010", setup=False)
    doc.units = units.M
    doc.header["$INSUNITS"] = 6
    doc.header["$MEASUREMENT"] = 1
    for name, colour in LAYERS.items():
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()
    for wall in floor.walls:
        for s0, s1 in standing_pieces(floor, wall):
            _poly(msp, outline(wall.centreline, wall.thickness_m, s0, s1), "A-WALL")
    for wall in floor.added:
        _poly(msp, outline(wall.centreline, wall.thickness_m), "A-WALL-NEWW")
    for change in floor.changes:
        if change.kind != "removed":
            continue
        t = floor.walls[change.wall_id].thickness_m if change.wall_id is not None else 0.1
        _poly(msp, outline(change.segment, t), "A-WALL-DEMO")
    for door in floor.doors:
        a, b = door.segment[:2], door.segment[2:]
        width = door.width_m
        u = (b - a) / max(width, 1e-12)
        n = np.array([-u[1], u[0]])
        if door.wall_id is not None:
            t = floor.walls[door.wall_id].thickness_m
        else:
            t = 0.0
        hinge = a + 0.5 * t * n
        tip = hinge + width * n
        msp.add_line(tuple(hinge), tuple(tip), dxfattribs={"layer": "A-DOOR"})
        start = math.degrees(math.atan2(u[1], u[0]))
        msp.add_arc(tuple(hinge), width, start, start + 90.0, dxfattribs={"layer": "A-DOOR"})
    for room in floor.rooms:
        p = room.polygon.representative_point()
        name = room.id + (f" ({room.label})" if room.label else "")
        text = msp.add_mtext(
            f"{name}\\P{room.area_m2:.2f} m²",
            dxfattribs={"layer": "A-AREA-IDEN", "char_height": TEXT_HEIGHT_M},
        )
        text.set_location((p.x, p.y), attachment_point=5)
    for change in floor.changes:
        a, b = change.segment[:2], change.segment[2:]
        mid = 0.5 * (a + b)
        radius = max(0.5 * float(np.hypot(*(b - a))), 0.25) + 0.1
        msp.add_circle(tuple(mid), radius, dxfattribs={"layer": "A-ANNO-CHNG"})
        msp.add_text(
            f"{change.kind.upper()} {change.room_id}".strip(),
            height=TEXT_HEIGHT_M,
            dxfattribs={"layer": "A-ANNO-CHNG", "insert": (float(mid[0]), float(mid[1] + radius))},
        )
    for c, t in zip(floor.plan_walls, floor.plan_thickness_m, strict=True):
        _poly(msp, outline(c, float(t) if np.isfinite(t) and t > 0 else 0.1), "I-SCAN")
    for d in floor.plan_doors:
        msp.add_line(tuple(d[:2]), tuple(d[2:]), dxfattribs={"layer": "I-SCAN"})
    return doc


FIXED_HEADER = {
    "$TDCREATE": "2451545.0",  # 2000-01-01 (a Julian date)
    "$TDUCREATE": "2451545.0",
    "$TDUPDATE": "2451545.0",
    "$TDUUPDATE": "2451545.0",
    "$TDINDWG": "0.0",
    "$TDUSRTIMER": "0.0",
    "$FINGERPRINTGUID": FIXED_GUID,
    "$VERSIONGUID": FIXED_GUID,
}
"""Header values ezdxf sets from the clock or at random on every save: fixed, so the bytes depend on the
floor alone."""
EZDXF_STAMP = re.compile(r"(?m)^(\d+\.\d+\.\d+\S*) @ \d{4}-\d\d-\d\dT[0-9:.+]+$")
"""ezdxf's "written by" note (version @ time) in the objects section."""


def write(floor: Floor, path: Path) -> dict[str, int]:
    """Write floor.dxf with fixed time stamps and GUIDs; returns the entity count per layer."""
    doc = build(floor)
    stream = io.StringIO()
    doc.write(stream)
    lines = stream.getvalue().split("\n")
    for i in range(len(lines) - 3):  # "  9", name, group code, value
        if lines[i].strip() == "9" and lines[i + 1].strip() in FIXED_HEADER:
            lines[i + 3] = FIXED_HEADER[lines[i + 1].strip()]
    text = _sorted_classes(EZDXF_STAMP.sub(r"\1 @ 2000-01-01T00:00:00+00:00", "\n".join(lines)))
    path.write_bytes(text.encode("utf-8"))
    counts: dict[str, int] = dict.fromkeys(LAYERS, 0)
    for e in doc.modelspace():
        counts[e.dxf.layer] = counts.get(e.dxf.layer, 0) + 1
    return counts


def _sorted_classes(text: str) -> str:
    """The CLASSES section with its CLASS records sorted: ezdxf adds the classes of the entity types in
    use in a set's order, which changes from one process to the next (their order means nothing)."""
    head = "  0\nSECTION\n  2\nCLASSES\n"
    start = text.find(head)
    if start < 0:
        return text
    body_start = start + len(head)
    end = text.index("  0\nENDSEC\n", body_start)
    records = [r for r in text[body_start:end].split("  0\nCLASS\n") if r]
    return text[:body_start] + "".join("  0\nCLASS\n" + r for r in sorted(records)) + text[end:]
