"""Shared fixtures. Real data lives in ../shared/realdata beside the clone; tests that need it skip with a
reason where it is absent, except under INDOOR_SURVEY_REQUIRE_REALDATA=1 (CI), where they fail."""

from __future__ import annotations

import os
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
