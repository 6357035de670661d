"""Paper experiments: `cooploc reproduce PAPER` (DESIGN §6).

Each paper has one module here with a `PaperExperiment` (`cooploc.reproduce.base`):
the sweeps of its figures, their plots, and a Markdown report that sets the paper's
numbers and statements beside ours. An experiment uses every estimator its paper
compares *that is registered*, so a method issue only adds its estimator (and, if it
needs, a line to its paper's entry).

Outputs go to `OUT/`: `fig*.png`, `report.md`, `data.json` with every number the
figures show, and `claims.json`: each claim of the paper with the verdict computed from
those numbers (`cooploc.reproduce.claims`).
"""

from __future__ import annotations

from cooploc.errors import ConfigError
from cooploc.reproduce.base import PaperExperiment, ReproduceContext, ReproduceOptions

__all__ = ["PaperExperiment", "ReproduceContext", "ReproduceOptions", "experiments", "get_experiment"]


def experiments() -> dict[str, PaperExperiment]:
    """All paper experiments by name."""
    from cooploc.reproduce import brambilla2020, froehle2018, gulati, plbp, sumo, zhang2016

    modules = (froehle2018, brambilla2020, zhang2016, gulati, plbp, sumo)
    return {m.EXPERIMENT.name: m.EXPERIMENT for m in modules}


def get_experiment(name: str) -> PaperExperiment:
    """The paper experiment `name`; a `ConfigError` naming the known ones otherwise."""
    known = experiments()
    if name not in known:
        raise ConfigError(f"unknown paper experiment {name!r}; known: {', '.join(sorted(known))}")
    return known[name]
