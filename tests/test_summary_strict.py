"""summary.json is strict JSON, and a diverged estimator-run is flagged and counted, never
dropped from a pooled RMSE (issue 16 item 5)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from cooploc.experiment import ExperimentConfig, ExperimentResult, RunResult, run_experiment
from cooploc.metrics import FEATURE, VEHICLE, ErrorTable, rmse
from cooploc.results import summarize, write_results
from faulty import failing_runs, faulty

SEED = 5


def _config(names=("gnss-kf",), runs=2, **overrides) -> ExperimentConfig:
    return ExperimentConfig.build("froehle2018", list(names), scenario_overrides={"n_steps": 12, **overrides},
                                  runs=runs, seed=SEED, backend="serial")


def _table(err_pos, ids, steps, kind=VEHICLE, heading=None) -> ErrorTable:
    n = len(err_pos)
    return ErrorTable(np.asarray(steps), np.asarray(steps) * 0.5, np.full(n, kind), np.asarray(ids),
                      np.asarray(err_pos, float), np.full(n, np.nan),
                      np.full(n, np.nan) if heading is None else np.asarray(heading, float),
                      np.full(n, np.nan))  # nees: no covariance


def _result(bad: float, heading: bool = False) -> ExperimentResult:
    """Two runs of vehicles 0 and 1 over 3 steps; in run 1 vehicle 1's error at step 2 is `bad`."""
    ids, steps = [0, 1] * 3, [0, 0, 1, 1, 2, 2]
    good = [1.0, 2.0, 1.0, 2.0, 1.0, 2.0]
    head = [0.1] * 6 if heading else None
    run0 = _table(good, ids, steps, heading=head)
    run1 = _table([*good[:5], bad], ids, steps,
                  heading=None if head is None else [*head[:5], np.nan if not np.isfinite(bad) else 0.1])
    runs = tuple(RunResult(r, {"gnss-kf": t}, {"gnss-kf": 1.0}, {"gnss-kf": 3}, ospa={"gnss-kf": np.ones(3)})
                 for r, t in enumerate((run0, run1)))
    return ExperimentResult(_config(), runs)


@pytest.mark.parametrize("bad", [np.inf, np.nan, 1e200])
def test_a_diverged_run_is_flagged_not_dropped(bad):
    summary = summarize(_result(bad))
    text = json.dumps(summary, allow_nan=False)  # strict JSON: raises on NaN/Infinity
    assert "Infinity" not in text and "NaN" not in text
    est = summary["estimators"]["gnss-kf"]
    assert est["diverged_runs"] == [{"run": 1, "step": 2, "vehicles": [1], "features": []}]
    # pooled figures that include the diverged row are null, not the RMSE of the others
    assert est["vehicle_rmse"] == {"0": 1.0, "1": None}
    assert est["vehicle_rmse_all"] is None and est["total_rmse"] is None
    assert est["per_run_vehicle_rmse"] == {"0": [1.0, 1.0], "1": [2.0, None]}
    assert est["heading_rmse_all"] is None  # no heading in the layout: not applicable, not diverged
    assert est["failed_runs"] == []


def test_heading_pooled_with_a_diverged_run_is_null():
    assert summarize(_result(np.inf, heading=True))["estimators"]["gnss-kf"]["heading_rmse_all"] is None
    assert summarize(_result(3.0, heading=True))["estimators"]["gnss-kf"]["heading_rmse_all"] == \
        pytest.approx(0.1, rel=1e-12)  # same arithmetic


def test_features_diverge_apart_from_vehicles():
    result = _result(3.0)
    tables = [dataclasses.replace(r, errors={"gnss-kf": ErrorTable.concatenate(
        [r.errors["gnss-kf"], _table([0.5, np.inf if r.run else 0.5], [7, 8], [1, 1], kind=FEATURE)])})
        for r in result.runs]
    est = summarize(ExperimentResult(result.config, tuple(tables)))["estimators"]["gnss-kf"]
    assert est["diverged_runs"] == [{"run": 1, "step": 1, "vehicles": [], "features": [8]}]
    assert est["feature_rmse_all"] is None
    assert est["vehicle_rmse_all"] == pytest.approx(rmse([1.0, 2.0] * 5 + [1.0, 3.0]), rel=1e-12)


def test_non_finite_parameters_are_strings():
    # a float field without bounds may hold inf (bounded ones refuse it): strict JSON still
    result = _result(1.0)
    object.__setattr__(result.config.scenario_params, "clutter_extent", float("inf"))
    summary = summarize(result)
    json.dumps(summary, allow_nan=False)
    assert summary["params"]["clutter_extent"] == "inf"


def test_rmse_skips_not_applicable_but_not_diverged_errors():
    assert rmse([3.0, 4.0, np.nan]) == pytest.approx(np.sqrt(12.5), rel=1e-15)
    assert rmse([1.0, np.inf]) == np.inf
    assert rmse([1.0, 1e200]) == np.inf  # its square overflows: as good as infinite
    assert np.isnan(rmse([np.nan]))


def test_an_estimator_that_diverges_end_to_end(tmp_path):
    p_fail = 0.5
    with faulty("diverge", at=4, p_fail=p_fail) as name:
        names = ["gnss-kf", name]
        result = run_experiment(_config(names, runs=4))
        diverged = failing_runs(name, SEED, 4, p_fail, names)
        folder = write_results(result, tmp_path / "out")
    assert 0 < len(diverged) < 4
    summary = json.loads((folder / "summary.json").read_text())
    est = summary["estimators"][name]
    assert [d["run"] for d in est["diverged_runs"]] == diverged
    assert all(d["step"] == 4 and d["vehicles"] == [0, 1] for d in est["diverged_runs"])
    assert est["vehicle_rmse_all"] is None and est["failed_runs"] == []
    assert summary["estimators"]["gnss-kf"]["diverged_runs"] == []
    assert f"{name} diverged in run {diverged[0]} from step 4" in (folder / "report.md").read_text()
