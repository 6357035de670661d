"""Memory budget of an experiment, checked before any work starts (issue 16, item 6).

A Monte Carlo experiment that cannot fit in memory should be refused in one line with
the estimate and what the machine has, not run for hours until `MemoryError`. The
estimate is a floor built from what scenario families and estimators say about
themselves; where one says nothing, nothing of it is counted (so no check):

- a scenario family's `Params` may define ``sizes() -> Sizes``: steps, vehicles and
  features of one run (for traffic that comes and goes: how many are ever present);
- an estimator class may define ``memory_bytes(sizes, params) -> float``: the peak of
  its own state beyond the estimates it returns (e.g. `oracle-kf`'s dense joint
  covariance, (state dimension)² floats).

The model of where memory goes (constants below measured with `tracemalloc` on the
paper presets, rounded down so that only what surely does not fit is refused):

- each worker holds one run at a time: the recording, every estimator's estimates of
  the run, and the largest estimator state;
- the main process holds the error table of every finished run and a task per run.

Time is not estimated: estimator speed depends too much on the data to promise it.
Available memory is `MemAvailable` of /proc/meminfo, else the physical memory the
operating system reports; where neither is known, no check.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from cooploc.errors import ConfigError
from cooploc.registry import get_estimator

if TYPE_CHECKING:
    from cooploc.experiment import ExperimentConfig

__all__ = ["Sizes", "available_memory", "check_memory", "estimate_memory"]

#: recording of one run, per entity and step (truth, measurements, frame objects)
RECORDING_BYTES = 200
#: estimates (means, covariances) of one estimator, per entity and step
ESTIMATE_BYTES = 40
#: error table kept in the main process, per entity, step and estimator (many estimators
#: report vehicles only, so fewer rows than entities)
RESULT_BYTES = 10
#: task tuple, future and bookkeeping of one run in the main process
TASK_BYTES = 1000


@dataclass(frozen=True)
class Sizes:
    """Sizes of one simulated run: steps, vehicles and features ever present, state dimension."""

    n_steps: int
    n_vehicles: int
    n_features: int = 0
    state_dim: int = 4

    @property
    def entity_steps(self) -> float:
        return float(self.n_steps) * (self.n_vehicles + self.n_features)


def estimate_memory(config: ExperimentConfig) -> tuple[float, str]:
    """(bytes, what dominates) of running `config`; (0, "") if the scenario reports no sizes."""
    sizes_of = getattr(config.scenario_params, "sizes", None)
    if sizes_of is None:
        return 0.0, ""
    sizes: Sizes = sizes_of()
    n_est = len(config.estimators)
    states = {spec.name: _estimator_bytes(spec.name, sizes, spec.params) for spec in config.estimators}
    largest = max(states, key=states.__getitem__)
    if config.backend == "serial":
        workers = 1
    elif config.backend == "dask":
        workers = 0  # the workers may live on other machines: count only the main process
    else:
        workers = min(config.runs, config.workers or os.cpu_count() or 1)
    entities = sizes.n_vehicles + sizes.n_features
    parts = {
        f"{workers} worker(s) × one run of {sizes.n_steps} steps × {entities} entities":
            workers * sizes.entity_steps * (RECORDING_BYTES + n_est * ESTIMATE_BYTES),
        f"{workers} worker(s) × {largest}'s state of {_size(states[largest])}": workers * states[largest],
        f"the results of {config.runs} runs": config.runs * (sizes.entity_steps * n_est * RESULT_BYTES
                                                             + TASK_BYTES),
    }
    return sum(parts.values()), max(parts, key=parts.__getitem__)


def _estimator_bytes(name: str, sizes: Sizes, params: Any) -> float:
    memory = getattr(get_estimator(name), "memory_bytes", None)
    return 0.0 if memory is None else float(memory(sizes, params))


def available_memory() -> int | None:
    """Bytes of memory available to a new process, or None where unknown."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def check_memory(config: ExperimentConfig) -> None:
    """Refuse `config` with a one-line `ConfigError` if its memory estimate exceeds what is available."""
    need, dominant = estimate_memory(config)
    have = available_memory()
    if have is None or need <= have:
        return
    raise ConfigError(f"{config.scenario}: this experiment needs about {_size(need)} of memory "
                      f"(mostly {dominant}), this machine has {_size(have)} available; "
                      f"lower --runs, --workers or the scenario's sizes")


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000:
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} EB"
