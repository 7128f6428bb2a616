"""Prefect's settings for indoor-survey runs, applied by the entry point (the CLI, the test session)
before Prefect is imported: nothing is set as a side effect of importing a module."""

from __future__ import annotations

import os

DEFAULTS = {
    # Offline, quiet and patient: the embedded server needs more than the default 20 s to start here.
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "120",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DO_NOT_TRACK": "1",
    # Stage failures are reported by the run summary in one line each; Prefect's own copy of them is a
    # traceback. PREFECT_LOGGING_LEVEL=ERROR in the environment brings those back for debugging.
    "PREFECT_LOGGING_LEVEL": "CRITICAL",
    # The embedded server is stopped when a run ends; its event writer's cancellation is not an error.
    "PREFECT_SERVER_LOGGING_LEVEL": "CRITICAL",
    "PREFECT_LOGGING_TO_API_ENABLED": "false",
    "PREFECT_RESULTS_PERSIST_BY_DEFAULT": "true",
}


def apply() -> None:
    """Set each default that the environment does not already set."""
    for name, value in DEFAULTS.items():
        os.environ.setdefault(name, value)
