"""`run --runner dask`: rooms as Dask tasks on a LocalCluster give the thread runner's artefacts, byte for
byte (content hashes), and the runner choice is checked before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from flows.runners import RunnerError, check_choice


def test_runner_choice_is_checked_up_front() -> None:
    check_choice("threads", None)
    check_choice("dask", None)
    check_choice("dask", "tcp://10.1.2.3:8786")
    with pytest.raises(RunnerError, match="needs --runner dask"):
        check_choice("threads", "tcp://host:8786")
    with pytest.raises(RunnerError, match="expected a Dask scheduler address"):
        check_choice("dask", "host:8786")
    with pytest.raises(RunnerError, match="expected one of"):
        check_choice("ray", None)


def test_cli_refuses_a_bad_dask_address(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from flows.cli import EXIT_BAD_INPUT, main

    survey = Path(__file__).resolve().parents[1] / "data" / "mini"
    code = main(["run", str(survey), "--work", str(tmp_path / "w"), "--dask-address", "tcp://a b"])
    assert code == EXIT_BAD_INPUT
    assert "--dask-address" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()  # refused before anything was written


def _hashes(rows) -> dict[tuple[str, str], dict[str, str]]:
    return {(r.room, r.stage): dict(r.result.files) for r in rows if r.result is not None}


def test_dask_runner_without_address_starts_a_local_cluster_of_processes() -> None:
    from prefect_dask import DaskTaskRunner

    from flows.runners import task_runner

    runner = task_runner("dask", 3)
    assert isinstance(runner, DaskTaskRunner)
    assert runner.cluster_kwargs["n_workers"] == 3
    assert runner.cluster_kwargs["threads_per_worker"] == 1
    assert runner.cluster_kwargs["processes"] is True
    assert task_runner("dask", 2, "tcp://127.0.0.1:8786").address == "tcp://127.0.0.1:8786"


def _room_tasks_run(dask_worker) -> int:
    """How many room tasks this worker started (its task log holds their keys)."""
    keys = {entry[0] for entry in dask_worker.state.log if entry and isinstance(entry[0], str)}
    return sum(key.startswith("room_task") for key in keys)


@pytest.mark.slow
def test_dask_cluster_gives_the_thread_runners_artefacts(tmp_path: Path, prefect_harness) -> None:
    """Three rooms (all TLS clouds) of a synthetic survey plus its plan, fused: once on the thread
    runner, once on a Dask cluster of 2 single-threaded worker processes (given by its address, as a
    multi-machine run is), each into a fresh work dir."""
    from distributed import Client, LocalCluster

    from flows.pipeline import run_survey
    from flows.planning import RunRequest
    from tasks.synth.survey import generate_survey

    survey = generate_survey(tmp_path / "survey", seed=0, rooms=2, profile="tls")  # r1, r5, hall
    runs = {}
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        for runner in ("threads", "dask"):
            req = RunRequest(survey=str(survey), work=str(tmp_path / runner), sets=("flow.max_workers=2",))
            rows = run_survey(req, runner, cluster.scheduler_address if runner == "dask" else None)
            assert {r.state for r in rows} == {"computed"}, [
                (r.room, r.stage, r.state, r.error) for r in rows
            ]
            runs[runner] = _hashes(rows)
        per_worker = client.run(_room_tasks_run)
    assert sum(per_worker.values()) == 3, per_worker  # every room was a task on a Dask worker
    assert {room for room, _ in runs["dask"]} == {"_building", "r1", "r5", "hall"}
    assert runs["dask"] == runs["threads"]
    # and the published deliverables agree too
    for name in ("floor.geojson", "changes.parquet", "rooms/r5/walls.parquet", "rooms/hall/plan.geojson"):
        a, b = (tmp_path / runner / "outputs" / name for runner in ("threads", "dask"))
        assert a.read_bytes() == b.read_bytes(), name
