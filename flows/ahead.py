"""Stages computed while Prefect's embedded server starts.

A run that starts its own Prefect server waits about 5 s for it (its imports, in its own process, about
one core). A rerun after tuning one stage has little else to do: a walls-only rerun of five rooms is a
few seconds of computation. So, while the server starts, one thread computes the stale stages that are
ready: every input of the stage current, taken from the run's own plan (`PlannedStage.upstream`, the
building stages it reads included, as the flow passes them), and computed by the flow's own
load-or-compute (`planning.execute`), so under the key the flow would use. The flow then finds them
current: it reports them computed (with their seconds) and makes no task run for them.

Only a stage that ran before and took at most `max_seconds` then is started ahead, and none once the
server answers: the flow waits for the stage in progress, and a long stage would keep the run's other
workers idle meanwhile. A cold run's stages (never run) and long ones (registration) are left to the flow.
A stage that fails ahead is left to the flow, which runs it again and reports the failure.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from flows.planning import (
    PlannedStage,
    RunRequest,
    SurveyPlan,
    current_results,
    execute,
    plan_survey,
    ready_inputs,
    save_code_memo,
    store_for,
)
from tasks import config as cfgmod
from tasks.artefacts import ArtefactError, read_json

log = logging.getLogger("indoor_survey")

MAX_SECONDS = 10.0
"""A stage is started ahead only when its last run took at most this long (its `compute_seconds`): about
twice the server's start, so that the flow waits little for a stage in progress."""


def last_seconds(item: PlannedStage) -> float | None:
    """How long the stage's last run for this room took, from its newest manifest (None: never run). Read
    without verifying the artefacts: it only decides what to start ahead."""
    root = store_for(item.call.work).stage_root(item.call.room, item.call.stage)
    newest: tuple[float, float] | None = None
    for manifest_path in root.glob("*/manifest.json") if root.is_dir() else ():
        if manifest_path.parent.name.startswith("."):  # a run's private folder, not yet committed
            continue
        try:
            manifest = read_json(manifest_path)
        except ArtefactError:
            continue
        finished, seconds = manifest.get("finished_at"), manifest.get("compute_seconds")
        if isinstance(finished, int | float) and isinstance(seconds, int | float):
            if newest is None or finished > newest[0]:
                newest = (float(finished), float(seconds))
    return None if newest is None else newest[1]


class Ahead:
    """Computes ready stages of a run in one thread until `finish` (call it once the server answers)."""

    def __init__(self, req: RunRequest, max_seconds: float = MAX_SECONDS) -> None:
        self.req = req
        self.max_seconds = max_seconds
        self.computed: dict[tuple[str, str], float] = {}
        self.planned = threading.Event()
        """Set once the plan is made (and with it every stage's code version read, which parses the stage
        modules: CPython 3.11's parser must not run in two threads at once)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ahead", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def wait(self, timeout: float | None = None) -> None:
        """Wait until it has gone through the whole plan (it stops by itself then)."""
        self._thread.join(timeout)

    def finish(self) -> dict[tuple[str, str], float]:
        """Start no more stages, wait for the one in progress; (room, stage) -> seconds of each stage
        computed ahead."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        return dict(self.computed)

    def _run(self) -> None:
        try:
            cfg = cfgmod.load_config([Path(p) for p in self.req.config_files], list(self.req.sets))
            survey = cfgmod.load_survey(Path(self.req.survey))
            plan = plan_survey(self.req, cfg, survey, cfgmod.load_sensor_profile(survey.sensor))
            save_code_memo(self.req.work)
        except Exception as exc:  # the flow plans again and reports what is wrong
            log.debug("nothing computed ahead: %s", exc)
            return
        finally:
            self.planned.set()
        self._compute(plan)

    def _compute(self, plan: SurveyPlan) -> None:
        found = current_results(plan, plan.rooms, skip=lambda item: item.call.force)
        for item in [*plan.before, *(i for chain in plan.rooms.values() for i in chain)]:
            if self._stop.is_set():
                return
            if item.ref in found:
                continue
            upstream = ready_inputs(item, found)
            seconds = last_seconds(item)
            if upstream is None or seconds is None or seconds > self.max_seconds:
                continue
            try:
                done = execute(item.call, upstream)
            except Exception as exc:  # left to the flow, which runs it again and reports it
                log.debug("[%s] %s: not computed ahead: %s", item.call.room, item.call.stage, exc)
                return
            found[item.ref] = done.result
            if done.how == "computed":  # else current once what it reads was (same bytes): a store hit
                self.computed[item.ref] = done.seconds
