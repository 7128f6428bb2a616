"""Fusion and change figures against a synthetic survey's truth/ (metrics.json, bench/fuse.py).

The truth carries no room transform, so it is derived: a registered room's model lives in its levelled
room frame; the true transform of that frame into the plan is the 2D rigid fit of the estimated camera
track (levelled) onto the true one (truth/poses), refined on the true inner faces (truth/walls.parquet)
as eq 7.4 and 7.9 split it: the rotation that makes the model's walls parallel to their true faces, the
least-squares translation of their samples onto the faces' lines (`refine_on_walls`): the placement that
puts this model where its walls truly are, also where the wall model differs from the building (a
straight wall through a jog of its face, a corridor a percent too long). Rooms given in a meaningful frame start from the identity.
Registration error = the fused placement against that one, as the rotation difference and the distance
between where the two put the model's centroid.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.compute as pc
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from tasks import artefacts as art
from tasks.evaluate import evaluate_walls
from tasks.fuse.config import FuseConfig
from tasks.fuse.place import describe
from tasks.fuse.register2d import Placement
from tasks.fuse.stage import _camera_txy, load_room
from tasks.lines import (
    Segments,
    angle_difference,
    angles,
    as_segments,
    lengths,
    point_segment_distances,
    sample_segments,
)


def rigid_fit(src: NDArray, dst: NDArray) -> Placement:
    """Least-squares rigid 2D placement of src (N, 2) onto dst (N, 2)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    h = (src - ms).T @ (dst - md)
    theta = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(theta), math.sin(theta)
    t = md - np.array([[c, -s], [s, c]]) @ ms
    return Placement(theta, (float(t[0]), float(t[1])))


def refine_on_walls(
    pred: Segments,
    truth: Segments,
    start: Placement,
    tol_m: float = 0.20,
    parallel_deg: float = 5.0,
    iterations: int = 50,
) -> Placement:
    """The placement of the model walls (from `start`) onto the true faces, as the thesis splits it
    (eq 7.4, 7.9): the rotation that makes the model walls parallel to the true faces they lie along
    (the length-weighted mean of the orientation differences), then the least-squares translation of the
    walls' 2 cm samples onto those faces' lines; every sample within tol_m of a true face that is
    parallel to its wall within parallel_deg takes part, iterated until nothing moves.

    A joint rigid fit of the samples (springs) is biased where the wall model differs from the building:
    a corridor wall modelled straight through a 6.5 cm jog of its true face tilts the whole room by the
    jog over the corridor's length (0.15-0.2 degrees, though every model wall is parallel to its face),
    and a corridor modelled a percent too long would be pinned at one end; here the orientation comes
    from the walls' directions alone and the translation splits a length error between the ends."""
    walls = as_segments(pred)
    pts, owner = sample_segments(walls, 0.02)
    wall_angle = angles(walls)[owner]
    truth = as_segments(truth)
    truth_angle = angles(truth)
    placement = start
    for _ in range(iterations):
        q = placement.points(pts)
        d = point_segment_distances(q, truth)
        k = d.argmin(axis=1)
        diff = angle_difference(truth_angle[k], wall_angle + placement.theta)
        near = (d[np.arange(len(q)), k] <= tol_m) & (np.abs(diff) <= math.radians(parallel_deg))
        if near.sum() < 10:
            break
        d_theta = float(diff[near].mean())
        placement = placement.then(d_theta, q[near].mean(axis=0), np.zeros(2))
        q = placement.points(pts[near])
        seg = truth[k[near]]
        u = (seg[:, 2:] - seg[:, :2]) / np.maximum(lengths(seg), 1e-12)[:, None]
        n = np.column_stack([-u[:, 1], u[:, 0]])
        f = ((q - seg[:, :2]) * n).sum(1)
        shift = np.linalg.lstsq(n, -f, rcond=None)[0]
        placement = placement.then(0.0, np.zeros(2), shift)
        if abs(d_theta) < 1e-10 and np.abs(shift).max() < 1e-9:
            break
    return placement


