"""The framed previews (tasks.preview), the floor SVG and the report page (tasks.report) on small synthetic
work dirs with known answers, `indoor-survey report`, and report.html of a real run opened in headless
Chromium (Playwright driving the system's /usr/bin/chromium)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from flows.cli import main
from tasks import artefacts as art
from tasks.artefacts import ArtefactStore
from tasks.preview import TITLE_PX, Key, View, frame_picture, retitle, tick_step
from tasks.report import write_report
from tasks.report.gather import RoomData, StageRow, gather
from tasks.report.page import room_figures
from tasks.report.svg import face_support, floor_svg, wall_outline

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")

# ------------------------------------------------------------------------------------------- previews


def _colour_in(img: np.ndarray, colour: tuple[int, int, int]) -> bool:
    return bool(np.all(img == np.array(colour, np.uint8), axis=2).any())


def test_frame_copies_the_drawing_and_adds_title_axes_legend_and_bar() -> None:
    drawing = np.full((200, 300, 3), 255, np.uint8)
    drawing[50:60, 100:200] = (10, 200, 30)
    view = View(x0_m=-1.0, y_top_m=2.0, m_per_px=0.02)  # 6 m x 4 m, 1 m = 50 px
    framed = frame_picture(drawing, view, "room r9: walls", [Key("green thing", (10, 200, 30))])
    # the drawing sits unchanged below the title band, right of the y axis labels
    top, left = TITLE_PX, 70
    assert np.array_equal(framed[top : top + 200, left : left + 300], drawing)
    assert np.any(framed[:TITLE_PX] < 128)  # a title was written
    panel = framed[:, left + 300 :]
    assert _colour_in(panel, (10, 200, 30))  # the legend shows the colour used
    # the 1 m bar: a black run of 1 / 0.02 = 50 px (+1 for the end ticks) in the panel
    black_runs = [int(np.all(row == 0, axis=1).sum()) for row in panel]
    assert max(black_runs) in (50, 51)
    # ticks every 1 m (>= 70 px apart at 50 px/m is 2 m): labels under the x axis
    assert tick_step(0.02) == 2.0
    assert np.any(framed[top + 200 + 8 : top + 200 + 22, left : left + 300] < 128)
    assert np.array_equal(
        frame_picture(drawing, view, "room r9: walls", [Key("g", (10, 200, 30))]),
        frame_picture(drawing, view, "room r9: walls", [Key("g", (10, 200, 30))]),
    )


def test_retitle_changes_only_the_title_band() -> None:
    drawing = np.full((120, 160, 3), 200, np.uint8)
    framed = frame_picture(drawing, View(0.0, 1.2, 0.01), "walls", [])
    again = retitle(framed, "room hall: walls")
    assert not np.array_equal(again[:TITLE_PX], framed[:TITLE_PX])
    assert np.array_equal(again[TITLE_PX - 1 :], framed[TITLE_PX - 1 :])
    with pytest.raises(ValueError, match="not a picture framed"):
        retitle(np.full((50, 50, 3), 255, np.uint8), "x")


def test_a_large_drawing_gets_larger_text_and_a_view_needs_a_scale() -> None:
    big = frame_picture(np.full((1500, 1500, 3), 255, np.uint8), View(0, 15, 0.01), "t", [])
    small = frame_picture(np.full((500, 500, 3), 255, np.uint8), View(0, 5, 0.01), "t", [])
    assert big.shape[0] - 1500 > small.shape[0] - 500  # wider bands around the larger drawing
    with pytest.raises(ValueError, match="positive"):
        View(0, 0, 0.0)


def test_walls_preview_has_a_legend_entry_for_each_colour_drawn_and_only_those() -> None:
    from tasks.walls.image import Grid
    from tasks.walls.model import EXTENDED_WALL, OBSERVED_WALL, WALL_END, render_preview

    counts = np.zeros((100, 120))
    counts[10, 10:110] = 5
    binary = counts > 0
    grid = Grid(np.array([0.0, 0.0]), 0.05, (100, 120))
    walls = np.array([[0.5, 0.525, 5.5, 0.525], [5.5, 0.525, 5.5, 4.0]])
    both = render_preview(
        counts, binary, walls, np.array(["observed", "extended"]), grid, title="room a: walls"
    )
    only = render_preview(counts, binary, walls[:1], np.array(["observed"]), grid)
    for img in (both, only):
        panel = img[:, -180:]  # the legend panel, right of the drawing
        assert _colour_in(panel, OBSERVED_WALL) and _colour_in(panel, WALL_END)
    assert _colour_in(both[:, -180:], EXTENDED_WALL)
    assert not _colour_in(only, EXTENDED_WALL)
    assert both.shape[1] >= 70 + 120 * 7 + 180  # enlarged 7x to at least 800 px, then framed


def test_walls_preview_axes_put_a_wall_at_its_metres() -> None:
    from tasks.walls.image import Grid
    from tasks.walls.model import OBSERVED_WALL, render_preview

    grid = Grid(np.array([-1.0, 2.0]), 0.05, (100, 120))  # x -1..5, y 2..7 m, enlarged 7x: 1 px = 1/140 m
    wall = np.array([[1.0, 3.0, 1.0, 6.0]])  # north-south at x = 1 m, y 3..6 m
    img = render_preview(np.zeros((100, 120)), np.zeros((100, 120), bool), wall, np.array(["observed"]), grid)
    drawing = img[TITLE_PX : TITLE_PX + 700, 70 : 70 + 840]  # 1x frame: the drawing at (36, 70)
    rows, cols = np.nonzero(np.all(drawing == np.array(OBSERVED_WALL, np.uint8), axis=2))
    m_per_px = 0.05 / 7
    assert -1.0 + (cols.mean() + 0.5) * m_per_px == pytest.approx(1.0, abs=0.02)
    assert 7.0 - (rows.min() + 0.5) * m_per_px == pytest.approx(6.0, abs=0.05)  # y up: north at the top
    assert 7.0 - (rows.max() + 0.5) * m_per_px == pytest.approx(3.0, abs=0.05)


def test_changes_overlay_legend_lists_the_kinds_present() -> None:
    from tasks.changes.detect import ADDED, Change
    from tasks.changes.overlay import GREEN, RED, overlay_png

    centre = np.array([[0, 0, 4, 0], [4, 0, 4, 3]], float)
    added = Change(1.0, 1.0, 3.0, 1.0, ADDED, "r1", 1.0, 0.5)
    img = overlay_png(centre, np.array([0.2, 0.2]), {}, [added], [])
    panel = img[:, 70 + (4 + 2) * 40 + 1 :]
    assert _colour_in(panel, GREEN)
    assert not _colour_in(img, RED)


# ------------------------------------------------------------------------------------------- floor svg


def test_wall_outline_and_face_support_known_answers() -> None:
    outline = wall_outline(np.array([0.0, 0.0, 2.0, 0.0]), 0.2)
    assert np.allclose(outline, [[0, 0.1], [2, 0.1], [2, -0.1], [0, -0.1]])
    wall = np.array([0.0, 0.0, 2.0, 0.0])
    half_seen = np.array([[0.0, 0.1, 1.0, 0.1]])  # a room face along the first half, at the wall's face
    assert face_support(wall, 0.2, half_seen) == pytest.approx(0.5, abs=0.03)
    assert face_support(wall, 0.2, np.array([[0.0, 0.5, 2.0, 0.5]])) == 0.0  # 0.5 m off: another wall
    assert face_support(wall, 0.2, np.array([[1.0, -1.0, 1.0, 1.0]])) == 0.0  # across it
    assert face_support(wall, 0.2, np.zeros((0, 4))) == 0.0


def _line(coords, **props):
    return {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords}, "properties": props}


def _floor() -> dict:
    room = {
        "type": "Feature",
        "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 3], [0, 3], [0, 0]]]},
        "properties": {"kind": "room", "room_id": "r1", "plan_room": "R1", "area_m2": 12.0, "closed": True},
    }
    walls = [
        _line([[-0.1, -0.1], [4.1, -0.1]], kind="wall", thickness_m=0.2, origin="plan", room_left="r1"),
        _line([[4.1, -0.1], [4.1, 3.1]], kind="wall", thickness_m=0.2, origin="plan", room_left="r1"),
        _line([[0, 1.5], [2, 1.5]], kind="wall", thickness_m=0.1, origin="observed", support=0.8),
    ]
    faces = [_line([[0, 0], [4, 0]], kind="wall_face", room_id="r1", origin="observed")]
    doors = [_line([[1, 3], [1.9, 3]], kind="door", room_id="r1", source="model")]
    return {
        "type": "FeatureCollection",
        "features": [room, *walls, *faces, *doors],
        "frame": "plan frame (m)",
    }


def test_floor_svg_has_one_wall_element_per_wall_with_its_tooltip() -> None:
    changes = {
        "type": "FeatureCollection",
        "features": [_line([[0, 1.5], [2, 1.5]], kind="added", room_id="r1")],
    }
    svg = floor_svg(_floor(), changes)
    walls = re.findall(r'<polygon class="wall"[^>]*><title>([^<]*)</title>', svg)
    assert len(walls) == 3
    assert "thickness 20.0 cm" in walls[0] and "origin plan" in walls[0]
    # the room's face runs along the south wall but for the 10 cm at either end (corners): 4.0 of 4.2 m
    assert 90 <= int(re.search(r"support (\d+)%", walls[0]).group(1)) <= 96
    assert "support 0%" in walls[1]  # nothing seen along the east wall
    assert "support 80%" in walls[2]  # a support the floor gives is shown as given
    assert svg.count('class="change change-added"') == 1 and 'stroke="#17a02a"' in svg
    assert svg.count('class="door door-model"') == 1
    assert 'href="#room-r1"' in svg


# ------------------------------------------------------------------------------------ synthetic work dirs


def _commit(store: ArtefactStore, room: str, stage: str, key: str, files: dict, metrics: dict, inputs: dict):
    def write(out: Path) -> dict:
        for name, data in files.items():
            (out / name).write_bytes(data)
        return {"metrics": metrics, "compute_seconds": 1.5}

    return store.commit(
        room, stage, key, write, {"inputs": inputs, "config": {}, "code_version": f"code-{stage}"}
    )


def _png(value: int) -> bytes:
    return art.encode_png(np.full((8, 12, 3), value, np.uint8))


def _histogram_bytes(path: Path) -> bytes:
    z = np.arange(-0.1, 2.8, 0.02)
    counts = np.where((np.abs(z) < 0.03) | (np.abs(z - 2.6) < 0.03), 500, 20).astype(np.int64)
    art.write_table(path, {"z_low_m": z, "z_high_m": z + 0.02, "count": counts})
    return path.read_bytes()


def synthetic_work(tmp_path: Path) -> Path:
    """A work dir two rooms left: r1 done (its walls run twice: the published one is the older), r2 with no
    result; floor_index's rooms.parquet and a fused floor.geojson."""
    work = tmp_path / "work"
    store = ArtefactStore(work)
    hist = _histogram_bytes(tmp_path / "h.parquet")
    pre_metrics = {
        "floor_z_m": 0.0,
        "ceiling_z_m": 2.6,
        "height_m": 2.6,
        "slice_low_z_m": 1.5,
        "slice_high_z_m": 2.5,
        "outlier_threshold_m": 0.055,
        "points_in": 100,
        "points_out": 90,
    }
    pre = _commit(store, "r1", "preprocess", "k-pre", {"height_histogram.parquet": hist}, pre_metrics, {})
    walls_metrics = {
        "walls": 4,
        "walls_observed": 4,
        "walls_extended": 0,
        "closed": True,
        "room_area_m2": 12.0,
        "alpha": 0.15,
        "alpha_reason": "stable over 3 of 8 candidates",
    }
    published = _commit(
        store,
        "r1",
        "walls",
        "k-walls-a",
        {"preview.png": _png(90), "model.ply": b"ply a"},
        walls_metrics,
        {"preprocess": pre.content_hash},
    )
    _commit(
        store,
        "r1",
        "walls",
        "k-walls-b",
        {"preview.png": _png(180), "model.ply": b"ply b"},
        {**walls_metrics, "alpha": 0.4},
        {"preprocess": pre.content_hash},
    )  # newer, never published
    for name in ("preview.png", "model.ply"):
        store.publish(published.file(name), "rooms", "r1", name)
    art.write_table(
        store.outputs / "rooms.parquet",
        {
            "room_id": ["r1", "r2"],
            "plan_room": ["101", "102"],
            "error": [None, "ingest: capture.mcap: truncated"],
        },
    )
    art.write_json(store.outputs / "floor.geojson", _floor())
    runs = work / "runs" / "20260101T000000"
    runs.mkdir(parents=True)
    from tasks import config as cfgmod

    cfg = cfgmod.load_config([], ["walls.alpha_candidates=[0.1, 0.2]"])
    (runs / "config.yaml").write_text("# indoor-survey run s\n" + cfgmod.to_yaml(cfg))
    return work


