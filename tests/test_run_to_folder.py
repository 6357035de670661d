"""Results are written run by run (issue 16 item 3): `run_to_folder` streams each finished
run to out/runs/ and merges at the end; an interrupted experiment keeps its finished
runs, marked incomplete; the numbers are those of `run_experiment` + `write_results`,
byte for byte, whatever the backend."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from cooploc.backends import completed
from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig, execute, iter_runs, run_experiment
from cooploc.metrics import ErrorTable
from cooploc.results import RUNS_FOLDER, merge_runs, read_runs, run_to_folder, write_results, write_run
from faulty import faulty

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

RUNS = 3


def _config(names=("gnss-kf", "oracle-kf"), backend="serial", runs=RUNS, workers=None) -> ExperimentConfig:
    return ExperimentConfig.build("froehle2018", list(names), scenario_overrides={"n_steps": 15}, runs=runs,
                                  seed=2, backend=backend, workers=workers)


def _numbers(folder) -> dict:
    summary = json.loads((folder / "summary.json").read_text())
    for est in summary["estimators"].values():
        est.pop("steps_per_second")
    return summary


@pytest.mark.parametrize("backend", ["serial", "processes"])
def test_run_to_folder_equals_run_experiment_and_write_results(tmp_path, backend):
    reference = write_results(run_experiment(_config()), tmp_path / "reference")
    config = _config(backend=backend, workers=None if backend == "serial" else 2)
    folder = run_to_folder(config, tmp_path / backend)
    assert (folder / "errors.parquet").read_bytes() == (reference / "errors.parquet").read_bytes()
    assert _numbers(folder) == _numbers(reference)
    assert ExperimentConfig.from_dict(tomllib.loads((folder / "config.toml").read_text())) == config
    assert _numbers(folder)["complete"] is True
    assert not (folder / RUNS_FOLDER).exists()  # merged: the parts are gone


def test_parts_read_back_to_the_same_runs(tmp_path):
    result = run_experiment(_config())
    for run in result.runs:
        write_run(run, result.config, tmp_path)
    back = read_runs(tmp_path)
    assert [r.run for r in back] == [0, 1, 2]
    for a, b in zip(result.runs, back, strict=True):
        assert a.step_seconds == b.step_seconds and a.n_steps == b.n_steps
        assert a.association == b.association and a.discarded == b.discarded and a.failures == b.failures
        assert a.nis == b.nis and set(a.nis) == {"gnss-kf", "oracle-kf"}   # (Σ NIS, Σ dof) per estimator
        for name in a.errors:
            for f in ErrorTable.__dataclass_fields__:
                np.testing.assert_array_equal(getattr(a.errors[name], f), getattr(b.errors[name], f))
                assert getattr(a.errors[name], f).dtype == getattr(b.errors[name], f).dtype
            np.testing.assert_array_equal(a.ospa[name], b.ospa[name])


def test_interrupted_in_the_first_run(tmp_path):
    # Ctrl-C inside run 0: nothing finished, the folder still says so
    with faulty("interrupt", at=5, p_fail=1.0) as name:
        with pytest.raises(KeyboardInterrupt):
            run_to_folder(_config(("gnss-kf", name), runs=4), tmp_path / "out")
    folder = tmp_path / "out"
    summary = json.loads((folder / "summary.json").read_text())
    assert (summary["complete"], summary["runs_finished"], summary["stopped_by"]) == (
        False, 0, "KeyboardInterrupt")
    assert summary["estimators"]["gnss-kf"]["vehicle_rmse_all"] is None
    report = (folder / "report.md").read_text()
    assert "incomplete: 0 of 4 runs finished (stopped by KeyboardInterrupt)" in report


@pytest.mark.parametrize("stop", [KeyboardInterrupt, OSError])
def test_interrupted_after_some_runs(tmp_path, monkeypatch, stop):
    import cooploc.results as results

    written = []

    def write_then_stop(run, config, folder):
        if len(written) == 2:
            raise stop
        written.append(run.run)
        write_run(run, config, folder)

    monkeypatch.setattr(results, "write_run", write_then_stop)
    with pytest.raises(stop):
        run_to_folder(_config(runs=5), tmp_path / "out")
    folder = tmp_path / "out"
    summary = json.loads((folder / "summary.json").read_text())
    assert (summary["complete"], summary["runs_finished"], summary["finished_runs"]) == (False, 2, [0, 1])
    assert summary["stopped_by"] == stop.__name__
    assert all(len(v) == 2 for v in summary["estimators"]["gnss-kf"]["per_run_vehicle_rmse"].values())
    assert sorted(p.name for p in (folder / RUNS_FOLDER).iterdir()) == [
        "run-000000.json", "run-000000.parquet", "run-000001.json", "run-000001.parquet"]
    # the finished runs' numbers are those of the full experiment's first two runs
    full = run_experiment(_config(runs=2))
    reference = write_results(full, tmp_path / "reference")
    assert (folder / "errors.parquet").read_bytes() == (reference / "errors.parquet").read_bytes()


def test_merge_runs_recovers_a_folder_killed_before_merging(tmp_path):
    config = _config(runs=2)
    result = run_experiment(config)
    write_results(result, tmp_path / "reference")
    folder = tmp_path / "killed"
    (folder).mkdir()
    (folder / "config.toml").write_text((tmp_path / "reference" / "config.toml").read_text())
    for run in result.runs:
        write_run(run, config, folder)
    merge_runs(folder)  # the configuration from config.toml
    assert _numbers(folder) == _numbers(tmp_path / "reference")


def test_results_are_delivered_as_they_finish():
    config = _config(runs=4)
    seen = []
    result = run_experiment(config, on_result=lambda r: seen.append(r.run))
    assert sorted(seen) == [0, 1, 2, 3] and [r.run for r in result.runs] == [0, 1, 2, 3]
    streamed = sorted(iter_runs(_config(runs=4, backend="processes", workers=2)), key=lambda r: r.run)
    for a, b in zip(result.runs, streamed, strict=True):
        np.testing.assert_array_equal(a.errors["oracle-kf"].err_pos, b.errors["oracle-kf"].err_pos)


def test_execute_takes_tasks_lazily():
    config = _config(("gnss-kf",), runs=3)
    taken = []

    def tasks():
        for r in range(3):
            taken.append(r)
            yield config, r

    out = execute(tasks(), "processes", workers=1, on_result=lambda r: None)
    assert [r.run for r in out] == [0, 1, 2] and taken == [0, 1, 2]
    gen = tasks()
    taken.clear()
    first = next(iter_runs_of(gen))
    assert first.run == 0 and taken == [0]  # serial: one task taken per result


def iter_runs_of(tasks):
    from cooploc.experiment import _run_task

    return (result for _, result in completed(_run_task, tasks, "serial"))


def test_the_command_line_reports_an_interrupted_run(tmp_path):
    from typer.testing import CliRunner

    from cooploc.cli import app

    with faulty("interrupt", at=2, p_fail=1.0) as name:
        result = CliRunner().invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "-e", name, "--runs", "3",
                                          "--set", "n_steps=5", "--backend", "serial", "--no-progress",
                                          "--out", str(tmp_path / "out")], env={"COLUMNS": "250"})
    assert result.exit_code == 130
    assert "incomplete: 0 of 3 runs finished (stopped by KeyboardInterrupt)" in result.output
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["complete"] is False


def test_a_refused_configuration_leaves_nothing_behind(tmp_path):
    """An estimator refused in run 0 (it can use nothing zhang2016's anonymous GNSS offers):
    the error, and no folder of empty results."""
    config = ExperimentConfig.build("zhang2016-cv", ["gnss-kf"], scenario_overrides={"n_steps": 5},
                                    runs=2, seed=1, backend="serial")
    with pytest.raises(ConfigError, match="can use nothing"):
        run_to_folder(config, tmp_path / "out")
    assert list((tmp_path / "out").iterdir()) == []


def test_cli_refusal_leaves_no_folder(tmp_path):
    from typer.testing import CliRunner

    from cooploc.cli import app

    out = tmp_path / "new"
    result = CliRunner().invoke(app, ["run", "zhang2016-cv", "-e", "gnss-kf", "--runs", "2", "--set",
                                      "n_steps=5", "--out", str(out), "--no-progress"])
    assert result.exit_code == 2 and "can use nothing" in result.output
    assert not out.exists()