def registration_error(est: Placement, true: Placement, centre: NDArray) -> dict[str, float]:
    """Rotation difference (degrees) and the distance between where the two placements put `centre` (m)."""
    d = math.degrees(math.atan2(math.sin(est.theta - true.theta), math.cos(est.theta - true.theta)))
    shift = est.points(centre)[0] - true.points(centre)[0]
    return {"registration_rotation_deg": abs(d), "registration_translation_m": float(np.hypot(*shift))}


def thickness_errors(
    centrelines: Segments,
    thickness_m: NDArray,
    truth_centrelines: Segments,
    truth_thickness: NDArray,
    tol_m: float = 0.10,
) -> NDArray[np.float64]:
    """(K,) |fused - true| thickness of every truth wall matched to the fused plan wall lying along most
    of it within tol_m (NaN where none)."""
    centrelines, truth = as_segments(centrelines), as_segments(truth_centrelines)
    out = np.full(len(truth), np.nan)
    if len(centrelines) == 0:
        return out
    pts, owner = sample_segments(truth, 0.05)
    d = point_segment_distances(pts, centrelines)
    k, dmin = d.argmin(axis=1), d.min(axis=1)
    for i in range(len(truth)):
        m = (owner == i) & (dmin <= tol_m)
        if m.sum() >= 3:
            out[i] = abs(float(thickness_m[np.bincount(k[m]).argmax()]) - float(truth_thickness[i]))
    return out


def both_sides_truth(
    truth_centrelines: Segments, truth_thickness: NDArray, truth_faces: Segments, face_rooms: NDArray
) -> NDArray[np.bool_]:
    """(K,) truth walls with a true inner face of a surveyed room on each side (captured from both)."""
    out = np.zeros(len(truth_centrelines), dtype=bool)
    faces = as_segments(truth_faces)
    for i, (c, t) in enumerate(zip(as_segments(truth_centrelines), truth_thickness, strict=True)):
        a, b = c[:2], c[2:]
        u = (b - a) / max(float(np.hypot(*(b - a))), 1e-12)
        n = np.array([-u[1], u[0]])
        mids = 0.5 * (faces[:, :2] + faces[:, 2:])
        off = (mids - a) @ n
        along = (mids - a) @ u
        par = (
            np.abs(
                np.abs(((faces[:, 2:] - faces[:, :2]) / np.maximum(lengths(faces), 1e-12)[:, None]) @ u) - 1
            )
            < 1e-3
        )
        on = par & (np.abs(np.abs(off) - t / 2) < 0.02) & (along > 0) & (along < np.hypot(*(b - a)))
        rooms_left = set(face_rooms[on & (off > 0)])
        rooms_right = set(face_rooms[on & (off < 0)])
        out[i] = bool(rooms_left and rooms_right and rooms_left != rooms_right)
    return out


