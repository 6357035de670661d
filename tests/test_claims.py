"""Verdicts of paper claims are computed from numbers: fabricated data through every check."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cooploc.errors import InvalidInputError
from cooploc.reproduce import claims as c
from cooploc.reproduce.base import PaperExperiment, ReproduceOptions


def _runs(mean: float, n: int = 20, spread: float = 0.1, seed: int = 0) -> np.ndarray:
    return mean + spread * np.random.default_rng(seed).standard_normal(n)


def test_less_paired_outcomes() -> None:
    base = _runs(2.0, seed=1)
    better = base - 0.2 + 0.01 * np.random.default_rng(2).standard_normal(base.size)
    assert c.less(better, base).outcome == c.REPRODUCED
    worse = c.less(base + 0.2, base)
    assert worse.outcome == c.NOT_REPRODUCED and "reversed" in worse.test
    tie = c.less(base + 0.001 * np.random.default_rng(3).standard_normal(base.size), base)
    assert tie.outcome == c.NOT_REPRODUCED and "not significant" in tie.test
    assert "90% interval" in tie.test


def test_less_pairing_matters() -> None:
    # a large common run-to-run spread hides a small but consistent difference unless paired
    common = _runs(2.0, spread=1.0, seed=4)
    a, b = common - 0.05, common.copy()
    assert c.less(a, b).outcome == c.REPRODUCED
    assert c.less(a, b, paired=False).outcome == c.NOT_REPRODUCED


def test_less_single_values_and_greater() -> None:
    assert c.less(1.0, 2.0).outcome == c.REPRODUCED
    assert c.less(2.0, 1.0).outcome == c.NOT_REPRODUCED
    assert "no interval" in c.less(1.0, 2.0).test
    assert c.greater(_runs(3.0), _runs(2.0, seed=5)).outcome == c.REPRODUCED


def test_close_to_is_an_equivalence_test() -> None:
    assert c.close_to(_runs(2.5, spread=0.05), 2.5, rel=0.1).outcome == c.REPRODUCED
    far = c.close_to(_runs(3.5, spread=0.05), 2.5, rel=0.1)
    assert far.outcome == c.NOT_REPRODUCED and "outside" in far.test
    straddle = c.close_to(_runs(2.75, n=5, spread=0.3), 2.5, rel=0.1)
    assert straddle.outcome == c.NOT_REPRODUCED and "inconclusive" in straddle.test
    assert c.close_to(2.6, 2.5, abs=0.2).outcome == c.REPRODUCED
    assert c.close_to(2.8, 2.5, abs=0.2).outcome == c.NOT_REPRODUCED
    with pytest.raises(InvalidInputError, match="tolerance"):
        c.close_to(2.0, 2.0)


def test_thresholds() -> None:
    assert c.at_most(1.2, 1.25).outcome == c.REPRODUCED
    assert c.at_most(1.3, 1.25).outcome == c.NOT_REPRODUCED
    assert c.at_least(0.96, 0.95).outcome == c.REPRODUCED
    assert c.at_least(0.94, 0.95).outcome == c.NOT_REPRODUCED
    near = c.at_most(_runs(1.24, spread=0.1), 1.25)
    assert "contains the limit" in near.test


def test_curves() -> None:
    assert c.trend([3.0, 2.5, 2.0, 1.9], "down").outcome == c.REPRODUCED
    assert c.trend([3.0, 2.5, 2.6, 1.9], "down").outcome == c.NOT_REPRODUCED
    assert c.trend([3.0, 2.5, 2.6, 1.9], "down", tolerance=0.2).outcome == c.REPRODUCED
    assert c.trend([1.0, 1.05], "up", tolerance=0.1).outcome == c.NOT_REPRODUCED
    assert c.flat([1.0, 1.02, 0.99], tolerance=0.05).outcome == c.REPRODUCED
    assert c.flat([1.0, 1.5, 0.99], tolerance=0.05).outcome == c.NOT_REPRODUCED
    assert c.flat([0.0, 0.03], tolerance=0.05, relative=False).outcome == c.REPRODUCED
    x = np.arange(6.0)
    assert c.linear(x, 2 * x + 1 + 0.01 * np.sin(x), min_r2=0.95).outcome == c.REPRODUCED
    assert c.linear(x, x ** 3, min_r2=0.95).outcome == c.NOT_REPRODUCED


def test_bad_input_names_the_field() -> None:
    with pytest.raises(InvalidInputError, match="direction"):
        c.trend([1.0, 2.0], "sideways")
    with pytest.raises(InvalidInputError, match="non-finite"):
        c.less([1.0, float("nan")], [1.0, 2.0])
    with pytest.raises(InvalidInputError, match="paired samples"):
        c.less([1.0, 2.0, 3.0], [1.0, 2.0])
    with pytest.raises(InvalidInputError, match="no values"):
        c.at_most([], 1.0)


def test_table_and_claims_json(tmp_path) -> None:
    def compute(ctx):
        return {"ours": [1.0, 1.1, 0.9], "bound": [0.8, 0.85, 0.75]}

    def claims(data):
        return [c.Claim("X beats the bound (Fig. 1)", "yes", "vehicle RMSE [m]",
                        c.less(data["ours"], data["bound"], names=("X", "bound"), unit=" m")),
                c.Claim("a | pipe", "–", "speed", c.not_checked("not in our scene"))]

    def report(data):
        return ["# test", "", *c.claims_table(claims(data))]

    experiment = PaperExperiment(name="t", title="t", paper="p", compute=compute, report=report,
                                 claims=claims)
    out = experiment.run(ReproduceOptions(out=tmp_path / "out", runs=1))
    records = json.loads((out / "claims.json").read_text())
    assert [r["outcome"] for r in records] == [c.NOT_REPRODUCED, c.NOT_CHECKED]
    assert records[0]["statement"].startswith("X beats")
    text = (out / "report.md").read_text()
    assert "reversed" in text and "a \\| pipe" in text