def test_the_report_reads_the_published_folders_and_shows_every_room(tmp_path) -> None:
    work = synthetic_work(tmp_path)
    data = gather(work)
    assert list(data.rooms) == ["r1", "r2"]
    r1 = data.rooms["r1"]
    assert r1.stages["walls"].key == "k-walls-a"  # the published one, not the newest folder
    assert r1.stages["preprocess"].key == "k-pre"  # found through the walls folder's input hash
    assert data.rooms["r2"].state == "failed" and "truncated" in data.rooms["r2"].error
    assert [(k, r) for k, _, r in data.config_changes] == [("walls.alpha_candidates", "[0.1, 0.2]")]
    page = write_report(work).read_text()
    assert re.findall(r'<section class="room" id="room-([^"]+)"', page) == ["r1", "r2"]
    assert "capture.mcap: truncated" in page and 'id="failed"' in page
    assert "stable over 3 of 8 candidates" in page and "outlier_threshold_m" in page
    assert page.count('class="wall"') == 3
    assert '<svg class="histogram"' in page and "ceiling 2.60 m" in page
    # self-contained: every picture embedded, no script, no stylesheet or font fetched
    srcs = re.findall(r'<img src="([^"]*)"', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "<script" not in page and "<link" not in page and "url(" not in page
    assert not re.search(r"(?:src|href)=\"(?:https?:)?//", page)
    assert "walls.alpha_candidates" in page
    assert "<h1>Survey report: s</h1>" in page  # the survey the run read, from its saved config


def test_a_run_manifest_gives_states_errors_and_versions(tmp_path) -> None:
    work = synthetic_work(tmp_path)
    manifest = {
        "run_id": "run-7",
        "finished": "2026-01-01T00:10:00Z",
        "config_hash": "abc123",
        "partial": True,
        "stages": [
            {
                "room": "r1",
                "stage": "walls",
                "state": "cached",
                "seconds": 0.0,
                "error": "",
                "key": "k-walls-b",
                "run_id": "run-6",
                "config_hash": "abc123",
            },
            {
                "room": "r2",
                "stage": "ingest",
                "state": "failed",
                "seconds": 0.2,
                "error": "capture.mcap: bad",
                "key": "",
                "run_id": "run-7",
                "config_hash": "abc123",
            },
        ],
        "rooms": {
            "r1": {"run_id": "run-6", "config_hash": "abc123", "state": "done", "error": ""},
            "r2": {"run_id": "run-7", "config_hash": "abc123", "state": "failed", "error": "ingest: bad"},
        },
        "versions": {"indoor-survey": "9.9.9", "python": "3.11", "numpy": "2"},
    }
    art.write_json(work / "outputs" / "manifest.json", manifest)
    data = gather(work)
    assert data.rooms["r1"].stages["walls"].key == "k-walls-b"  # the manifest names the folder
    assert data.rooms["r1"].stages["walls"].metrics["alpha"] == 0.4
    assert data.rooms["r2"].error == "ingest: bad"
    assert any(r.stage == "ingest" and r.state == "failed" for r in data.rows)
    page = write_report(work).read_text()
    assert "9.9.9" in page and "a partial run" in page and "run-7" in page
    art.write_json(work / "outputs" / "manifest.json", ["not", "a", "manifest"])
    with pytest.raises(art.ArtefactError, match=r"manifest\.json: not a run manifest"):
        gather(work)


def test_report_command(tmp_path, capsys) -> None:
    work = synthetic_work(tmp_path)
    before = {p: p.stat().st_mtime_ns for p in (work / "cache").rglob("*")}
    assert main(["report", str(work)]) == 0
    assert {p: p.stat().st_mtime_ns for p in (work / "cache").rglob("*")} == before  # nothing recomputed
    assert (work / "outputs" / "report.html").is_file()
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    assert "no such folder" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(empty)]) == 2
    assert "not the work dir" in capsys.readouterr().err


