"""The walls stage: the preprocess stage's slice and levelling in, the room's walls, plan, extruded model and
preview out, in the input cloud's own frame when that frame means something."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import shapely.affinity
import shapely.geometry
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.context import StageContext
from tasks.preview import retitle
from tasks.walls.config import WallsConfig
from tasks.walls.evidence import faces_below_slice, lifted
from tasks.walls.lowtop import low_topped_walls
from tasks.walls.model import WallModel, model_walls
from tasks.walls.round import on_round_objects


def levelled_to_input(levelling: dict[str, Any]) -> tuple[NDArray[np.float64], float]:
    """The inverse levelling transform (levelled -> input frame, 4x4) and the height at which wall
    lines are carried back: the levelling pivot's, where the rotation moves nothing."""
    back = np.linalg.inv(np.asarray(levelling["transform"], dtype=np.float64))
    pivot = levelling.get("pivot_m")
    return back, float(pivot[2]) if pivot else 0.0


def segments_to_input(walls: NDArray[np.float64], back: NDArray[np.float64], z: float) -> NDArray[np.float64]:
    """(M, 4) levelled-frame wall lines as (M, 4) lines of the input cloud's own x-y frame."""
    ends = np.concatenate([walls[:, :2], walls[:, 2:]], axis=0)
    pts = np.column_stack([ends, np.full(len(ends), z)]) @ back[:3, :3].T + back[:3, 3]
    half = len(walls)
    return np.column_stack([pts[:half, :2], pts[half:, :2]])


def wall_features(
    walls: NDArray[np.float64], origin: Any, support: Any, polygon: Any, room: str
) -> list[dict]:
    """GeoJSON features: one LineString per wall, and the room Polygon when the walls close it."""
    features = [
        {
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [[w[0], w[1]], [w[2], w[3]]]},
            "properties": {"room_id": room, "kind": "wall", "origin": str(o), "support": float(s)},
        }
        for w, o, s in zip(walls.tolist(), origin, support, strict=True)
    ]
    if polygon is not None:
        features.append(
            {
                "type": "Feature",
                "geometry": shapely.geometry.mapping(polygon),
                "properties": {"room_id": room, "kind": "room", "area_m2": float(polygon.area)},
            }
        )
    return features


def wall_noise(slice_points: NDArray[np.float64], walls: NDArray[np.float64], band_m: float) -> float:
    """The slice points' spread about the walls (M, 4): 1.4826 x the median plan distance of the points
    (N, 3) within `band_m` of a wall (a Gaussian's sigma); 0 without such points."""
    from tasks.lines import point_segment_distances

    if len(walls) == 0:
        return 0.0
    d = np.concatenate(
        [
            point_segment_distances(slice_points[k : k + 20000, :2], walls).min(axis=1)
            for k in range(0, len(slice_points), 20000)
        ]
    )
    d = d[d <= band_m]
    return float(1.4826 * np.median(d)) if len(d) else 0.0


FACE_ROUNDS = 2
"""Rounds of `faces_below_slice`: the first finds a stub's second face under the slice, the second runs it on
to the host wall where the first found it over part of the stub only."""


