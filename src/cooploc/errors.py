"""Exceptions raised by cooploc.

Every error a user can cause (bad arrays, bad configuration) is a `CooplocError`, and
its message names the field and the offending value, so that nobody has to read a
NumPy traceback from deep inside an estimator to learn what was wrong.
"""

from __future__ import annotations

__all__ = ["ConfigError", "CooplocError", "EstimatorError", "InvalidInputError"]


class CooplocError(Exception):
    """Base class of every error cooploc raises on purpose."""


class InvalidInputError(CooplocError, ValueError):
    """An array or value handed to cooploc is malformed (shape, NaN, covariance, ids)."""


class ConfigError(CooplocError, ValueError):
    """A scenario, estimator or experiment configuration is invalid (unknown key, bad value)."""


class EstimatorError(CooplocError, RuntimeError):
    """A numerical failure inside an estimator (not the user's input).

    It names the estimator, the Monte Carlo run and the step, and what failed, so the
    runner can record it and still write the other estimators' results. `run` and
    `step` are None where they are not known (yet): `cooploc.experiment.estimate`
    fills in the step, the runner the run.
    """

    def __init__(self, estimator: str, what: str, *, step: int | None = None,
                 run: int | None = None) -> None:
        self.estimator = estimator
        self.what = what
        self.step = step
        self.run = run
        super().__init__(self._message())

    def _message(self) -> str:
        where = [f"run {self.run}" if self.run is not None else "",
                 f"step {self.step}" if self.step is not None else ""]
        place = ", ".join(w for w in where if w)
        return f"{self.estimator} failed" + (f" at {place}" if place else "") + f": {self.what}"

    def at(self, *, step: int | None = None, run: int | None = None) -> EstimatorError:
        """The same failure with the step and/or run filled in (those already set stay)."""
        return EstimatorError(self.estimator, self.what,
                              step=self.step if self.step is not None else step,
                              run=self.run if self.run is not None else run)

    def __reduce__(self):  # picklable across worker processes with its fields
        return (_rebuild, (self.estimator, self.what, self.step, self.run))


def _rebuild(estimator: str, what: str, step: int | None, run: int | None) -> EstimatorError:
    return EstimatorError(estimator, what, step=step, run=run)
