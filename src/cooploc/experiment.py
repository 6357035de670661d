"""Monte Carlo experiments and parameter sweeps (DESIGN §6).

Seeding
-------
One `seed` determines every number. Run r draws from `SeedSequence([seed, r])`,
which is split into a child for the scenario and a child per estimator; an
estimator's child is keyed by its name (CRC-32), so adding or removing an estimator
from a comparison leaves the other estimators' numbers unchanged. The work unit is
one run (scenario + every estimator), and results are put back in run order, so the
numbers are identical whatever the backend (`serial`, `processes`, `dask`) or the
number of workers. Sweeps reuse the same seed for every swept value (common random
numbers), so a curve's shape is not hidden under Monte Carlo noise.

Timing: `steps_per_second` = steps processed / seconds spent inside `step`, summed
over runs — single-process throughput, whatever the backend.

`estimate(estimator, recording)` is the one way an estimator is run over a recording
(by the runner, the paper experiments, the benchmarks and the tests): `step` on every
frame, then, for an estimator with a `smooth() -> list[Estimate]` method (batch
smoothers, DESIGN §4), the smoothed estimates (one per frame) in place of the per-step
ones; the time of `smooth` counts as step time (`StepTimer`).

The summary of results and the results folder are `cooploc.results`.
"""

from __future__ import annotations

import dataclasses
import os
import time
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cooploc._version import __version__
from cooploc.errors import ConfigError
from cooploc.metrics import ErrorTable, evaluate, ospa_per_step, score_association
from cooploc.params import Params
from cooploc.registry import get_estimator, get_preset, make_estimator
from cooploc.types import Estimate, Frame, Recording

__all__ = [
    "BACKENDS",
    "EstimatorSpec",
    "ExperimentConfig",
    "ExperimentResult",
    "RunResult",
    "StepTimer",
    "estimate",
    "run_experiment",
    "run_generators",
    "run_one",
    "run_sweep",
]

BACKENDS: tuple[str, ...] = ("serial", "processes", "dask")


@dataclass(frozen=True)
class EstimatorSpec:
    """An estimator by registered name with its resolved parameters."""

    name: str
    params: Params

    @classmethod
    def of(cls, name: str, overrides: Mapping[str, Any] | None = None) -> EstimatorSpec:
        est = get_estimator(name)
        return cls(name, est.Params().with_overrides(overrides or {}))


