"""`summarize` is linear in runs (issue 17 item 5), checked without a clock: the elements that
element-wise operations touch on the error table's columns, per row, do not grow with the
number of runs (masking every row once per vehicle and run made them grow in proportion);
and the per-run RMSE are, bit for bit, those of that masking."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.experiment import ExperimentResult
from cooploc.metrics import ErrorTable
from cooploc.results import summarize
from helpers import load_script

bench = load_script("benchmarks/summarize.py")


class Touched(np.ndarray):
    """An array that counts the elements that ufuncs (comparisons, arithmetic) read from it."""

    elements = 0

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        Touched.elements += max(np.size(x) for x in inputs if isinstance(x, Touched))
        plain = tuple(x.view(np.ndarray) if isinstance(x, Touched) else x for x in inputs)
        return getattr(ufunc, method)(*plain, **kwargs)


def _touched_per_row(runs: int, monkeypatch) -> float:
    result = bench.fabricated(bench.study(runs, steps=6))
    real = ExperimentResult.errors

    def counted(self, name):
        run, table = real(self, name)
        columns = (getattr(table, f).view(Touched) for f in ErrorTable.__dataclass_fields__)
        return run.view(Touched), ErrorTable(*columns)

    monkeypatch.setattr(ExperimentResult, "errors", counted)
    Touched.elements = 0
    summarize(result)
    rows = sum(len(r.errors["gnss-kf"]) for r in result.runs)
    monkeypatch.setattr(ExperimentResult, "errors", real)
    return Touched.elements / rows


def test_work_per_row_does_not_grow_with_runs(monkeypatch):
    small, large = _touched_per_row(10, monkeypatch), _touched_per_row(400, monkeypatch)
    assert small > 0
    # 40 times the runs: the masking of every row per vehicle and run read 40 times more per row
    assert large < 1.5 * small, (small, large)


@pytest.mark.parametrize("runs", [1, 7])
def test_per_run_rmse_equal_the_masking_reference(runs):
    result = bench.fabricated(bench.study(runs, steps=8), seed=runs)
    summary = summarize(result)["estimators"]["gnss-kf"]["per_run_vehicle_rmse"]
    assert summary == bench.masked_per_run(result, "gnss-kf")


def test_per_run_rmse_keep_run_order_and_missing_runs():
    result = bench.fabricated(bench.study(5, steps=8))
    # an incomplete experiment whose runs are in run order with a gap, and one run without vehicle 1
    runs = [result.runs[i] for i in (0, 2, 3, 4)]
    table = runs[1].errors["gnss-kf"]
    runs[1] = dataclasses.replace(runs[1], errors={"gnss-kf": table.select(table.id != 1)})
    partial = ExperimentResult(result.config, tuple(runs))
    per_run = summarize(partial)["estimators"]["gnss-kf"]["per_run_vehicle_rmse"]
    reference = bench.masked_per_run(partial, "gnss-kf")
    reference["1"][1] = None  # no rows: null (the reference's rmse of nothing is nan)
    assert per_run == reference
