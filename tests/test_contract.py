"""The estimator contract (STYLE §9): every registered estimator, present and future.

The checks live in `cooploc.testing` (so that a plug-in's author can run them on an
estimator of their own with `check_estimator`); this module parametrises them over
every registered estimator, so a newly registered one is covered without touching
this file. A check that cannot apply to an estimator's preset is skipped with the
reason; the long-run check is slow.

This module also checks that the contract can fail: estimators that break it one way
each (NaN, wrong ids, reading truth, a constant) must be caught by the check named.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import pytest

from cooploc.estimators import estimators, get_estimator
from cooploc.estimators.gnss_kf import GnssKF
from cooploc.testing import CHECKS, CheckSkipped, check_estimator, run_check
from cooploc.types import Estimate, Frame, StateSet

NAMES = sorted(estimators())


def test_registry_is_not_empty() -> None:
    assert {"gnss-kf", "oracle-kf"} <= set(NAMES)


@pytest.mark.parametrize(
    "check", [pytest.param(c, marks=pytest.mark.slow) if CHECKS[c].slow else c for c in CHECKS])
@pytest.mark.parametrize("name", NAMES)
def test_contract(name: str, check: str, seed: int) -> None:
    try:
        run_check(name, check, seed)
    except CheckSkipped as exc:
        pytest.skip(str(exc))


# ----------------------------------------------------------------------------
# the contract catches what it should
# ----------------------------------------------------------------------------


class _Broken(GnssKF):
    """gnss-kf with one defect, chosen by `defect` (never registered)."""

    name: ClassVar[str] = "broken-kf"
    defect: ClassVar[str] = ""

    def step(self, frame: Frame) -> Estimate:
        out = super().step(frame)
        v = out.vehicles
        if self.defect == "nan" and frame.k == 3 and len(v):
            mean = v.mean.copy()
            mean[0, 0] = np.nan
            return _raw(v.ids, mean, v.cov)
        if self.defect == "drops a vehicle" and len(v) > 1:
            return Estimate(StateSet(v.ids[1:], v.mean[1:], v.cov[1:]))
        if self.defect == "constant":
            return Estimate(StateSet(v.ids, np.zeros_like(v.mean), v.cov))
        return out


def _raw(ids: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> Estimate:
    """An Estimate whose StateSet skips validation (a defective estimator could build one)."""
    states = object.__new__(StateSet)
    for key, value in (("ids", ids), ("mean", mean), ("cov", cov)):
        object.__setattr__(states, key, value)
    return Estimate(states)


def _broken(defect: str) -> type:
    return type(f"Broken_{defect.replace(' ', '_')}", (_Broken,), {"defect": defect})


@pytest.mark.parametrize(("defect", "check"), [
    ("nan", "valid_estimates"),
    ("drops a vehicle", "valid_estimates"),
    ("constant", "valid_estimates"),
])
def test_the_contract_catches_defects(defect: str, check: str, seed: int) -> None:
    with pytest.raises(AssertionError):
        run_check(_broken(defect), check, seed)
    with pytest.raises(AssertionError, match=f"^{check}: broken-kf fails the contract"):
        check_estimator(_broken(defect), seed=seed, slow=False)


def test_the_contract_catches_an_estimator_that_takes_truth(seed: int) -> None:
    class Peeking(GnssKF):
        name: ClassVar[str] = "peeking-kf"

        def __init__(self, setup: Any, params: Any, rng: Any, truth: Any = None) -> None:
            super().__init__(setup, params, rng)

    with pytest.raises(AssertionError):
        run_check(Peeking, "truth_only_to_references", seed)


def test_check_estimator_reports_every_check(seed: int) -> None:
    outcome = check_estimator(get_estimator("gnss-kf"), seed=seed, slow=False)
    assert set(outcome) == {c for c in CHECKS if not CHECKS[c].slow}
    assert outcome["valid_estimates"] == "passed"
    assert all(v == "passed" or v.startswith("skipped: ") for v in outcome.values())
