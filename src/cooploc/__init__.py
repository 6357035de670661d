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

from cooploc._version import __version__
from cooploc.errors import ConfigError, CooplocError, InvalidInputError
from cooploc.experiment import (
    ExperimentConfig,
    ExperimentResult,
    estimate,
    run_experiment,
    run_sweep,
)
from cooploc.metrics import ecdf, evaluate, rmse
from cooploc.registry import (
    Preset,
    estimators,
    get_estimator,
    get_preset,
    make_estimator,
    presets,
    register_estimator,
    register_scenario,
)
from cooploc.results import summarize, write_results
from cooploc.types import (
    Batch,
    Estimate,
    Frame,
    Recording,
    Setup,
    StateLayout,
    StateSet,
    Truth,
)

__all__ = [
    "Batch",
    "ConfigError",
    "CooplocError",
    "Estimate",
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
    "estimators",
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
    "summarize",
    "write_results",
]
