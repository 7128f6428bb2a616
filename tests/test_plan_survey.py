"""Plan parsing on the generator's evacuation plans (issue 7 must-show): a synthetic survey's plan/plan.png
parsed at its stated scale against the as-planned truth the survey writes (truth/planned_walls.parquet,
truth/planned_rooms.geojson). The survey is data/mini (the generator's seed 0, as
`tasks.synth.survey.generate_survey` writes it): the plan draws the whole building whatever is surveyed, so
generating another survey for its plan would only repeat that work; test_plan.py parses plans drawn
straight from other seeds' buildings."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from shapely.geometry import shape

from tasks.artefacts import read_table
from tasks.evaluate import evaluate_walls
from tasks.plan.config import PlanConfig, PlanScale
from tasks.plan.parse import parse_plan
from tasks.plan.raster import load_plan_image

MINI = Path(__file__).resolve().parents[1] / "data" / "mini"


@pytest.mark.slow
def test_generator_plan_walls_and_rooms():
    out = MINI
    doc = yaml.safe_load((out / "survey.yaml").read_text())
    image = load_plan_image(out / doc["plan"]["image"])
    res = parse_plan(image, PlanScale(m_per_px=float(doc["plan"]["m_per_px"])), PlanConfig())

    t = read_table(out / "truth" / "planned_walls.parquet")
    truth = np.column_stack([t[c].to_numpy() for c in ("x0", "y0", "x1", "y1")])
    ev = evaluate_walls(res.walls, truth, tol_m=0.05)
    assert ev["completeness"] >= 0.95, ev
    assert ev["correctness"] >= 0.95, ev

    rooms = json.loads((out / "truth" / "planned_rooms.geojson").read_text())["features"]
    assert len(rooms) == 7  # hallway 100, 101-105 and the WC
    pred = [p for p, _ in res.rooms]
    for f in rooms:
        tp = shape(f["geometry"])
        best = max(pred, key=lambda p: p.intersection(tp).area)
        iou = best.intersection(tp).area / best.union(tp).area
        assert iou >= 0.95, (f["properties"]["plan_room"], iou)
    # every room found once: no parsed room is left over or split off
    assert len(pred) == len(rooms)
