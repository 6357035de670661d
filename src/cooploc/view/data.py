"""What the viewer reads from a results folder, and what it regenerates.

A results folder of `cooploc run` holds ``config.toml`` (scenario, parameters, seed,
estimators), ``errors.parquet`` and ``estimates.parquet`` (run 0's estimates). The
recording is not stored: `cooploc.experiment.run_recording(config, run)` simulates it
again, exactly, from the seed (SUMO traffic comes from its cache or is simulated again,
deterministically). Storing it
would cost more than the rest of the folder (every measurement of every step) for no
information. A run whose estimates were not kept (``--run N`` with N > 0) is run
again with the same generators, so its numbers equal those of the original run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.errors import InvalidInputError
from cooploc.types import Estimate, FloatArray, Recording

__all__ = ["RunView", "load_run", "read_config"]


@dataclass(frozen=True)
class RunView:
    """One run of a results folder: its config, preset, recording, estimates and RMSE."""

    folder: Path
    run: int
    config: Any  # cooploc.config.ExperimentConfig
    preset: Any  # cooploc.registry.Preset
    recording: Recording
    estimates: dict[str, list[Estimate]]
    rmse: dict[str, tuple[FloatArray, FloatArray]]
    recomputed: bool


def read_config(folder: Path) -> Any:
    """The `ExperimentConfig` of a results folder (its ``config.toml``)."""
    from cooploc.config import ExperimentConfig

    path = folder / "config.toml"
    if not path.is_file():
        raise InvalidInputError(f"{folder}: not a results folder of `cooploc run` (no config.toml)")
    return ExperimentConfig.read(path)


def _rmse_over_time(folder: Path, run: int) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per estimator, (t, RMSE over the vehicles) of every step of `run` from errors.parquet."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    path = folder / "errors.parquet"
    if not path.is_file():
        return {}
    table = pq.read_table(path, columns=["run", "t", "estimator", "kind", "err_pos"],
                          filters=[("run", "=", run), ("kind", "=", "vehicle")])
    out = {}
    for name in pc.unique(table["estimator"]).to_pylist():
        part = table.filter(pc.equal(table["estimator"], name))
        t_all, err = part["t"].to_numpy(), part["err_pos"].to_numpy()
        t, inverse = np.unique(t_all, return_inverse=True)
        sq = np.bincount(inverse, weights=err**2, minlength=t.size)
        count = np.bincount(inverse, minlength=t.size)
        out[name] = (t, np.sqrt(sq / np.maximum(count, 1)))
    return out


def load_run(folder: str | os.PathLike[str], run: int = 0) -> RunView:
    """Config, regenerated recording, estimates (kept, or run again) and RMSE of one run."""
    from cooploc.experiment import run_one, run_recording
    from cooploc.registry import get_preset
    from cooploc.view.estimates import read_estimates

    folder = Path(folder)
    if not folder.is_dir():
        raise InvalidInputError(f"results folder {str(folder)!r} does not exist")
    config = read_config(folder)
    if isinstance(run, bool) or run < 0 or run >= config.runs:
        raise InvalidInputError(f"--run must lie in [0, {config.runs - 1}] for {folder} "
                                f"({config.runs} runs), got {run}")
    recording = run_recording(config, run)
    estimates = read_estimates(folder, run, len(recording.frames), recording.setup.vehicle_layout.dim)
    recomputed = estimates is None
    if estimates is None:
        estimates = run_one(config, run, keep_estimates=True).estimates or {}
    names = [e.name for e in config.estimators if e.name in estimates]
    return RunView(folder, run, config, get_preset(config.scenario), recording,
                   {n: estimates[n] for n in names}, _rmse_over_time(folder, run), recomputed)
