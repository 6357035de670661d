"""A numerical failure inside an estimator is an EstimatorError that the runner records
(issue 16 item 4): the estimator, run, step and what failed are named; the other
estimators' numbers are unchanged; summary.json, report.md, failures.log and the
terminal list every failed estimator-run."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cooploc.cli import app
from cooploc.errors import EstimatorError
from cooploc.experiment import WHAT_MAX_CHARS, ExperimentConfig, estimate, run_experiment
from cooploc.registry import make_estimator
from cooploc.results import summarize, write_results
from faulty import failing_runs, faulty
from helpers import froehle_recording

SMALL = {"n_steps": 12}
SEED, RUNS, P_FAIL = 5, 4, 0.5


def _config(names, backend="serial", runs=RUNS, workers=None) -> ExperimentConfig:
    return ExperimentConfig.build("froehle2018", list(names), scenario_overrides=SMALL, runs=runs,
                                  seed=SEED, backend=backend, workers=workers)


def _run(name: str, recording):
    est = make_estimator(name, recording.setup, None, np.random.default_rng(0))
    return estimate(est, recording)


@pytest.mark.parametrize(("mode", "what"), [
    ("raise", "LinAlgError: Matrix is not positive definite:"),
    ("nan", "non-finite estimate (vehicles.mean)"),
])
def test_estimate_names_the_estimator_step_and_what_failed(mode, what):
    recording = froehle_recording(1, n_steps=8)
    with faulty(mode, at=3) as name:
        with pytest.raises(EstimatorError) as info:
            _run(name, recording)
    err = info.value
    assert (err.estimator, err.step, err.run) == (name, 3, None)
    assert err.what == what  # the first line only: no array dump
    assert "\n" not in str(err) and len(err.what) <= WHAT_MAX_CHARS
    if mode == "raise":
        assert isinstance(err.__cause__, np.linalg.LinAlgError)  # the traceback is kept


def test_a_long_message_is_bounded():
    with faulty("raise", at=0) as name, pytest.raises(EstimatorError) as info:
        est = make_estimator(name, froehle_recording(1, n_steps=2).setup, None, np.random.default_rng(0))
        est.step = lambda frame: (_ for _ in ()).throw(ValueError("x" * 1000))
        estimate(est, froehle_recording(1, n_steps=2))
    assert len(info.value.what) == WHAT_MAX_CHARS and info.value.what.endswith("…")


def test_a_failing_smoother_is_named_without_a_step():
    recording = froehle_recording(1, n_steps=5)
    with faulty("smooth") as name, \
            pytest.raises(EstimatorError, match="in smooth: ZeroDivisionError") as info:
        _run(name, recording)
    assert info.value.step is None
    with faulty("smooth", p_fail=0.0) as name:  # a smoother that works: its estimates
        assert len(_run(name, recording)) == 5


@pytest.mark.parametrize("exc", [MemoryError, KeyboardInterrupt])
def test_resource_exhaustion_and_interrupts_are_not_estimator_failures(exc):
    with faulty("raise") as name:
        est = make_estimator(name, froehle_recording(1, n_steps=2).setup, None, np.random.default_rng(0))

        def step(frame):
            raise exc
        est.step = step
        with pytest.raises(exc):
            estimate(est, froehle_recording(1, n_steps=2))


def _other_numbers(summary: dict, name: str) -> dict:
    est = dict(summary["estimators"][name])
    est.pop("steps_per_second")
    return est


@pytest.mark.parametrize("backend", ["serial", "processes", "dask"])
def test_the_runner_records_failures_and_keeps_the_others(backend):
    if backend == "dask":
        distributed = pytest.importorskip("dask.distributed", reason="dask extra not installed")
        # threads: the estimator registered by this test exists in the workers
        client = distributed.Client(processes=False, n_workers=1, threads_per_worker=2,
                                    dashboard_address=None)
    alone = summarize(run_experiment(_config(["gnss-kf"])))
    try:
        with faulty("raise", p_fail=P_FAIL) as name:
            names = ["gnss-kf", name]
            result = run_experiment(_config(names, backend, workers=None if backend == "serial" else 2))
            failed = failing_runs(name, SEED, RUNS, P_FAIL, names)
    finally:
        if backend == "dask":
            client.close()
    assert 0 < len(failed) < RUNS  # the seed makes some runs fail, not all
    summary = summarize(result)
    json.dumps(summary, allow_nan=False)
    # the other estimator's numbers are those it has alone
    assert _other_numbers(summary, "gnss-kf") == _other_numbers(alone, "gnss-kf")
    # every failed run is recorded with its place and what failed
    assert [f.run for f in result.failures()] == failed
    est = summary["estimators"][name]
    what = "LinAlgError: Matrix is not positive definite:"
    assert est["failed_runs"] == [{"run": r, "step": 3, "error": what} for r in failed]
    # metrics over the runs it finished: there it is gnss-kf
    for vid, per_run in est["per_run_vehicle_rmse"].items():
        expected = [None if r in failed else v
                    for r, v in enumerate(alone["estimators"]["gnss-kf"]["per_run_vehicle_rmse"][vid])]
        assert per_run == expected
    assert est["vehicle_rmse_all"] is not None


def test_an_estimator_failing_every_run_still_appears(tmp_path):
    with faulty("raise", p_fail=1.0) as name:
        result = run_experiment(_config(["gnss-kf", name], runs=2))
        folder = write_results(result, tmp_path / "out")
    summary = json.loads((folder / "summary.json").read_text())
    est = summary["estimators"][name]
    assert [f["run"] for f in est["failed_runs"]] == [0, 1]
    assert est["vehicle_rmse"] == {} and est["per_run_vehicle_rmse"] == {}
    assert est["vehicle_rmse_all"] is None and est["steps_per_second"] is None
    # failures.log: each failure's line and its traceback down to the LinAlgError
    log = (folder / "failures.log").read_text()
    assert log.count(f"{name} failed at run") == 2 and "Traceback" in log and "LinAlgError" in log
    report = (folder / "report.md").read_text()
    assert f"{name} failed in run 1 at step 3: LinAlgError" in report
    # a rerun without failures leaves no stale failures.log
    write_results(run_experiment(_config(["gnss-kf"], runs=1)), folder)
    assert not (folder / "failures.log").exists()


def test_the_terminal_lists_failed_estimator_runs(tmp_path):
    with faulty("raise", p_fail=1.0) as name:
        result = CliRunner().invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "-e", name, "--runs", "1",
                                          "--set", "n_steps=6", "--backend", "serial", "--no-progress",
                                          "--out", str(tmp_path / "out")], env={"COLUMNS": "250"})
    assert result.exit_code == 0, result.output
    assert f"{name} failed in run 0 at step 3: LinAlgError: Matrix is not positive definite:" in result.output
    assert (tmp_path / "out" / "failures.log").is_file()
