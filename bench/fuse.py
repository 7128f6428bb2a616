"""Fuse and changes on a finished run of a synthetic survey, against its truth/ (the issue's figures).

    python -m bench.fuse SURVEY WORK [--out DIR] [--starts 100] [--labels]

Reads the latest room results (walls, preprocess, register) and the plan from WORK/cache, runs the fuse
and changes stages into DIR (default WORK/bench-fuse), and prints per room: correspondence source,
registration error against the derived true transform (tasks/fuse/truth.py), fit score, closure; the
thickness errors of both methods on walls captured from both sides; change precision and recall; with
--starts N the spread of the fine registration from N random starts within +-45 degrees and +-1 m.
--labels reads the plan rooms' labels on the plan raster (tasks/room_labels.py) when the plan stage has
none, and checks them against truth/planned_rooms.geojson.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.compute as pc
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
    """A copy of the plan's files whose rooms carry the label read on the plan raster (tasks/room_labels.py,
    what the plan stage will store), and how the labels compare with the as-planned truth."""
    from tasks.room_labels import read_room_labels

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
    figures = evaluate(args.survey, rooms, plan, fuse, changes, args.starts)
    figures["labels"] = label_check
    print(json.dumps(figures, indent=1, default=float))
    art.write_json(out / "figures.json", figures)
    return figures


def true_placement(room: str, results: dict, walls: np.ndarray, truth_dir: Path) -> Placement:
    """The derived true transform (tasks/fuse/truth.py)."""
    table = art.read_table(truth_dir / "walls.parquet")
    mine = table.filter(pc.equal(table["room_id"], room))
    tw = np.column_stack([mine[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
    start = Placement(0.0, (0.0, 0.0))
    if "register" in results and (truth_dir / "poses" / f"{room}.parquet").is_file():
        from tasks.fuse.stage import _camera_txy

        est = _camera_txy(results["register"].file("poses.parquet"), results.get("preprocess"))
        tru = art.read_table(truth_dir / "poses" / f"{room}.parquet").to_pydict()
        tt = np.asarray(tru["t_ns"], dtype=np.float64)
        k = np.abs(est[:, :1] - tt[None, :]).argmin(axis=1)  # float times: nearest within 1 ms
        ok = np.abs(tt[k] - est[:, 0]) < 1e6
        if ok.sum() >= 3:
            dst = np.column_stack([np.asarray(tru["tx"])[k[ok]], np.asarray(tru["ty"])[k[ok]]])
            start = T.rigid_fit(est[ok, 1:3], dst)
    return T.refine_on_walls(walls, tw, start)


def evaluate(survey: Path, rooms: dict, plan, fuse, changes, starts: int) -> dict[str, Any]:
    truth_dir = survey / "truth"
    report = art.read_json(fuse.file("fuse.json"))
    cfg = FuseConfig()
    out: dict[str, Any] = {"rooms": {}}
    for rid, rep in report["rooms"].items():
        row: dict[str, Any] = {
            k: rep.get(k)
            for k in (
                "plan_room",
                "source",
                "placed",
                "reason",
                "fit_score",
                "closed",
                "open_reason",
                "start",
            )
        }
        if rep.get("placed"):
            room = load_room(rid, rooms[rid], None)
            model = describe(room, cfg)
            true = true_placement(rid, rooms[rid], room.walls, truth_dir)
            est = Placement(math.radians(rep["theta_deg"]), tuple(rep["t_m"]))
            row.update(T.registration_error(est, true, model.centre))
            if starts:
                row.update(_spread(room, model, plan, rep, est, starts, cfg))
            # walls in the plan frame against the truth (the walls issue's figures)
            from tasks.evaluate import evaluate_walls

            table = art.read_table(truth_dir / "walls.parquet")
            mine = table.filter(pc.equal(table["room_id"], rid))
            tw = np.column_stack([mine[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
            segs, _ = art.read_segments(fuse.file(f"{rid}.walls.parquet"))
            ev = evaluate_walls(segs, tw)
            row.update({k: ev[k] for k in ("completeness", "correctness", "accuracy_mean_m")})
        out["rooms"][rid] = row
    # thickness
    tc, tt = art.read_segments(truth_dir / "plan_walls.parquet")
    tthick = tt["thickness_m"].to_numpy()
    faces = art.read_table(truth_dir / "walls.parquet")
    fsegs = np.column_stack([faces[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
    both = T.both_sides_truth(tc, tthick, fsegs, np.asarray(faces["room_id"].to_pylist()))
    fc, ft = art.read_segments(fuse.file("thickness.parquet"))
    for name, col in (("both_sides", "thickness_m"), ("residuals", "thickness_residuals_m")):
        err = T.thickness_errors(fc, ft[col].to_numpy(), tc, tthick)
        e = err[both & np.isfinite(err)]
        out[f"thickness_{name}"] = {
            "walls": len(e),
            "max_m": float(e.max()) if len(e) else None,
            "mean_m": float(e.mean()) if len(e) else None,
            "errors_m": e.round(4).tolist(),
        }
    pred = art.read_table(changes.file("changes.parquet")).to_pylist()
    true_changes = art.read_table(truth_dir / "changes.parquet").to_pylist()
    out["changes"] = T.change_scores(pred, true_changes)
    return out


def _spread(room, model, plan, rep, est: Placement, n: int, cfg: FuseConfig) -> dict[str, float]:
    """Fine registration from n random starts within +-45 degrees and +-1 m of the answer."""
    from tasks.fuse.place import room_faces

    plan_rooms, centrelines, _, doors = read_plan(plan)
    faces = room_faces({p.id: p for p in plan_rooms}, doors, centrelines, cfg)[rep["plan_room"]]
    rng = np.random.default_rng(0)
    shell = room.walls[model.shell]
    inward = model.inward[model.shell]
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