@dataclass(frozen=True)
class ExperimentConfig:
    """The fully resolved configuration of a Monte Carlo experiment."""

    scenario: str
    scenario_params: Params
    estimators: tuple[EstimatorSpec, ...]
    runs: int = 10
    seed: int = 0
    backend: str = "processes"
    workers: int | None = None

    def __post_init__(self) -> None:
        for key, value, low in (("runs", self.runs, 1), ("seed", self.seed, 0)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                what = "a positive" if low == 1 else "a non-negative"
                raise ConfigError(f"{key} must be {what} integer, got {value!r}")
        self.check_backend(self.backend, self.workers)
        if not self.estimators:
            raise ConfigError("at least one estimator is needed (-e NAME)")
        names = [e.name for e in self.estimators]
        if len(set(names)) != len(names):
            raise ConfigError(f"estimators are listed twice: {names}")

    @staticmethod
    def check_backend(backend: Any, workers: Any) -> None:
        """Refuse an unknown backend, a bad worker count, or workers with the serial backend."""
        if not isinstance(backend, str) or backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ConfigError(f"workers must be a positive integer, got {workers!r}")
        if workers is not None and backend == "serial":
            # a worker count that nothing uses would be silently ignored
            raise ConfigError(f"workers apply to the processes and dask backends, not serial; "
                              f"got workers = {workers}")

    @classmethod
    def build(
        cls,
        scenario: str,
        estimators: Sequence[str],
        *,
        scenario_overrides: Mapping[str, Any] | None = None,
        estimator_overrides: Mapping[str, Mapping[str, Any]] | None = None,
        runs: int = 10,
        seed: int = 0,
        backend: str = "processes",
        workers: int | None = None,
    ) -> ExperimentConfig:
        """Resolve names and overrides (strings are parsed by the params' field types)."""
        preset = get_preset(scenario)
        specs = _specs(estimators, {}, estimator_overrides or {})
        return cls(scenario, preset.params.with_overrides(scenario_overrides or {}), specs,
                   runs, seed, backend, workers)

    def with_overrides(
        self,
        estimators: Sequence[str] | None = None,
        *,
        scenario_overrides: Mapping[str, Any] | None = None,
        estimator_overrides: Mapping[str, Mapping[str, Any]] | None = None,
        runs: int | None = None,
        seed: int | None = None,
        backend: str | None = None,
        workers: int | None = None,
    ) -> ExperimentConfig:
        """A copy with what is given replaced (`cooploc run --config FILE` plus options).

        `estimators` replaces the list: an estimator already in the config keeps its
        parameters, a new one starts from its defaults; then `estimator_overrides` and
        `scenario_overrides` are applied on top (strings parsed as in `build`). A backend
        given without workers drops the config's workers where the backend takes none.
        """
        names = [e.name for e in self.estimators] if estimators is None else list(estimators)
        backend = self.backend if backend is None else backend
        if workers is None and backend != "serial":
            workers = self.workers
        return type(self)(
            self.scenario, self.scenario_params.with_overrides(scenario_overrides or {}),
            _specs(names, {e.name: e.params for e in self.estimators}, estimator_overrides or {}),
            self.runs if runs is None else runs, self.seed if seed is None else seed, backend, workers)

    def to_dict(self) -> dict[str, Any]:
        """Everything needed to rerun, as plain data (written to config.toml)."""
        return {
            "cooploc_version": __version__,
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "backend": self.backend,
            "workers": self.workers,
            "scenario_params": self.scenario_params.to_dict(),
            "estimators": {e.name: e.params.to_dict() for e in self.estimators},
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ExperimentConfig:
        """Inverse of `to_dict` (e.g. a config.toml written by `cooploc run`).

        Every key is checked: an unknown key, or a value of the wrong kind (e.g.
        `estimators` not a table of tables), is a `ConfigError` naming key and value.
        """
        if not isinstance(data, Mapping):
            raise ConfigError(f"configuration must be a table of keys, got {data!r}")
        unknown = sorted(set(data) - set(_CONFIG_KEYS))
        if unknown:
            raise ConfigError(f"configuration: unknown key {unknown[0]!r}; "
                              f"valid keys: {', '.join(_CONFIG_KEYS)}")
        if "scenario" not in data:
            raise ConfigError("configuration is missing the key 'scenario'")
        scenario = data["scenario"]
        if not isinstance(scenario, str):
            raise ConfigError(f"configuration: scenario must be a preset name, got {scenario!r}")
        preset = get_preset(scenario)
        scenario_params = data.get("scenario_params", {})
        if not isinstance(scenario_params, Mapping):
            raise ConfigError(f"configuration: scenario_params must be a table of parameters, "
                              f"got {scenario_params!r}")
        estimators = data.get("estimators", {})
        if not isinstance(estimators, Mapping):
            raise ConfigError("configuration: estimators must be a table of estimator tables "
                              f"([estimators.NAME]), got {estimators!r}")
        specs = []
        for name, params in estimators.items():
            if not isinstance(params, Mapping):
                raise ConfigError(f"configuration: estimators.{name} must be a table of parameters, "
                                  f"got {params!r}")
            specs.append(EstimatorSpec(name, get_estimator(name).Params.from_dict(params)))
        return cls(scenario, type(preset.params).from_dict(scenario_params), tuple(specs),
                   runs=data.get("runs", 10), seed=data.get("seed", 0),
                   backend=data.get("backend", "processes"), workers=data.get("workers"))

    def same_experiment(self, other: ExperimentConfig) -> bool:
        """Whether `other` gives the same numbers: all but the backend and the workers agree."""
        return dataclasses.replace(self, backend="serial", workers=None) == dataclasses.replace(
            other, backend="serial", workers=None)


def _specs(names: Sequence[str], params: Mapping[str, Params],
           overrides: Mapping[str, Mapping[str, Any]]) -> tuple[EstimatorSpec, ...]:
    """Specs of `names`: their `params` where given, else defaults, with `overrides` applied."""
    stray = sorted(set(overrides) - set(names))
    if stray:
        raise ConfigError(f"--est-set names estimator {stray[0]!r}, which is not in -e: {list(names)}")
    return tuple(EstimatorSpec(n, params[n].with_overrides(overrides.get(n, {}))) if n in params
                 else EstimatorSpec.of(n, overrides.get(n)) for n in names)


#: the keys of `ExperimentConfig.to_dict` (config.toml)
_CONFIG_KEYS = ("cooploc_version", "scenario", "runs", "seed", "backend", "workers",
                "scenario_params", "estimators")


@dataclass(frozen=True)
class RunResult:
    """What one run returns: errors per estimator, time inside `step`, peak memory."""

    run: int
    errors: dict[str, ErrorTable]
    step_seconds: dict[str, float]
    n_steps: dict[str, int]
    association: dict[str, tuple[int, int]] = field(default_factory=dict)
    discarded: dict[str, tuple[int, int]] = field(default_factory=dict)
    ospa: dict[str, np.ndarray] = field(default_factory=dict)  # per step, m (metrics.ospa)


@dataclass(frozen=True)
class ExperimentResult:
    """All runs of an experiment, in run order."""

    config: ExperimentConfig
    runs: tuple[RunResult, ...]

    def errors(self, estimator: str) -> tuple[np.ndarray, ErrorTable]:
        """(run index per row, concatenated error table) of one estimator."""
        tables = [r.errors[estimator] for r in self.runs]
        run = np.concatenate([np.full(len(t), r.run) for t, r in zip(tables, self.runs, strict=True)])
        return run, ErrorTable.concatenate(tables)


# ----------------------------------------------------------------------------
# one run
# ----------------------------------------------------------------------------


def run_generators(seed: int, run: int, names: Sequence[str]
                   ) -> tuple[np.random.Generator, dict[str, np.random.Generator]]:
    """The scenario generator and one generator per estimator name for run `run`."""
    root = np.random.SeedSequence([seed, run])
    scenario_seq, estimator_root = root.spawn(2)
    estimator_rngs = {
        name: np.random.default_rng(np.random.SeedSequence(
            estimator_root.entropy,
            spawn_key=(*estimator_root.spawn_key, zlib.crc32(name.encode()))))
        for name in names
    }
    return np.random.default_rng(scenario_seq), estimator_rngs


class StepTimer:
    """Seconds spent inside an estimator's `step` (and `smooth`), summed over calls.

    >>> timer = StepTimer()
    >>> estimates = estimate(est, recording, timer=timer)     # doctest: +SKIP
    >>> timer.seconds / timer.steps                           # doctest: +SKIP
    """

    def __init__(self) -> None:
        self.seconds = 0.0
        self.steps = 0


def estimate(estimator: Any, recording: Recording | Sequence[Frame], *, smooth: bool = True,
             timer: StepTimer | None = None) -> list[Estimate]:
    """Step `estimator` through every frame; the smoothed estimates if it can smooth.

    `recording` is a `Recording` or its frames. `smooth=False` keeps the per-step
    (filtered) estimates of a batch smoother. With a `timer`, the seconds spent inside
    `step` and `smooth` (nothing else) are added to it, and the frames to its steps.
    """
    frames = recording.frames if isinstance(recording, Recording) else recording
    clock = time.perf_counter
    estimates, spent = [], 0.0
    for frame in frames:
        start = clock()
        estimates.append(estimator.step(frame))
        spent += clock() - start
    smoother = getattr(estimator, "smooth", None)
    if smooth and callable(smoother):  # batch smoother: its estimates replace the per-step ones
        start = clock()
        estimates = list(smoother())
        spent += clock() - start
    if timer is not None:
        timer.seconds += spent
        timer.steps += len(frames)
    return estimates


def run_one(config: ExperimentConfig, run: int) -> RunResult:
    """Simulate run `run` and process it with every estimator of the config."""
    preset = get_preset(config.scenario)
    names = [e.name for e in config.estimators]
    scenario_rng, estimator_rngs = run_generators(config.seed, run, names)
    recording = preset.generate(scenario_rng, config.scenario_params)
    errors, seconds, steps, association, discarded, ospa = {}, {}, {}, {}, {}, {}
    for spec in config.estimators:
        estimator = make_estimator(spec.name, recording.setup, spec.params,
                                   estimator_rngs[spec.name], recording.truth)
        timer = StepTimer()
        estimates, score = score_association(recording, estimate(estimator, recording, timer=timer))
        if score is not None and score.total:
            association[spec.name] = (score.correct, score.total)
        if score is not None and score.discarded is not None:
            discarded[spec.name] = (score.discarded, score.rows)
        errors[spec.name] = evaluate(recording, estimates)
        ospa[spec.name] = ospa_per_step(recording, estimates)
        seconds[spec.name], steps[spec.name] = timer.seconds, timer.steps
    return RunResult(run, errors, seconds, steps, association, discarded, ospa)


# ----------------------------------------------------------------------------
# backends
# ----------------------------------------------------------------------------

Task = tuple[ExperimentConfig, int]


def _worker_init() -> None:
    # Workers are single-threaded so that n workers use n cores, not n × BLAS threads.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def _run_task(task: Task) -> RunResult:
    return run_one(*task)


def execute(tasks: Sequence[Task], backend: str = "processes", workers: int | None = None,
            progress: Callable[[], None] | None = None) -> list[RunResult]:
    """Run every (config, run) task with the backend; results in task order."""
    results: list[RunResult | None] = [None] * len(tasks)
    tick = progress or (lambda: None)
    n_workers = workers or os.cpu_count() or 1
    if backend == "serial" or len(tasks) == 1 or (backend == "processes" and n_workers == 1):
        for i, task in enumerate(tasks):
            results[i] = _run_task(task)
            tick()
    elif backend == "processes":
        with ProcessPoolExecutor(max_workers=min(n_workers, len(tasks)),
                                 initializer=_worker_init) as pool:
            futures = {pool.submit(_run_task, task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                tick()
    elif backend == "dask":
        for i, result in _dask_results(tasks, n_workers):
            results[i] = result
            tick()
    else:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    return [r for r in results if r is not None]


def _dask_results(tasks: Sequence[Task], workers: int) -> Iterator[tuple[int, RunResult]]:
    """Run tasks on the current dask.distributed client, or a local cluster of `workers`."""
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:
        raise ConfigError(
            "backend 'dask' needs the dask extra: pip install 'cooploc[dask]'"
        ) from exc
    try:
        client, own = Client.current(), False
    except ValueError:  # no client yet: start a local one for this experiment
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client, own = Client(cluster), True
    try:
        futures = client.map(_run_task, list(tasks), pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        for future in dask_completed(futures):
            yield index[future.key], future.result()
    finally:
        if own:
            client.close()
            cluster.close()


class _Progress:
    """A rich progress bar over runs (silent when `enabled` is False)."""

    def __init__(self, total: int, label: str, enabled: bool) -> None:
        self.enabled = enabled
        if enabled:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )
            self.bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn())
            self.task = self.bar.add_task(label, total=total)

    def __enter__(self) -> Callable[[], None]:
        if not self.enabled:
            return lambda: None
        self.bar.start()
        return lambda: self.bar.advance(self.task)

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            self.bar.stop()


def run_experiment(config: ExperimentConfig, progress: bool = False) -> ExperimentResult:
    """All runs of `config` with its backend."""
    tasks = [(config, r) for r in range(config.runs)]
    with _Progress(len(tasks), f"{config.scenario}: runs", progress) as tick:
        results = execute(tasks, config.backend, config.workers, tick)
    return ExperimentResult(config, tuple(results))


def run_sweep(
    config: ExperimentConfig,
    key: str,
    values: Sequence[Any],
    target: str = "scenario",
    progress: bool = False,
) -> list[tuple[Any, ExperimentResult]]:
    """Repeat the experiment for each value of `key` in the scenario's params
    (`target="scenario"`) or in one estimator's params (`target=<estimator name>`).

    Every swept point uses the same seed (common random numbers). All runs of all
    points are scheduled together, so the backend stays busy across points.
    """
    configs = []
    for value in values:
        if target == "scenario":
            cfg = dataclasses.replace(
                config, scenario_params=config.scenario_params.with_overrides({key: value}))
        else:
            specs = []
            for spec in config.estimators:
                if spec.name == target:
                    spec = EstimatorSpec(spec.name, spec.params.with_overrides({key: value}))
                specs.append(spec)
            if target not in [s.name for s in specs]:
                raise ConfigError(f"sweep target {target!r} is not among the estimators")
            cfg = dataclasses.replace(config, estimators=tuple(specs))
        configs.append(cfg)
    tasks = [(cfg, r) for cfg in configs for r in range(cfg.runs)]
    with _Progress(len(tasks), f"sweep {key}", progress) as tick:
        results = execute(tasks, config.backend, config.workers, tick)
    out, i = [], 0
    for value, cfg in zip(values, configs, strict=True):
        out.append((value, ExperimentResult(cfg, tuple(results[i:i + cfg.runs]))))
        i += cfg.runs
    return out