def knowable_samples(
    truth_faces: Segments,
    cloud_xy: NDArray | None,
    added: Segments,
    step_m: float = 0.01,
    seen_tol_m: float = 0.05,
    min_points: int = 10,
    added_tol_m: float = 0.10,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The truth faces' step_m samples and which of them a fused model can be asked for: every sample a
    plan wall stands on (gap filling supplies it from the plan's shell where the capture did not look)
    and every sample of a wall the plan does not hold (an added wall's face, within added_tol_m of a true
    "added" change's centreline) that the capture saw: at least min_points of the room's wall-height
    points (cloud_xy, plan frame) within seen_tol_m. The face of a new partition that the camera never
    looked at is known to nobody, as the issue has it for changes ("unknown, not removed"). cloud_xy None:
    every sample counts."""
    samples, _ = sample_segments(as_segments(truth_faces), step_m)
    knowable = np.ones(len(samples), dtype=bool)
    added = as_segments(added)
    if cloud_xy is None or len(samples) == 0 or len(added) == 0:
        return samples, knowable
    unplanned = point_segment_distances(samples, added).min(axis=1) <= added_tol_m
    if unplanned.any():
        seen = np.zeros(len(samples), dtype=bool)
        if len(cloud_xy):
            count = cKDTree(np.asarray(cloud_xy)[:, :2]).query_ball_point(
                samples[unplanned], seen_tol_m, return_length=True
            )
            seen[unplanned] = count >= min_points
        knowable = ~unplanned | seen
    return samples, knowable


def completeness_on(samples: NDArray, pred: Segments, tol_m: float = 0.10) -> float:
    """Share of the samples within tol_m of a predicted wall (the evaluation's completeness)."""
    pred = as_segments(pred)
    if len(samples) == 0:
        return 0.0
    if len(pred) == 0:
        return 0.0
    return float((point_segment_distances(samples, pred).min(axis=1) <= tol_m).mean())


def change_scores(
    pred: list[dict[str, Any]], truth: list[dict[str, Any]], tol_m: float = 0.30
) -> dict[str, Any]:
    """Precision and recall of added and removed walls (unknown ones make no claim): a predicted change is
    right when half its length lies within tol_m of a true change of its kind; a true change is found when
    half its length lies within tol_m of predicted changes of its kind."""
    out: dict[str, Any] = {}
    tp_p = n_p = tp_t = n_t = 0
    for kind in ("added", "removed"):
        p = np.array([[c["x0"], c["y0"], c["x1"], c["y1"]] for c in pred if c["kind"] == kind]).reshape(-1, 4)
        t = np.array([[c["x0"], c["y0"], c["x1"], c["y1"]] for c in truth if c["kind"] == kind]).reshape(
            -1, 4
        )
        right = _covered_share(p, t, tol_m) >= 0.5 if len(p) else np.zeros(0, dtype=bool)
        found = _covered_share(t, p, tol_m) >= 0.5 if len(t) else np.zeros(0, dtype=bool)
        out[f"{kind}_predicted"], out[f"{kind}_right"] = len(p), int(right.sum())
        out[f"{kind}_true"], out[f"{kind}_found"] = len(t), int(found.sum())
        tp_p, n_p, tp_t, n_t = tp_p + int(right.sum()), n_p + len(p), tp_t + int(found.sum()), n_t + len(t)
    out["precision"] = tp_p / n_p if n_p else 1.0
    out["recall"] = tp_t / n_t if n_t else 1.0
    return out


def _covered_share(a: Segments, b: Segments, tol_m: float) -> NDArray[np.float64]:
    """(len(a),) share of each segment of a lying within tol_m of some segment of b."""
    if len(a) == 0:
        return np.zeros(0)
    if len(b) == 0:
        return np.zeros(len(a))
    pts, owner = sample_segments(a, 0.05)
    near = point_segment_distances(pts, b).min(axis=1) <= tol_m
    return np.bincount(owner, near, len(a)) / np.bincount(owner, minlength=len(a))


def true_placement(room: str, results: dict, walls: np.ndarray, truth_dir: Path) -> Placement:
    """The derived true transform of a room model (the module doc)."""
    table = art.read_table(truth_dir / "walls.parquet")
    mine = table.filter(pc.equal(table["room_id"], room))
    tw = np.column_stack([mine[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
    start = Placement(0.0, (0.0, 0.0))
    if "register" in results and (truth_dir / "poses" / f"{room}.parquet").is_file():
        est = _camera_txy(results["register"].file("poses.parquet"), results.get("preprocess"))
        tru = art.read_table(truth_dir / "poses" / f"{room}.parquet").to_pydict()
        tt = np.asarray(tru["t_ns"], dtype=np.float64)
        k = np.abs(est[:, :1] - tt[None, :]).argmin(axis=1)  # float times: nearest within 1 ms
        ok = np.abs(tt[k] - est[:, 0]) < 1e6
        if ok.sum() >= 3:
            dst = np.column_stack([np.asarray(tru["tx"])[k[ok]], np.asarray(tru["ty"])[k[ok]]])
            start = rigid_fit(est[ok, 1:3], dst)
    return refine_on_walls(walls, tw, start)


def fusion_figures(
    truth_dir: Path, rooms: dict, fuse: art.StageResult, changes: art.StageResult | None
) -> dict[str, Any]:
    """metrics.json's fusion figures: per room, the correspondence, registration error against the
    derived true transform, fit score, closure and the walls in the plan frame against truth/walls
    (completeness over what the capture or the plan could give, `knowable_samples`; `completeness_all`
    over every true face, `unknowable_m` the length left out);
    the thickness errors of both methods on walls captured from both sides; change precision and
    recall. `rooms`: room id -> {stage name -> result}."""
    report = art.read_json(fuse.file("fuse.json"))
    cfg = FuseConfig()
    out: dict[str, Any] = {"rooms": {}}
    added = np.zeros((0, 4))
    if (truth_dir / "changes.parquet").is_file():
        true_changes = art.read_table(truth_dir / "changes.parquet").to_pylist()
        added = np.array(
            [[c["x0"], c["y0"], c["x1"], c["y1"]] for c in true_changes if c["kind"] == "added"], dtype=float
        ).reshape(-1, 4)
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
        if rep.get("placed") and "walls" in rooms.get(rid, {}):
            room = load_room(rid, rooms[rid], None)
            model = describe(room, cfg)
            true = true_placement(rid, rooms[rid], room.walls, truth_dir)
            est = Placement(math.radians(rep["theta_deg"]), tuple(rep["t_m"]))
            row.update(registration_error(est, true, model.centre))
            # walls in the plan frame against the truth (the walls issue's figures)
            table = art.read_table(truth_dir / "walls.parquet")
            mine = table.filter(pc.equal(table["room_id"], rid))
            tw = np.column_stack([mine[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
            segs, _ = art.read_segments(fuse.file(f"{rid}.walls.parquet"))
            ev = evaluate_walls(segs, tw)
            row.update({k: ev[k] for k in ("completeness", "correctness", "accuracy_mean_m")})
            # completeness over what the capture or the plan could give (knowable_samples)
            cloud = None
            if room.points is not None:
                z = room.points[:, 2]
                band = (z >= room.floor_z + 0.15) & (z <= room.ceiling_z - 0.10)
                cloud = true.points(room.points[band, :2])
            samples, knowable = knowable_samples(tw, cloud, added)
            row["completeness_all"] = row["completeness"]
            row["completeness"] = completeness_on(samples[knowable], segs)
            row["unknowable_m"] = round(float((~knowable).sum()) * 0.01, 2)
        out["rooms"][rid] = row
    # thickness
    tc, tt = art.read_segments(truth_dir / "plan_walls.parquet")
    tthick = tt["thickness_m"].to_numpy()
    faces = art.read_table(truth_dir / "walls.parquet")
    fsegs = np.column_stack([faces[c].to_numpy() for c in ("x0", "y0", "x1", "y1")]).astype(np.float64)
    both = both_sides_truth(tc, tthick, fsegs, np.asarray(faces["room_id"].to_pylist()))
    fc, ft = art.read_segments(fuse.file("thickness.parquet"))
    methods = [("both_sides", "thickness_m"), ("residuals", "thickness_residuals_m")]
    if "thickness_lines_m" in ft.column_names:
        methods.append(("model_lines", "thickness_lines_m"))
    for name, col in methods:
        err = thickness_errors(fc, ft[col].to_numpy(), tc, tthick)
        e = err[both & np.isfinite(err)]
        out[f"thickness_{name}"] = {
            "walls": len(e),
            "max_m": float(e.max()) if len(e) else None,
            "mean_m": float(e.mean()) if len(e) else None,
            "errors_m": e.round(4).tolist(),
        }
    if changes is not None and (truth_dir / "changes.parquet").is_file():
        pred = art.read_table(changes.file("changes.parquet")).to_pylist()
        out["changes"] = change_scores(pred, art.read_table(truth_dir / "changes.parquet").to_pylist())
    return out
