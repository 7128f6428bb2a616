"""outputs/report.html: one self-contained page (pictures as data: URIs, inline SVG and CSS, no script, no
network) that a surveyor opens from a USB stick."""

from __future__ import annotations

import base64
import math
import re
from html import escape
from pathlib import Path
from typing import Any

from tasks.artefacts import BUILDING, ArtefactError, atomic_path, read_json, read_table
from tasks.report.gather import ReportData, RoomData, StageRow, gather
from tasks.report.svg import CHANGE_COLOURS, floor_svg, histogram_svg

REPORT = "report.html"

CHOICE = re.compile(
    r"alpha|threshold|reason|k_inv|chosen|auto|adapt|peak|floor_z|ceiling_z|slice_(low|high)|tilt|seed|"
    r"method|source|^start$|bridged_gap|orientations|fallback|outlier_reference|ambiguous|matching|applied|"
    r"downsample|working_m_per_px|drift_model"
)
"""Metric names that record a choice a stage made by itself (a parameter it adapted to the data)."""

STYLE = """
body{font:15px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1d1d1f;background:#fafafa}
header,main{max-width:1100px;margin:0 auto;padding:0 20px}
header{padding-top:18px}
h1{font-size:26px;margin:8px 0}h2{font-size:21px;margin:28px 0 8px;border-bottom:1px solid #ddd}
h3{font-size:16px;margin:18px 0 6px}
nav a{margin-right:14px}
section.room,section.block{background:#fff;border:1px solid #e3e3e3;border-radius:6px;padding:6px 18px 14px;
margin:16px 0}
table{border-collapse:collapse;margin:6px 0 10px;font-size:14px}
th,td{border-bottom:1px solid #eee;padding:3px 10px 3px 0;text-align:left;vertical-align:top}
td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:100%;height:auto;border:1px solid #e3e3e3}
.figs{display:flex;flex-wrap:wrap;gap:18px;align-items:flex-start}
.error{color:#b00020;font-weight:600}.note{color:#666}
.state-failed{color:#b00020}.state-computed{color:#0b6e2e}
#floor{max-width:100%;height:auto;background:#fff;border:1px solid #e3e3e3}
#floor .room{stroke:#b8c4d6;stroke-width:0.02}
#floor .room-label{font-size:0.45px;fill:#2a3b5a;text-anchor:middle}
#floor .wall{fill:#3b3b3b;stroke:none}#floor .wall[data-origin=gap_filled]{fill:#8a6d3b}
#floor .wall:hover{fill:#e67e22}
#floor .door{stroke:#1f6fd1;stroke-width:0.09;stroke-linecap:round}
#floor .door-plan{stroke:#9bbbe6;stroke-width:0.05}
#floor .change{stroke-width:0.16;stroke-linecap:round;opacity:0.85}
#floor .change-unknown{stroke-dasharray:0.25 0.15}
#floor .scale{stroke:#000;stroke-width:0.06}#floor .north{fill:#000}#floor .small{font-size:0.3px}
.histogram .hist-text{font-size:11px;fill:#333}
.swatch{display:inline-block;width:22px;height:8px;margin:0 6px 1px 14px;vertical-align:middle}
code{font-size:13px}
"""

TRUTH_FIGURES = (
    "completeness",
    "correctness",
    "accuracy_median_m",
    "accuracy_mean_m",
    "corner_f1",
    "angle_error_deg",
    "ate_2d_rmse_m",
    "scale_error_pct",
)
"""The figures against truth shown per room (metrics.json), in this order."""


def data_uri(path: Path) -> str:
    """A PNG file as a data: URI (the report carries its pictures)."""
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def fmt(value: Any) -> str:
    """A metric for people: 4 significant digits, short lists, no NaN."""
    if isinstance(value, bool) or value is None:
        return {True: "yes", False: "no", None: "-"}[value]
    if isinstance(value, float):
        if not math.isfinite(value):
            return "-"
        return f"{value:.4g}"
    if isinstance(value, list | tuple):
        shown = ", ".join(fmt(v) for v in value[:8])
        return f"[{shown}{', ...' if len(value) > 8 else ''}]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {fmt(v)}" for k, v in list(value.items())[:8]) + "}"
    return str(value)


