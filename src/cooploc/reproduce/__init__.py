"""Paper experiments: `cooploc reproduce PAPER` (DESIGN §6).

Each paper has one module here with a `PaperExperiment`: the sweeps of its figures,
their plots, and a Markdown report that sets the paper's numbers and statements beside
ours. An experiment uses every estimator its paper compares *that is registered*, so a
method issue only adds its estimator (and, if it needs, a line to its paper's entry).

Outputs go to `OUT/`: `fig*.png`, `report.md`, and `data.json` with every number the
figures show.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cooploc.errors import ConfigError

__all__ = ["PaperExperiment", "ReproduceOptions", "experiments", "get_experiment"]


@dataclass(frozen=True)
class ReproduceOptions:
    """How to run a paper experiment.

    Attributes
    ----------
    out : output folder.
    runs : Monte Carlo runs per point (None: the experiment's default).
    seed : the one seed of every number.
    backend, workers : as for `cooploc run`.
    quick : a small version (few runs, short trajectories) to check the pipeline.
    progress : show progress bars.
    """

    out: Path
    runs: int | None = None
    seed: int = 0
    backend: str = "processes"
    workers: int | None = None
    quick: bool = False
    progress: bool = False


@dataclass(frozen=True)
class PaperExperiment:
    """A paper's whole experiment: `run(options)` writes figures and report.md."""

    name: str
    title: str
    paper: str
    run: Callable[[ReproduceOptions], Path]


def experiments() -> dict[str, PaperExperiment]:
    """All paper experiments by name."""
    from cooploc.reproduce import brambilla2020, froehle2018, gulati, plbp, sumo, zhang2016

    modules = (froehle2018, brambilla2020, zhang2016, gulati, plbp, sumo)
    return {m.EXPERIMENT.name: m.EXPERIMENT for m in modules}


def get_experiment(name: str) -> PaperExperiment:
    known = experiments()
    if name not in known:
        raise ConfigError(f"unknown paper experiment {name!r}; known: {', '.join(sorted(known))}")
    return known[name]
