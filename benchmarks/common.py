"""What the benchmark scripts share: the environment record, JSON output, recordings and step timing.

Every script in this folder imports from here, so that their JSON files describe the
machine with the same keys and time estimators the same way:

- `environment()`: versions, platform, CPU count and load average at the start;
- `write_json()`: the results, with the load average at the end, to a JSON file;
- `recording()`: a recording of a preset with overridden parameters;
- `new_estimator()`, `run_steps()`: a seeded estimator, and the time spent inside its `step`;
- `peak_memory()`, `step_memory()`: peak traced memory, always in a pass of its own
  because tracemalloc slows Python down;
- `time_steps()`, `time_estimator()`: best-of-repeats steps per second and peak memory.

Scripts load this module with `from common import ...` after putting this folder on
`sys.path`, which `python benchmarks/<name>.py` does already and a script loaded from
its file (the tests, through importlib) does not.
"""

from __future__ import annotations

import json
import os
import platform
import tracemalloc
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cooploc import __version__
from cooploc.estimators import Estimator, make_estimator
from cooploc.experiment import StepTimer, estimate
from cooploc.params import Params
from cooploc.scenarios import get_preset
from cooploc.types import Estimate, Frame, Recording


def _load_average() -> float | None:
    # the machine may be shared: a loaded machine's numbers are lower bounds
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def _numba_version() -> str | None:
    try:
        import numba
    except ImportError:  # an environment without it says so rather than failing
        return None
    return numba.__version__


def environment() -> dict[str, Any]:
    """What the numbers depend on: versions, platform, CPU count, and the load average now.

    Keys: cooploc_version, python, numpy, numba (None if not importable), platform,
    machine, cpu_count, load_average (1-minute; None where the OS has none).
    """
    return {
        "cooploc_version": __version__,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": _numba_version(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "load_average": _load_average(),
    }


def write_json(results: dict[str, Any], out: Path) -> None:
    """Add `load_average_end` to `results`, write them to `out` (creating its folder) and say where."""
    results["load_average_end"] = _load_average()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"written {out}")


def recording(preset_name: str, seed: int, overrides: dict[str, Any] | None = None) -> Recording:
    """The recording of preset `preset_name` with `overrides` on its parameters, from `seed`."""
    preset = get_preset(preset_name)
    params = preset.params.with_overrides(overrides or {})
    return preset.generate(np.random.default_rng(seed), params)


def new_estimator(name: str, rec: Recording, params: Params | None = None, seed: int = 0) -> Estimator:
    """Estimator `name` for recording `rec`, seeded; known-association references get the truth."""
    return make_estimator(name, rec.setup, params, np.random.default_rng(seed), rec.truth)


def run_steps(est: Estimator, frames: Sequence[Frame]) -> tuple[float, list[Estimate]]:
    """Seconds spent inside `est.step` over `frames` (nothing else timed), and the estimates."""
    timer = StepTimer()
    estimates = estimate(est, frames, smooth=False, timer=timer)
    return timer.seconds, estimates


def peak_memory(fn: Callable[[], object]) -> int:
    """Peak memory traced while `fn()` runs, in bytes."""
    tracemalloc.start()
    try:
        fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return int(peak)


def step_memory(est: Estimator, frames: Sequence[Frame]) -> int:
    """Peak traced memory while `est` steps through `frames`, each estimate dropped when done."""

    def steps() -> None:
        for frame in frames:
            est.step(frame)

    return peak_memory(steps)


def time_steps(name: str, rec: Recording, repeats: int,
               params: Params | None = None) -> tuple[dict[str, Any], list[Estimate]]:
    """`time_estimator`'s record, and the estimates of the last timed pass."""
    best = np.inf
    for r in range(repeats):
        spent, estimates = run_steps(new_estimator(name, rec, params, seed=r), rec.frames)
        best = min(best, spent)
    peak = step_memory(new_estimator(name, rec, params), rec.frames)
    n = len(rec.frames)
    record = {"steps": n, "seconds": best, "steps_per_second": n / best, "us_per_step": best / n * 1e6,
              "peak_memory_bytes": peak}
    return record, estimates


def time_estimator(name: str, rec: Recording, repeats: int, params: Params | None = None) -> dict[str, Any]:
    """Time inside `step` over recording `rec`, best of `repeats` passes with a fresh
    estimator each (seeded by pass): steps, seconds, steps_per_second, us_per_step; and
    peak_memory_bytes of a separate pass."""
    return time_steps(name, rec, repeats, params)[0]