def room_model(
    slice_points: NDArray[np.float64],
    levelled: NDArray[np.float64],
    floor_z_m: float,
    ceiling_z_m: float,
    cfg: WallsConfig,
    ceiling_captured: bool | None = None,
) -> tuple[WallModel, dict[str, Any]]:
    """The wall model of the slice (N, 3), and what the stage chose beyond `model_walls`:

    - the grid from the noise: when the points spread about the walls found by more than
      `grid_noise_ratio` times the grid (`wall_noise`), the model is made again on a grid of that spread;
    - partition faces below the slice: when a stub's second face is found in the levelled cloud (L, 3)
      under the slice (`evidence.faces_below_slice`), that face is stood up in the slice and the model
      made again.

    Before them, without a ceiling, the columns of walls seen only up to under the slice's top are draped
    into the slice (`lowtop.low_topped_walls`; `ceiling_captured` is preprocess's verdict, None: judged
    from the slice). Each costs a second model only when it applies. Returns
    the model and those choices (metrics)."""
    draped: dict[str, Any] = {}
    if cfg.low_top_min_m > 0 and len(slice_points) > cfg.min_points:
        slice_points, draped = low_topped_walls(
            levelled, slice_points, floor_z_m, ceiling_z_m, cfg, ceiling_captured=ceiling_captured
        )
    model = model_walls(slice_points, floor_z_m, ceiling_z_m, cfg)
    grid = float(model.metrics["grid_size_m"])
    first, round_things = model, model.metrics["round_objects"]
    if round_things:
        # the round things found go before any model made again: on another grid, or with faces stood up
        # from below the slice, the same pot might not be found again
        slice_points = slice_points[~on_round_objects(slice_points[:, :2], round_things, grid)]
    noise = wall_noise(slice_points, model.walls, cfg.noise_band_m)
    choices: dict[str, Any] = {**draped, "wall_noise_m": round(noise, 4), "grid_from_noise": False}
    if cfg.grid_noise_ratio > 0 and noise > cfg.grid_noise_ratio * grid:
        cfg = replace(cfg, grid_size_m=round(noise, 3))
        model = model_walls(slice_points, floor_z_m, ceiling_z_m, cfg)
        grid = float(model.metrics["grid_size_m"])
        choices["grid_from_noise"] = True
        choices["wall_noise_after_m"] = round(wall_noise(slice_points, model.walls, cfg.noise_band_m), 4)
    choices["faces_below_slice"] = []
    if cfg.below_slice_min_share <= 0 or len(model.walls) < 2:
        return model, choices
    z = slice_points[:, 2]
    points = slice_points
    # a face found under the slice over part of its stub makes a model whose second face stops short of the
    # host wall: the second round gives it the rest (`faces_below_slice`'s capped stubs only)
    for k in range(FACE_ROUNDS):
        faces, found = faces_below_slice(
            model.walls, levelled, points, floor_z_m, cfg, grid, capped_only=k > 0
        )
        if not faces:
            break
        points = np.concatenate([points, lifted(faces, float(z.min()), float(z.max()), grid)])
        choices["faces_below_slice"] += found
        model = model_walls(points, floor_z_m, ceiling_z_m, cfg)
    if model is not first and round_things:
        model.metrics["round_objects"] = round_things + model.metrics["round_objects"]
        model.metrics["round_object_points"] += first.metrics["round_object_points"]
    return model, choices


def run(ctx: StageContext, cfg: WallsConfig, out: Path) -> dict[str, Any]:
    """The room's walls (`walls.parquet`), plan (`plan.geojson`), extruded model (`model.ply`) and preview
    (`preview.png`) from the preprocess stage's furniture slice and levelling."""
    pre = ctx.upstream["preprocess"]
    levelling = art.read_json(pre.file("levelling.json"))
    slice_cloud = art.read_cloud(pre.file("slice.ply"))
    # the levelled cloud: a partition's second face may have been seen only under the slice
    levelled = art.read_cloud(pre.file("levelled.ply"))
    model, choices = room_model(
        slice_cloud.points,
        levelled.points,
        levelling["floor_z_m"],
        levelling["ceiling_z_m"],
        cfg,
        levelling.get("ceiling_captured"),
    )
    # A given cloud's frame means something (a TLS survey's, the user's): walls go back into it. A frame
    # made by registration is arbitrary and maybe tilted: walls stay in the levelled (z up) room frame.
    if levelling.get("source") == "register":
        back, z, frame = np.eye(4), 0.0, "levelled room frame (m)"
    else:
        back, z = levelled_to_input(levelling)
        frame = "input cloud x-y (m)"
    walls = segments_to_input(model.walls, back, z)
    polygon = model.polygon
    if polygon is not None:
        polygon = shapely.affinity.affine_transform(
            polygon,
            [
                back[0, 0],
                back[0, 1],
                back[1, 0],
                back[1, 1],
                back[0, 3] + back[0, 2] * z,
                back[1, 3] + back[1, 2] * z,
            ],
        )
    art.write_table(
        out / "walls.parquet",
        art.segments_table(
            walls,
            height=np.full(len(walls), model.height_m),
            origin=model.origin.astype(str),
            support=model.support,
        ),
        art.WALLS_SCHEMA,
    )
    art.write_geojson(
        out / "plan.geojson",
        wall_features(walls, model.origin, model.support, polygon, ctx.room),
        frame,
    )
    vertices = model.mesh_vertices @ back[:3, :3].T + back[:3, 3]
    art.write_ply_mesh(out / "model.ply", vertices, model.mesh_triangles)
    art.write_png(out / "preview.png", retitle(model.preview, f"room {ctx.room}: walls"))
    return {
        "frame": frame,
        "metrics": {
            **model.metrics,
            "walls": len(walls),
            "closed": model.closed,
            "alpha": model.alpha,
            **choices,
        },
    }
