"""The stage table: for each stage, what it reads, which config section it owns and how its outputs are
loaded and saved. Each `run_*` here is the thin shell around a pure stage function: load the inputs from
the artefact store, call, write the outputs into the folder the store commits. Orchestration (Prefect)
lives in flows/; formats live in tasks/artefacts.py; the computation lives in each stage's module.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tasks import artefacts as art
from tasks.artefacts import StageResult

ProgressFn = Callable[[str], None]


@dataclass(frozen=True)
class StageContext:
    """What a stage run gets besides its config: its upstream results, raw input files, the survey's
    sensor profile, and a progress callback."""

    room: str
    upstream: dict[str, StageResult]
    raw_inputs: dict[str, str]
    """Name -> path of raw survey files this stage reads (their content hashes are in the key)."""
    profile: dict[str, Any]
    progress: ProgressFn
    extra_config: dict[str, Any] = field(default_factory=dict)
    """Section name -> config of the stage's `extra_sections`."""
    params: dict[str, Any] = field(default_factory=dict)
    """Survey-given values (the plan's scale)."""


@dataclass(frozen=True)
class Stage:
    name: str
    section: str
    """Config section the stage owns (its config in the cache key)."""
    module: str
    """The module holding the stage's computation (its source is part of the code version)."""
    run: Callable[[StageContext, Any, Path], dict[str, Any]]
    """(context, config section, output folder) -> metrics; writes its files into the folder."""
    uses_profile: bool = False
    """Whether the survey's sensor profile is an input (then its content is part of the cache key)."""
    extra_sections: tuple[str, ...] = ()
    """Further config sections the stage reads (a stage that runs several methods: register reads sfm
    and scale); they enter its cache key too and reach `run` as `ctx.extra_config`."""

    def code_version(self) -> str:
        """Hash of the computation's module source and of this stage's shell, so editing either
        invalidates the stage (and, through content hashes, what depends on it). Read once per process."""
        return _code_version(self.module, self.run)


@functools.cache
def _code_version(module_name: str, run: Callable[..., Any]) -> str:
    module = sys.modules.get(module_name) or importlib.import_module(module_name)
    digest = hashlib.sha256(Path(inspect.getfile(module)).read_bytes())
    digest.update(inspect.getsource(run).encode())
    return digest.hexdigest()[:16]


# ------------------------------------------------------------------------------------------------ shells


def run_calibrate(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """The survey's calibration from its target images, else the sensor profile's values (said so)."""
    from tasks.calibrate.stage import run

    return run(ctx, cfg, out)


def run_plan(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """The coarse plan raster as metric walls (centrelines + thickness) and rooms (thesis 4.2.3)."""
    from tasks.plan import PlanScale, run_parse_plan

    known = ctx.params.get("known_distance")
    scale = PlanScale(
        m_per_px=ctx.params.get("m_per_px"),
        known_distance=tuple(known) if known else None,
        outline_length_m=ctx.params.get("outline_length_m"),
    )
    metrics = run_parse_plan(Path(ctx.raw_inputs["plan"]), out, scale, cfg)
    metrics.pop("outputs", None)
    return {"metrics": metrics}


def run_ingest(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.ingest import ingest_capture

    return {"metrics": ingest_capture(Path(ctx.raw_inputs["capture"]), out, ctx.profile, cfg, ctx.progress)}


def run_register(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    """SfM -> metric scale -> fused coloured cloud, or the track-based fallback (thesis 3.2)."""
    from tasks.register.stage import run

    return run(ctx, cfg, out)


def room_cloud(ctx: StageContext) -> tuple[art.Cloud, str]:
    """The room's registered cloud and where it came from: "register" (frames placed by this pipeline,
    in an arbitrary room frame) or "capture" (a cloud given in its own, meaningful frame)."""
    for stage, source in (("register", "register"), ("ingest", "capture")):
        result = ctx.upstream.get(stage)
        if result is not None and result.has("cloud.ply"):
            return art.read_cloud(result.file("cloud.ply")), source
    raise art.ArtefactError(f"room {ctx.room}: no registered cloud to preprocess (capture has frames only)")


def run_preprocess(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    from tasks.preprocess import preprocess

    cloud, source = room_cloud(ctx)
    result = preprocess(cloud, cfg)
    art.write_cloud(out / "levelled.ply", result.cloud)
    art.write_cloud(out / "slice.ply", result.slice)
    art.write_png(out / "height_histogram.png", result.histogram_png)
    edges, counts = result.histogram
    art.write_table(
        out / "height_histogram.parquet", {"z_low_m": edges[:-1], "z_high_m": edges[1:], "count": counts}
    )
    art.write_json(
        out / "levelling.json",
        {
            "transform": np.asarray(result.levelling).tolist(),
            "floor_z_m": result.floor_z_m,
            "ceiling_z_m": result.ceiling_z_m,
            "height_m": result.height_m,
            "pivot_m": result.metrics.get("levelling_pivot_m"),
            "source": source,
        },
    )
    return {"metrics": result.metrics}


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
    import shapely.geometry

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


def run_walls(ctx: StageContext, cfg: Any, out: Path) -> dict[str, Any]:
    import shapely.affinity

    from tasks.walls import model_walls

    pre = ctx.upstream["preprocess"]
    levelling = art.read_json(pre.file("levelling.json"))
    slice_cloud = art.read_cloud(pre.file("slice.ply"))
    model = model_walls(slice_cloud.points, levelling["floor_z_m"], levelling["ceiling_z_m"], cfg)
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
    art.write_png(out / "preview.png", model.preview)
    return {
        "frame": frame,
        "metrics": {**model.metrics, "walls": len(walls), "closed": model.closed, "alpha": model.alpha},
    }


ROOM_DELIVERABLES = {"walls": ("walls.parquet", "plan.geojson", "model.ply", "preview.png")}
"""Stage -> files published to outputs/rooms/<id>/ (PIPELINE.md "Deliverables")."""

BUILDING_DELIVERABLES = {"plan": ("plan_walls.parquet", "rooms.geojson", "plan_preview.png")}
"""Stage -> files published to outputs/ (PIPELINE.md "Deliverables")."""


STAGES: dict[str, Stage] = {
    stage.name: stage
    for stage in (
        Stage("calibrate", "calibrate", "tasks.calibrate.stage", run_calibrate, uses_profile=True),
        Stage("plan", "plan", "tasks.plan", run_plan),
        Stage("ingest", "ingest", "tasks.ingest", run_ingest, uses_profile=True),
        Stage("register", "register", "tasks.register.stage", run_register, True, ("sfm", "scale")),
        Stage("preprocess", "preprocess", "tasks.preprocess", run_preprocess),
        Stage("walls", "walls", "tasks.walls", run_walls),
    )
}
