"""cooploc — cooperative localization of connected vehicles.

Published cooperative-positioning methods as estimators, the papers' scenarios as
generators, and Monte Carlo experiments that compare them side by side.

>>> import numpy as np, cooploc
>>> recording = cooploc.get_preset("froehle2018").generate(np.random.default_rng(1))
>>> est = cooploc.make_estimator("gnss-kf", recording.setup, None, np.random.default_rng(2))
>>> estimates = cooploc.estimate(est, recording)
>>> errors = cooploc.evaluate(recording, estimates)

Your own estimator or scenario joins with `register_estimator` / `register_scenario`
(or the entry-point groups ``cooploc.estimators`` / ``cooploc.scenarios``), and
`cooploc.testing.check_estimator` runs the contract every estimator must pass.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from cooploc._version import __version__
from cooploc.errors import ConfigError, CooplocError, EstimatorError, InvalidInputError

#: public name → the module that holds it; loaded on first access (Scientific Python
#: SPEC 1), so that `import cooploc` and the command line start without NumPy & co.
_EXPORTS = {
    "ExperimentConfig": "cooploc.config",
    "ExperimentResult": "cooploc.experiment",
    "estimate": "cooploc.experiment",
    "run_experiment": "cooploc.experiment",
    "run_sweep": "cooploc.experiment",
    "ecdf": "cooploc.metrics",
    "evaluate": "cooploc.metrics",
    "rmse": "cooploc.metrics",
    "Preset": "cooploc.registry",
    "get_estimator": "cooploc.registry",
    "get_preset": "cooploc.registry",
    "make_estimator": "cooploc.registry",
    "presets": "cooploc.registry",
    "register_estimator": "cooploc.registry",
    "register_scenario": "cooploc.registry",
    "run_to_folder": "cooploc.results",
    "summarize": "cooploc.results",
    "write_results": "cooploc.results",
    "Batch": "cooploc.types",
    "Estimate": "cooploc.types",
    "Frame": "cooploc.types",
    "Recording": "cooploc.types",
    "Setup": "cooploc.types",
    "StateLayout": "cooploc.types",
    "StateSet": "cooploc.types",
    "Truth": "cooploc.types",
}

__all__ = [
    "Batch",
    "ConfigError",
    "CooplocError",
    "Estimate",
    "EstimatorError",
    "ExperimentConfig",
    "ExperimentResult",
    "Frame",
    "InvalidInputError",
    "Preset",
    "Recording",
    "Setup",
    "StateLayout",
    "StateSet",
    "Truth",
    "__version__",
    "ecdf",
    "estimate",
    "evaluate",
    "get_estimator",
    "get_preset",
    "make_estimator",
    "presets",
    "register_estimator",
    "register_scenario",
    "rmse",
    "run_experiment",
    "run_sweep",
    "run_to_folder",
    "summarize",
    "write_results",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        value = getattr(importlib.import_module(_EXPORTS[name]), name)
        globals()[name] = value  # next time a plain attribute
        return value
    raise AttributeError(f"module 'cooploc' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # what static tools see
    from cooploc.config import ExperimentConfig
    from cooploc.experiment import ExperimentResult, estimate, run_experiment, run_sweep
    from cooploc.metrics import ecdf, evaluate, rmse
    from cooploc.registry import (
        Preset,
        get_estimator,
        get_preset,
        make_estimator,
        presets,
        register_estimator,
        register_scenario,
    )
    from cooploc.results import run_to_folder, summarize, write_results
    from cooploc.types import Batch, Estimate, Frame, Recording, Setup, StateLayout, StateSet, Truth