# -------------------------------------------------------------------------------------------- browser


def _chromium_or_skip() -> None:
    message = ""
    if not CHROMIUM.exists():
        message = f"{CHROMIUM} is absent (Debian package chromium; .ci/setup installs it)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            message = "playwright is not installed (the test extra)"
    if message:
        if os.environ.get("INDOOR_SURVEY_REQUIRE_REALDATA") == "1":
            pytest.fail(message + " and INDOOR_SURVEY_REQUIRE_REALDATA=1")
        pytest.skip(message)


@pytest.mark.slow
def test_report_of_the_mini_run_in_a_real_browser(mini_run, tmp_path) -> None:
    """report.html of data/mini opened in headless Chromium: a section per room, every picture decoded, one
    SVG wall element per wall of floor.geojson, no console error, nothing fetched from the network."""
    _chromium_or_skip()
    from playwright.sync_api import sync_playwright

    _, work = mini_run
    path = write_report(work)
    rooms = [r["id"] for r in yaml.safe_load((REPO / "data" / "mini" / "survey.yaml").read_text())["rooms"]]
    floor = art.read_json(work / "outputs" / "floor.geojson")
    walls = sum(1 for f in floor["features"] if f["properties"].get("kind") == "wall")
    errors: list[str] = []
    fetched: list[str] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 1000})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("request", lambda r: fetched.append(r.url))
            page.goto(path.as_uri(), wait_until="load")
            sections = page.eval_on_selector_all("section.room", "els => els.map(e => e.id)")
            images = page.eval_on_selector_all(
                "img", "els => els.map(e => [e.complete, e.naturalWidth, e.alt])"
            )
            svg_walls = page.eval_on_selector_all("svg#floor .wall", "els => els.length")
            tooltip = page.eval_on_selector("svg#floor .wall title", "e => e.textContent")
            shot = tmp_path / "report.png"
            page.screenshot(path=str(shot))
        finally:
            browser.close()
    assert sorted(sections) == sorted(f"room-{r}" for r in rooms)
    assert len(images) >= len(rooms) + 1
    assert all(complete and width > 0 for complete, width, _ in images), images
    assert svg_walls == walls > 0
    assert "thickness" in tooltip and "origin" in tooltip and "support" in tooltip
    assert errors == []
    assert all(u.startswith(("file:", "data:")) for u in fetched), fetched
    assert 0 < shot.stat().st_size < 500_000
    if os.environ.get("INDOOR_SURVEY_WRITE_DOCS") == "1":  # refresh the README's picture
        shutil.copyfile(shot, REPO / "docs" / "report.png")


def test_room_figures_say_which_map_was_used_and_why() -> None:
    check = {"used": "sfm seed 1", "why": "seed 0: 000007.png disagrees with its neighbours' depth"}
    row = StageRow(
        "r1", "register", "computed", 1.0, manifest={"metrics": {"frames": 24, "map_check": check}}
    )
    figures = dict(room_figures(RoomData("r1", {"register": row}), None, None))
    assert figures["map used"] == "sfm seed 1 (seed 0: 000007.png disagrees with its neighbours' depth)"
