"""Shared fixtures. Real data lives in ../shared/realdata beside the clone; tests that need it skip with a
reason where it is absent, except under INDOOR_SURVEY_REQUIRE_REALDATA=1 (CI), where they fail."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

from flows import prefect_env

prefect_env.apply()  # the test session is an entry point, like the CLI

REPO = Path(__file__).resolve().parents[1]
REALDATA = Path(os.environ.get("INDOOR_SURVEY_REALDATA", REPO.parent / "shared" / "realdata"))


def _realdata(name: str) -> Path:
    folder = REALDATA / name
    if not folder.is_dir():
        message = f"real data folder {folder} is absent (a clone outside the workspace)"
        if os.environ.get("INDOOR_SURVEY_REQUIRE_REALDATA") == "1":
            pytest.fail(message + " and INDOOR_SURVEY_REQUIRE_REALDATA=1")
        pytest.skip(message)
    return folder


@pytest.fixture
def realdata():
    """Call with a subfolder name of ../shared/realdata: `realdata("calib_stereo_opencv")` -> Path."""
    return _realdata


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def prefect_harness():
    """One temporary Prefect server and database for the whole session (its start-up costs ~10-20 s)."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


# ------------------------------------------------------------------------- expensive results, made once
# Each of these costs from tens of seconds to minutes; the tests that read it share one run per session
# instead of each making its own. A fixture returns where the files are; tests only read them.

MINI = REPO / "data" / "mini"


@pytest.fixture(scope="session")
def mini_run(tmp_path_factory, prefect_harness):
    """`indoor-survey run data/mini` (every stage of the six rooms, through Prefect), once per session:
    (exit code, work dir). The end-to-end tests and the register tests on the synthetic survey read it."""
    from flows.cli import main

    work = tmp_path_factory.mktemp("mini-work")
    code = main(["-q", "run", str(MINI), "--work", str(work)])
    return code, work


@dataclass(frozen=True)
class KitchenRun:
    """The register-room verb on 50 of the real 7-Scenes redkitchen frames."""

    folder: Path
    """The frames the verb read: frame-XXXXXX.color.jpg / .depth.png / .pose.txt (the given camera-to-world
    poses), links into the real-data folder."""
    out: Path
    """What the verb wrote: poses.parquet, cloud.ply, scale.json."""
    metrics: dict
    """The verb's return value: the register stage's metrics (`sfm`, `methods`...) and `ingest`'s."""


@pytest.fixture(scope="session")
def kitchen_registered(tmp_path_factory) -> KitchenRun:
    """`register-room` (ingest -> sfm -> scale -> fusion) on 50 real Kinect v1 frames (every other frame of
    the 100 in the real-data folder, linked into a temporary folder), once per session: SfM of 640x480
    frames is the suite's largest single cost, and 50 frames still need sequential matching with loop
    pairs (ATE 4.26 cm against 4.23 cm on all 100, at half the CPU). The SfM, register and verb tests
    read it."""
    from flows.oneoff import register_room
    from tasks.config import load_config

    source = _realdata("rgbd_7scenes_redkitchen")
    folder = tmp_path_factory.mktemp("kitchen-frames")
    for path in source.iterdir():
        frame = re.fullmatch(r"frame-(\d+)\..*", path.name)
        if frame is None or int(frame.group(1)) % 20 == 0:
            (folder / path.name).symlink_to(path)
    out = tmp_path_factory.mktemp("kitchen") / "out"
    cfg = load_config([], ["ingest.intrinsics_px=[585, 585, 320, 240]", "ingest.tum_depth_units_per_m=1000"])
    return KitchenRun(folder, out, register_room(folder, out, cfg=cfg))


@pytest.fixture(scope="session")
def generator_calibration_set(tmp_path_factory):
    """Call with a size ("mini" or "full"): (folder, true calibration JSON) of the survey generator's
    calibration set for the Kinect v1 profile at seed 5 with the default settings, written once per
    session (the full set costs ~20 s of CPU). Tests read the folder, never write into it."""
    import numpy as np
    import yaml

    from tasks.synth.calibration_set import write_calibration_set

    profile = yaml.safe_load((REPO / "configs" / "sensors" / "kinect_v1.yaml").read_text())
    sets: dict[str, tuple[Path, dict]] = {}

    def get(size: str) -> tuple[Path, dict]:
        if size not in sets:
            folder = tmp_path_factory.mktemp(f"calibration-set-{size}")
            sets[size] = (folder, write_calibration_set(folder, profile, size, np.random.default_rng(5)))
        return sets[size]

    return get
