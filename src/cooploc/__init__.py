"""cooploc — cooperative localization of connected vehicles.

Published cooperative-positioning methods as estimators, the papers' scenarios as
generators, and Monte Carlo experiments that compare them side by side.

>>> import numpy as np, cooploc
>>> recording = cooploc.get_preset("froehle2018").generate(np.random.default_rng(1))
>>> est = cooploc.make_estimator("gnss-kf", recording.setup, None, np.random.default_rng(2))
>>> estimates = [est.step(frame) for frame in recording.frames]
>>> errors = cooploc.evaluate(recording, estimates)
"""

from __future__ import annotations

__version__ = "0.1.0"

from cooploc.errors import ConfigError, CooplocError, InvalidInputError
from cooploc.estimators import get_estimator, make_estimator
from cooploc.experiment import (
    ExperimentConfig,
    ExperimentResult,
    run_experiment,
    run_sweep,
    summarize,
    write_results,
)
from cooploc.metrics import ecdf, evaluate, rmse
from cooploc.scenarios import get_preset, presets
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
    "Recording",
    "Setup",
    "StateLayout",
    "StateSet",
    "Truth",
    "__version__",
    "ecdf",
    "evaluate",
    "get_estimator",
    "get_preset",
    "make_estimator",
    "presets",
    "rmse",
    "run_experiment",
    "run_sweep",
    "summarize",
    "write_results",
]
