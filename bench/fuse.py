"""Fuse and changes on a finished run of a synthetic survey, against its truth/ (the issue's figures).

    python -m bench.fuse SURVEY WORK [--out DIR] [--starts 100] [--labels]

Reads the latest room results (walls, preprocess, register) and the plan from WORK/cache, runs the fuse
and changes stages into DIR (default WORK/bench-fuse), and prints per room: correspondence source,
registration error against the derived true transform (tasks/fuse/truth.py), fit score, closure; the
thickness errors of both methods on walls captured from both sides; change precision and recall; with
--starts N the spread of the fine registration from N random starts within +-45 degrees and +-1 m.
--labels reads the plan rooms' labels on the plan raster (tasks/plan/labels.py) when the plan stage has
none, and checks them against truth/planned_rooms.geojson.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from shapely.geometry import Point, shape

from tasks import artefacts as art
from tasks.changes.config import ChangesConfig
from tasks.changes.stage import run as run_changes
from tasks.context import StageContext
from tasks.fuse import truth as T
from tasks.fuse.config import FuseConfig
from tasks.fuse.place import describe
from tasks.fuse.register2d import Placement, fine_register
from tasks.fuse.stage import load_room, read_plan
from tasks.fuse.stage import run as run_fuse
from tasks.fuse.truth import fusion_figures


def _result(folder: Path, room: str, stage: str) -> art.StageResult:
    files = {
        p.name: art.sha256_file(p) for p in folder.iterdir() if p.is_file() and p.name != "manifest.json"
    }
    return art.StageResult(room, stage, "bench", str(folder), files, art.hash_json(files))


def _run_stage(run, ctx: StageContext, cfg: Any, out: Path, room: str, stage: str) -> art.StageResult:
    out.mkdir(parents=True, exist_ok=True)
    report = run(ctx, cfg, out)
    art.write_json(out / "manifest.json", report)
    return _result(out, room, stage)


def _labelled_plan(plan: art.StageResult, survey: Path, doc: dict, out: Path) -> tuple[art.StageResult, dict]:
    """A copy of the plan's files whose rooms carry the label read on the plan raster (tasks/plan/labels.py,
    what the plan stage will store), and how the labels compare with the as-planned truth."""
    from tasks.plan.labels import read_room_labels

    out.mkdir(parents=True, exist_ok=True)
    data = art.read_json(plan.file("rooms.geojson"))
    polys = [f for f in data["features"] if f["geometry"]["type"] == "Polygon"]
    image = art.read_image(survey / doc["plan"]["image"])
    labels = read_room_labels(image, [shape(f["geometry"]) for f in polys], float(doc["plan"]["m_per_px"]))
    planned = art.read_json(survey / "truth" / "planned_rooms.geojson")["features"]
    check = {}
    for f, label in zip(polys, labels, strict=True):
        f["properties"]["label"] = label
        p = shape(f["geometry"]).representative_point()
        printed = next(
            (g["properties"]["plan_room"] for g in planned if shape(g["geometry"]).contains(Point(p))), None
        )
        check[f["properties"]["room_id"]] = {"read": label, "printed": printed, "ok": label == printed}
    art.write_json(out / "rooms.geojson", data)
    (out / "plan_walls.parquet").write_bytes(plan.file("plan_walls.parquet").read_bytes())
    return _result(out, art.BUILDING, "plan"), check


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser()
    ap.add_argument("survey", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--starts", type=int, default=0)
    ap.add_argument("--labels", action="store_true")
    args = ap.parse_args(argv)
    store = art.ArtefactStore(args.work)
    out = args.out or args.work / "bench-fuse"
    survey = yaml.safe_load((args.survey / "survey.yaml").read_text())
    plan = store.latest(art.BUILDING, "plan")
    assert plan is not None, "no plan result in the work dir"
    label_check = None
    if args.labels:
        plan, label_check = _labelled_plan(plan, args.survey, survey, out / "plan")
    rooms = {}
    for entry in survey["rooms"]:
        res = {s: store.latest(entry["id"], s) for s in ("ingest", "register", "preprocess", "walls")}
        rooms[entry["id"]] = {s: r for s, r in res.items() if r is not None}
    params = {"rooms": [{"id": r["id"], "plan_room": r.get("plan_room")} for r in survey["rooms"]]}
    raw = {"track": str(args.survey / survey["track"])} if survey.get("track") else {}
    ctx = StageContext(art.BUILDING, {"plan": plan}, raw, {}, print, params=params, rooms=rooms)
    fuse = _run_stage(run_fuse, ctx, FuseConfig(), out / "fuse", art.BUILDING, "fuse")
    ctx2 = StageContext(art.BUILDING, {"plan": plan, "fuse": fuse}, {}, {}, print)
    changes = _run_stage(run_changes, ctx2, ChangesConfig(), out / "changes", art.BUILDING, "changes")
    figures = fusion_figures(args.survey / "truth", rooms, fuse, changes)
    if args.starts:
        report = art.read_json(fuse.file("fuse.json"))
        for rid, rep in report["rooms"].items():
            if rep.get("placed"):
                room = load_room(rid, rooms[rid], None)
                est = Placement(math.radians(rep["theta_deg"]), tuple(rep["t_m"]))
                figures["rooms"][rid].update(
                    _spread(room, describe(room, FuseConfig()), plan, rep, est, args.starts, FuseConfig())
                )
    figures["labels"] = label_check
    print(json.dumps(figures, indent=1, default=float))
    art.write_json(out / "figures.json", figures)
    return figures


def _spread(room, model, plan, rep, est: Placement, n: int, cfg: FuseConfig) -> dict[str, float]:
    """Fine registration from n random starts within +-45 degrees and +-1 m of the answer."""
    from tasks.fuse.place import room_faces

    plan_rooms, centrelines, _, doors = read_plan(plan)
    faces = room_faces({p.id: p for p in plan_rooms}, doors, centrelines, cfg)[rep["plan_room"]]
    rng = np.random.default_rng(0)
    shell = room.walls[model.shell]
    inward = model.inward[model.shell]
    est = fine_register(shell, inward, model.centre, faces, est, cfg).placement  # the same fit without doors
    dth, dt = [], []
    for _ in range(n):
        turn = math.radians(rng.uniform(-45, 45))
        start = est.then(turn, est.points(model.centre)[0], rng.uniform(-1, 1, 2))
        fit = fine_register(shell, inward, model.centre, faces, start, cfg)
        err = T.registration_error(fit.placement, est, model.centre)
        dth.append(err["registration_rotation_deg"])
        dt.append(err["registration_translation_m"])
    return {
        "starts": n,
        "spread_rotation_deg_max": max(dth),
        "spread_translation_m_max": max(dt),
        "starts_within_1cm_0.1deg": int(
            sum(1 for a, b in zip(dth, dt, strict=True) if a <= 0.1 and b <= 0.01)
        ),
    }


if __name__ == "__main__":
    main()
