"""A deliberately faulty estimator for the runner's tests (failures, divergence, interrupts).

`faulty(mode, ...)` registers a `gnss-kf` subclass under a throw-away name and takes it
back afterwards. In the runs it picks (its own generator's first draw below `p_fail`,
so the test can tell which: `failing_runs`), from step `at` on it

- ``"raise"``: raises a LinAlgError with a long, multi-line message (an array dump);
- ``"nan"``: returns an estimate whose vehicle means are NaN (built around `StateSet`'s
  own check, as a plug-in might);
- ``"diverge"``: returns finite means 1e200 m off (the error overflows when squared);
- ``"interrupt"``: raises KeyboardInterrupt (Ctrl-C during the run);
- ``"smooth"``: steps fine, then its `smooth` raises ZeroDivisionError.

Elsewhere it is exactly `gnss-kf` (same numbers).
"""

from __future__ import annotations

import contextlib
import dataclasses
import types
from collections.abc import Iterator

import numpy as np

from cooploc.estimators.gnss_kf import GnssKF
from cooploc.experiment import run_generators
from cooploc.registry import register_estimator, unregister_estimator
from cooploc.types import StateSet

ARRAY_DUMP = "Matrix is not positive definite:\n" + repr(np.arange(400.0).reshape(20, 20))


@contextlib.contextmanager
def faulty(mode: str, at: int = 3, p_fail: float = 1.0) -> Iterator[str]:
    """Register the faulty estimator; yields its name."""
    name = f"test-faulty-{mode}"  # fixed: the name seeds its generator, so tests are reproducible

    class Faulty(GnssKF):
        def __init__(self, setup, params, rng):
            super().__init__(setup, params, rng)
            self.fails = rng.random() < p_fail
            self.k = 0
            self.kept = []

        def step(self, frame):
            k, self.k = self.k, self.k + 1
            estimate = super().step(frame)
            self.kept.append(estimate)
            if not self.fails or k < at or mode == "smooth":
                return estimate
            if mode == "raise":
                raise np.linalg.LinAlgError(ARRAY_DUMP)
            if mode == "interrupt":
                raise KeyboardInterrupt
            v = estimate.vehicles
            if mode == "nan":
                bad = types.SimpleNamespace(ids=v.ids, mean=np.full_like(v.mean, np.nan), cov=v.cov)
                return dataclasses.replace(estimate, vehicles=bad)
            return dataclasses.replace(estimate, vehicles=StateSet(v.ids, v.mean + 1e200, v.cov))

        if mode == "smooth":
            def smooth(self):
                if self.fails:
                    return 1 / 0
                return self.kept

    Faulty.name = name
    register_estimator(Faulty)
    try:
        yield name
    finally:
        unregister_estimator(name)


def failing_runs(name: str, seed: int, runs: int, p_fail: float, names: list[str]) -> list[int]:
    """The runs in which `faulty(..., p_fail)` registered as `name` fails."""
    return [r for r in range(runs) if run_generators(seed, r, names)[1][name].random() < p_fail]
