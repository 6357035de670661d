"""`PaperExperiment`: what every paper module shares (options, runs, data.json, report.md)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from cooploc.metrics import VEHICLE, total_rmse, total_rmse_per_run_and_step
from cooploc.reproduce import PaperExperiment, ReproduceContext, ReproduceOptions, experiments
from cooploc.results import summarize


def _compute(ctx: ReproduceContext) -> dict:
    result = ctx.run(ctx.config("froehle2018", scenario_overrides={"n_steps": 5}))
    run, table = result.errors("gnss-kf")
    rows = table.kind == VEHICLE
    per_run, per_step = total_rmse_per_run_and_step(run[rows], table.step[rows], table.err_pos[rows])
    return {"per_run": per_run.tolist(), "per_step": per_step.tolist(),
            "per_run_eq20": [total_rmse(table.step[rows & (run == r)], table.err_pos[rows & (run == r)])
                             for r in range(ctx.runs)],
            "rmse": summarize(result)["estimators"]["gnss-kf"]["vehicle_rmse_all"]}


TOY = PaperExperiment(
    name="toy", title="a toy experiment", paper="none.txt", compute=_compute,
    report=lambda data: ["# toy", "", f"{data['runs']} runs"],
    compared=("gnss-kf", "no-such-estimator"), runs=7, quick_runs=3,
    figures=(("Fig. 1", "fig1.png"),),
)


def test_paper_experiment_writes_common_keys_and_report(tmp_path) -> None:
    out = TOY.run(ReproduceOptions(tmp_path / "toy", seed=4, quick=True, backend="serial"))
    data = json.loads((out / "data.json").read_text())
    assert list(data)[:4] == ["runs", "seed", "quick", "compared"]
    assert (data["runs"], data["seed"], data["quick"]) == (3, 4, True)
    assert data["compared"] == ["gnss-kf"]          # only registered estimators run
    assert len(data["per_run"]) == 3 and len(data["per_step"]) == 5
    # the per-run form of eq. (20) is the same number as total_rmse over that run's rows
    np.testing.assert_allclose(data["per_run"], data["per_run_eq20"], rtol=1e-12)
    report = (out / "report.md").read_text()
    assert report == "# toy\n\n3 runs\n\n![Fig. 1](fig1.png)\n\nAll numbers: `data.json`.\n"


def test_runs_option_wins(tmp_path) -> None:
    out = TOY.run(ReproduceOptions(tmp_path, runs=2, quick=True, backend="serial"))
    assert json.loads((out / "data.json").read_text())["runs"] == 2


def test_experiments_list_imports_no_plotting() -> None:
    code = ("import sys, cooploc.reproduce as r; e = r.experiments(); "
            "print(sorted(e)); print('matplotlib' in sys.modules)")
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           check=True).stdout.splitlines()
    assert lines == [str(sorted(experiments())), "False"]
    for exp in experiments().values():
        assert exp.title and exp.paper.endswith(".txt") and exp.figures