def _table(rows: list[tuple[Any, ...]], head: tuple[str, ...], cls: str = "") -> str:
    out = [f'<table class="{cls}"><tr>' + "".join(f"<th>{escape(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        cells = []
        for v in row:
            text = v if isinstance(v, str) else fmt(v)
            num = isinstance(v, int | float) and not isinstance(v, bool)
            cells.append(f'<td class="num">{escape(text)}</td>' if num else f"<td>{escape(text)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    return "".join(out) + "</table>"


def automatic_choices(room: RoomData, fuse_room: dict[str, Any] | None) -> list[tuple[str, str, Any]]:
    """(stage, name, value) of every choice a stage of this room recorded as made by itself."""
    found = []
    for stage, row in room.stages.items():
        for name, value in row.metrics.items():
            if name in ("alpha_candidates", "timings", "timings_s", "warnings"):
                continue
            if isinstance(value, dict) and not CHOICE.search(name):
                for sub, v in value.items():
                    if CHOICE.search(sub) and not isinstance(v, dict | list):
                        found.append((stage, f"{name}.{sub}", v))
            elif CHOICE.search(name):
                found.append((stage, name, value))
    for name in ("source", "start", "ambiguous_turn", "doors_used", "theta_deg"):
        if fuse_room and name in fuse_room:
            found.append(("fuse", name, fuse_room[name]))
    return found


def room_figures(room: RoomData, floor_room: dict[str, Any] | None, fuse_room: dict[str, Any] | None) -> list:
    """(figure, value) rows: walls, closure, area, height, registration, placement into the plan."""
    walls, pre, reg = room.metrics("walls"), room.metrics("preprocess"), room.metrics("register")
    rows: list[tuple[str, Any]] = []
    if walls:
        rows.append(
            (
                "walls",
                f"{walls.get('walls', '-')} ({walls.get('walls_observed', '-')} observed, "
                f"{walls.get('walls_extended', '-')} extended)",
            )
        )
        rows.append(("closed", walls.get("closed")))
        rows.append(("floor area (room model)", f"{fmt(walls.get('room_area_m2'))} m²"))
    if floor_room and isinstance(floor_room.get("area_m2"), int | float):
        rows.append(("floor area (fused floor)", f"{fmt(floor_room['area_m2'])} m²"))
    if pre:
        rows.append(("height floor to ceiling", f"{fmt(pre.get('height_m'))} m"))
        rows.append(("points (in / kept)", f"{pre.get('points_in', '-')} / {pre.get('points_out', '-')}"))
    if reg:
        methods = reg.get("methods") or {}
        rows.append(
            (
                "SfM frames registered",
                f"{reg.get('sfm_registered', '-')} of {reg.get('frames', '-')} "
                f"(placed by SfM {methods.get('sfm', 0)}, IMU track {methods.get('track', 0)}, "
                f"none {methods.get('none', 0)})",
            )
        )
        check = reg.get("map_check") or {}
        if check.get("used"):
            why = f" ({check['why']})" if check.get("why") else ""
            rows.append(("map used", f"{check['used']}{why}"))
        if reg.get("fallback_reason"):
            rows.append(("fallback used", f"IMU track: {reg['fallback_reason']}"))
        drift = (reg.get("fallback") or {}).get("drift_model") or {}
        if "residual_spread_m" in drift:
            rows.append(("registration residual (track fit spread)", f"{fmt(drift['residual_spread_m'])} m"))
        scale = room.stages["register"].file("scale.json")
        if scale is not None:
            try:
                per_frame = read_json(scale).get("per_frame") or {}
                rms = sorted(float(v["rms_m"]) for v in per_frame.values() if "rms_m" in v)
                if rms:
                    rows.append(
                        (
                            "registration residual (depth vs SfM, median RMS per frame)",
                            f"{fmt(rms[len(rms) // 2])} m",
                        )
                    )
            except (ArtefactError, AttributeError, TypeError, ValueError, KeyError):
                pass
    elif "register" not in room.stages and room.stages:
        rows.append(("registration", "a registered cloud: none needed"))
    if fuse_room:
        if fuse_room.get("placed"):
            rows.append(
                (
                    "placed into the plan",
                    f"room {fuse_room.get('plan_room', '?')} by {fuse_room.get('source', '?')}, "
                    f"fit residual RMS {fmt(fuse_room.get('rms_m'))} m, score {fmt(fuse_room.get('fit_score'))}",
                )
            )
        else:
            rows.append(("placed into the plan", f"no: {fuse_room.get('reason', '')}"))
    return rows


def _histogram(room: RoomData) -> str:
    row = room.stages.get("preprocess")
    path = row.file("height_histogram.parquet") if row else None
    if path is None:
        return ""
    try:
        table = read_table(path)
        z_low, z_high, counts = (table[c].to_numpy() for c in ("z_low_m", "z_high_m", "count"))
    except (ArtefactError, KeyError) as exc:
        return f'<p class="note">height histogram unreadable: {escape(str(exc))}</p>'
    m = row.metrics
    marks = {
        name: float(m[key])
        for name, key in (("floor", "floor_z_m"), ("ceiling", "ceiling_z_m"))
        if isinstance(m.get(key), int | float)
    }
    band = None
    if isinstance(m.get("slice_low_z_m"), int | float) and isinstance(m.get("slice_high_z_m"), int | float):
        band = (float(m["slice_low_z_m"]), float(m["slice_high_z_m"]))
    return (
        "<figure><figcaption>height histogram (levelled cloud; slice shaded)</figcaption>"
        + histogram_svg(z_low, z_high, counts, marks, band)
        + "</figure>"
    )


def _room_section(
    data: ReportData, room: RoomData, floor_room: dict | None, fuse_room: dict | None, truth: dict | None
) -> str:
    title = f"Room {room.room}" + (f" (plan room {room.plan_room})" if room.plan_room else "")
    out = [f'<section class="room" id="room-{escape(room.room)}"><h2>{escape(title)}</h2>']
    if room.state == "failed":
        earlier = " The figures below are from the run that last computed it." if room.stages else ""
        out.append(f'<p class="error">failed: {escape(room.error)}</p>')
        if earlier:
            out.append(f'<p class="note">{escape(earlier.strip())}</p>')
    if not room.stages:
        out.append('<p class="note">no result of any run.</p></section>')
        return "".join(out)
    figures = room_figures(room, floor_room, fuse_room)
    out.append('<div class="figs"><div><h3>figures</h3>' + _table(figures, ("figure", "value")) + "</div>")
    out.append(_histogram(room) + "</div>")
    preview = data.work / "outputs" / "rooms" / room.room / "preview.png"
    if not preview.is_file() and "walls" in room.stages:
        preview = room.stages["walls"].file("preview.png") or preview
    if preview.is_file():
        out.append(
            f'<h3>wall model</h3><img src="{data_uri(preview)}" alt="walls of room {escape(room.room)}" '
            'loading="eager">'
        )
    choices = automatic_choices(room, fuse_room)
    if choices:
        out.append("<h3>automatic choices</h3>" + _table(choices, ("stage", "choice", "value")))
    walls = room.metrics("walls")
    if walls.get("warnings"):
        out.append('<p class="note">walls: ' + escape("; ".join(map(str, walls["warnings"]))) + "</p>")
    if truth:
        keep = TRUTH_FIGURES
        rows = [(k, truth[k]) for k in keep if k in truth]
        if rows:
            out.append("<h3>against truth</h3>" + _table(rows, ("figure", "value")))
    out.append("</section>")
    return "".join(out)


def _floor_section(data: ReportData) -> tuple[str, dict[str, dict], dict[str, dict]]:
    outputs = data.work / "outputs"
    floor_rooms: dict[str, dict] = {}
    fuse_rooms: dict[str, dict] = {}
    parts = ['<section class="block" id="floor-plan"><h2>Floor</h2>']
    path = outputs / "floor.geojson"
    if path.is_file():
        floor = read_json(path)
        changes_path = outputs / "changes.geojson"
        changes = read_json(changes_path) if changes_path.is_file() else None
        for feat in floor.get("features", []):
            props = feat.get("properties") or {}
            if props.get("kind") == "room":
                floor_rooms[str(props.get("room_id") or props.get("id"))] = props
        frame = floor.get("frame") or (floor.get("crs") or {}).get("properties", {}).get("name", "")
        parts.append(
            f"<p>The rooms fused into the plan ({escape(str(frame or 'plan frame, metres'))}). Walls at their "
            "thickness (hover for thickness, origin and support), doors in blue, changes:"
            + "".join(
                f'<span class="swatch" style="background:{c}"></span>{k}' for k, c in CHANGE_COLOURS.items()
            )
            + ". Click a room for its section.</p>"
        )
        parts.append(floor_svg(floor, changes))
        kinds = {}
        for feat in (changes or {}).get("features", []):
            kind = (feat.get("properties") or {}).get("kind", "unknown")
            kinds[kind] = kinds.get(kind, 0) + 1
        if changes is not None:
            parts.append(
                "<p>changes: " + (", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "none") + "</p>"
            )
    else:
        parts.append('<p class="note">no floor.geojson: the rooms were not fused into a plan.</p>')
    fuse_json = outputs / "fuse.json"
    if fuse_json.is_file():
        try:
            fuse_rooms = {str(k): v for k, v in (read_json(fuse_json).get("rooms") or {}).items()}
        except (ArtefactError, AttributeError):
            data.notes.append(f"{fuse_json}: unreadable")
    for name, caption in (
        ("changes.png", "changes against the plan"),
        ("plan_preview.png", "the coarse plan as read"),
    ):
        if (outputs / name).is_file():
            parts.append(f'<h3>{caption}</h3><img src="{data_uri(outputs / name)}" alt="{caption}">')
    parts.append("</section>")
    return "".join(parts), floor_rooms, fuse_rooms


def _accuracy_section(data: ReportData) -> str:
    if not data.metrics:
        return ""
    m = data.metrics
    parts = ['<section class="block" id="accuracy"><h2>Accuracy against truth</h2>']
    summary = m.get("summary") or {}
    parts.append(_table(sorted(summary.items()), ("figure (mean over rooms)", "value")))
    rooms = [r for r in m.get("rooms", []) if isinstance(r, dict)]
    keys = TRUTH_FIGURES
    rows = [
        (r.get("room", "?") + (" (earlier run)" if r.get("earlier_run") else ""), *(r.get(k) for k in keys))
        for r in rooms
    ]
    parts.append("<h3>rooms</h3>" + _table(rows, ("room", *keys)))
    fusion = m.get("fusion") or {}
    if fusion.get("rooms"):
        fk = (
            "registration_translation_m",
            "registration_rotation_deg",
            "completeness",
            "correctness",
            "accuracy_mean_m",
        )
        rows = [(rid, *(v.get(k) for k in fk)) for rid, v in fusion["rooms"].items()]
        parts.append("<h3>in the plan frame (after fusion)</h3>" + _table(rows, ("room", *fk)))
    for name in ("thickness_both_sides", "changes"):
        if isinstance(fusion.get(name), dict):
            rows = [(k, v) for k, v in fusion[name].items()]
            parts.append(f"<h3>{escape(name.replace('_', ' '))}</h3>" + _table(rows, ("figure", "value")))
    parts.append("</section>")
    return "".join(parts)


def _run_section(data: ReportData) -> str:
    run = data.run
    parts = ['<section class="block" id="run"><h2>The run</h2>']
    source = (
        "the run's manifest"
        if run["source"] == "manifest"
        else "the artefact store (this run wrote no manifest)"
    )
    parts.append(
        f"<p>run {escape(run['run_id'])}, finished {escape(run['finished'])}"
        + (", a partial run (some rooms)" if run["partial"] else "")
        + (f", config hash <code>{escape(run['config_hash'][:16])}</code>" if run["config_hash"] else "")
        + f"; read from {escape(source)}.</p>"
    )

    def state(row: StageRow) -> str:
        return row.state

    rows = [
        (
            "building" if r.room == BUILDING else r.room,
            r.stage,
            state(r),
            round(r.seconds, 2),
            round(float(r.manifest.get("compute_seconds") or 0.0), 2),
            r.key[:12],
            r.code_version,
            r.error,
        )
        for r in data.rows
    ]
    parts.append(
        "<h3>stages</h3>"
        + _table(
            rows,
            ("room", "stage", "state", "seconds (this run)", "seconds (when made)", "key", "code", "error"),
            "stages",
        )
    )
    if data.config_file is not None:
        if data.config_changes:
            parts.append(
                f'<h3>configuration differences from the defaults</h3><p class="note">{escape(str(data.config_file.relative_to(data.work)))} '
                "against configs/default.yaml</p>"
                + _table(data.config_changes, ("setting", "default", "this run"))
            )
        else:
            parts.append("<h3>configuration</h3><p>the defaults, unchanged.</p>")
    parts.append("<h3>versions</h3>" + _table(sorted(data.versions.items()), ("component", "version")))
    if data.notes:
        parts.append("<h3>notes</h3><ul>" + "".join(f"<li>{escape(n)}</li>" for n in data.notes) + "</ul>")
    parts.append("</section>")
    return "".join(parts)


def render(data: ReportData) -> str:
    """The whole page."""
    floor, floor_rooms, fuse_rooms = _floor_section(data)
    truth = {r.get("room"): r for r in (data.metrics or {}).get("rooms", []) if isinstance(r, dict)}
    failed = [r for r in data.rooms.values() if r.state == "failed"]
    rooms = "".join(
        _room_section(data, room, floor_rooms.get(rid), fuse_rooms.get(rid), truth.get(rid))
        for rid, room in data.rooms.items()
    )
    nav = " ".join(f'<a href="#room-{escape(r)}">{escape(r)}</a>' for r in data.rooms)
    failed_html = ""
    if failed:
        failed_html = (
            '<section class="block" id="failed"><h2>Rooms that failed</h2><ul>'
            + "".join(
                f'<li><a href="#room-{escape(r.room)}">{escape(r.room)}</a>: <span class="error">{escape(r.error)}</span></li>'
                for r in failed
            )
            + "</ul></section>"
        )
    title = f"Survey report: {Path(data.survey).name or data.work.name}"
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title><style>{STYLE}</style></head><body><header>"
        f"<h1>{escape(title)}</h1><p>work dir {escape(str(data.work))}: {len(data.rooms)} rooms, "
        f"{len(failed)} failed; run "
        f"{escape(data.run['run_id'])} finished {escape(data.run['finished'])}.</p>"
        f'<nav><a href="#floor-plan">floor</a>{" <a href=#failed>failed rooms</a>" if failed else ""} rooms: {nav} '
        f'{"<a href=#accuracy>accuracy</a> " if data.metrics else ""}<a href="#run">run</a></nav></header><main>'
        + failed_html
        + floor
        + rooms
        + _accuracy_section(data)
        + _run_section(data)
        + "</main></body></html>\n"
    )


def write_report(work: Path) -> Path:
    """Write WORK/outputs/report.html from what the work dir holds (nothing is recomputed); returns its
    path."""
    data = gather(Path(work))
    path = data.work / "outputs" / REPORT
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(render(data), encoding="utf-8")
    return path
