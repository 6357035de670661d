"""Memory and time budget of an experiment, checked before any work starts (issue 16, item 6).

A Monte Carlo experiment that cannot fit in memory should be refused in one line with
the estimate and what the machine has, not run for hours until `MemoryError`. The
estimate is a floor built from what scenario families and estimators say about
themselves; where one says nothing, nothing of it is counted (so no check):

- a scenario family's `Params` may define ``sizes() -> Sizes``: steps, vehicles and
  features of one run (for traffic that comes and goes: how many are ever present);
- an estimator class may define ``memory_bytes(sizes, params) -> float``: the peak of
  its own state beyond the estimates it returns (e.g. `oracle-kf`'s dense joint
  covariance, (state dimension)² floats), and ``flops_per_step(sizes, params) -> float``:
  the floating-point operations of one step (its dense linear algebra).

The model of where memory goes (constants below measured with `tracemalloc` on the
paper presets, rounded down so that only what surely does not fit is refused):

- each worker holds one run at a time: the recording, every estimator's estimates of
  the run, and the largest estimator state; a recording that makes its frames on demand
  (`Sizes.streamed`, `cooploc.streams`) holds only its truth and the origin of every row;
- the main process holds the error table of every finished run and a task per run.

Time is a floor too: the declared operations at `FLOPS` per worker (an estimator that
declares none counts as free). It is not refused — a long study may be meant — but the
command line states it before starting when it exceeds an hour, and in a memory refusal.
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

__all__ = ["Sizes", "available_memory", "check_memory", "duration", "estimate_memory", "estimate_seconds"]

#: recording of one run, per entity and step (truth, measurements, frame objects)
RECORDING_BYTES = 200
#: the same for a recording that streams its frames (truth, presence, origins of rows):
#: 67 measured on brambilla-crossroad at 1500 steps, where the whole recording takes 834
STREAMED_RECORDING_BYTES = 60
#: estimates (means, covariances) of one estimator, per entity and step
ESTIMATE_BYTES = 40
#: error table kept in the main process, per entity, step and estimator (many estimators
#: report vehicles only, so fewer rows than entities)
RESULT_BYTES = 10
#: task tuple, future and bookkeeping of one run in the main process
TASK_BYTES = 1000
#: floating-point operations per second of one worker with BLAS (rounded up: times are floors)
FLOPS = 1e10


@dataclass(frozen=True)
class Sizes:
    """Sizes of one simulated run: steps, vehicles and features ever present, state
    dimension, and whether the recording makes its frames on demand (`cooploc.streams`)."""

    n_steps: int
    n_vehicles: int
    n_features: int = 0
    state_dim: int = 4
    streamed: bool = False

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
    states = {spec.name: _declared(spec.name, "memory_bytes", sizes, spec.params)
              for spec in config.estimators}
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
            workers * sizes.entity_steps * ((STREAMED_RECORDING_BYTES if sizes.streamed else RECORDING_BYTES)
                                            + n_est * ESTIMATE_BYTES),
        f"{workers} worker(s) × {largest}'s state of {_size(states[largest])}": workers * states[largest],
        f"the results of {config.runs} runs": config.runs * (sizes.entity_steps * n_est * RESULT_BYTES
                                                             + TASK_BYTES),
    }
    return sum(parts.values()), max(parts, key=parts.__getitem__)


def estimate_seconds(config: ExperimentConfig) -> float:
    """A floor of the wall-clock seconds of `config`: declared operations at `FLOPS` per worker."""
    sizes_of = getattr(config.scenario_params, "sizes", None)
    if sizes_of is None:
        return 0.0
    sizes: Sizes = sizes_of()
    flops = sum(_declared(spec.name, "flops_per_step", sizes, spec.params) for spec in config.estimators)
    workers = 1 if config.backend == "serial" else config.workers or os.cpu_count() or 1
    return config.runs * sizes.n_steps * flops / FLOPS / min(workers, config.runs)


def _declared(name: str, hook: str, sizes: Sizes, params: Any) -> float:
    """What estimator `name` declares through `hook` (0 where it declares nothing)."""
    method = getattr(get_estimator(name), hook, None)
    return 0.0 if method is None else float(method(sizes, params))


def duration(seconds: float) -> str:
    """Seconds as a person says them: "40 s", "3.2 h", "2.1 years"."""
    for unit, length in (("years", 365.25 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= length:
            return f"{seconds / length:.2g} {unit}"
    return f"{seconds:.2g} s"


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
    seconds = estimate_seconds(config)
    also = f" and at least {duration(seconds)} of computing" if seconds >= 3600 else ""
    raise ConfigError(f"{config.scenario}: this experiment needs about {_size(need)} of memory "
                      f"(mostly {dominant}){also}, this machine has {_size(have)} available; "
                      f"lower --runs, --workers or the scenario's sizes")


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000:
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} EB"
