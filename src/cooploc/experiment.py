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

Failures
--------
An exception raised inside an estimator's `step` or `smooth` is the estimator's
failure, not the experiment's: `estimate` turns it into an `EstimatorError` naming
the estimator, the step and what failed (the exception's class and the first line of
its message, bounded; the original is chained, so its traceback is kept), and so is
an estimate whose means or covariances are not finite. Every `Exception` is wrapped,
`CooplocError`s raised inside `step` too (the frames were checked when the recording
was loaded or generated, so what goes wrong inside an estimator is the estimator's),
except `MemoryError`, which says the machine is too small, not that the estimator
failed; `KeyboardInterrupt` and `SystemExit` are not `Exception`s and stop the
experiment. `run_one` records each failed estimator-run as a `Failure` in
`RunResult.failures` (with the traceback text) and goes on with the other estimators,
whose numbers do not depend on it (their generators are their own).

Streaming
---------
`iter_runs` yields the runs of an experiment as they finish (completion order, each
numbered by `RunResult.run`); `execute`, `run_experiment` and `run_sweep` put them back
in task order, and take an optional `on_result` callback. The backends
(`cooploc.backends`) take the (config, run) tasks lazily, a few per worker ahead, so a
large `runs` builds no big list up front. `cooploc.results.run_to_folder` writes each
run to disk as it finishes, and a resumed experiment passes the runs it has already to
`iter_runs(..., skip=...)`.

The configuration (`ExperimentConfig`, `EstimatorSpec`) is `cooploc.config`, re-exported
here; the summary of results and the results folder are `cooploc.results`.
"""

from __future__ import annotations

import dataclasses
import time
import traceback
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cooploc.backends import BACKENDS, completed
from cooploc.config import EstimatorSpec, ExperimentConfig
from cooploc.errors import ConfigError, EstimatorError
from cooploc.metrics import ErrorTable, evaluate, ospa_per_step, score_association
from cooploc.registry import get_estimator, get_preset, make_estimator, unused_kinds
from cooploc.types import Estimate, Frame, Recording, StateSet

__all__ = [
    "BACKENDS",
    "EstimatorSpec",
    "ExperimentConfig",
    "ExperimentResult",
    "Failure",
    "RunResult",
    "StepTimer",
    "estimate",
    "execute",
    "iter_runs",
    "iter_tasks",
    "run_configs",
    "run_experiment",
    "run_generators",
    "run_one",
    "run_recording",
    "run_sweep",
    "sweep_configs",
]



@dataclass(frozen=True)
class Failure:
    """An estimator-run that ended in an `EstimatorError`: where, what, and the traceback.

    `step` is None where the failure was not at a step (e.g. in `smooth`); `what` is
    the bounded one-line description, `traceback` the full text (chained exceptions
    included) for failures.log.
    """

    estimator: str
    run: int
    step: int | None
    what: str
    traceback: str = ""

    @classmethod
    def of(cls, error: EstimatorError, run: int) -> Failure:
        """The record of `error` (raised, so that it has a traceback) in run `run`."""
        text = "".join(traceback.format_exception(type(error), error, error.__traceback__))
        return cls(error.estimator, run, error.step, error.what, text)

    @property
    def message(self) -> str:
        """One line naming the estimator, run, step and what failed."""
        return str(EstimatorError(self.estimator, self.what, step=self.step, run=self.run))


@dataclass(frozen=True)
class RunResult:
    """What one run returns: errors per estimator, time inside `step`, peak memory.

    An estimator that failed in this run is in `failures` and in none of the other
    dicts (its partial estimates are not scored).
    """

    run: int
    errors: dict[str, ErrorTable]
    step_seconds: dict[str, float]
    n_steps: dict[str, int]
    association: dict[str, tuple[int, int]] = field(default_factory=dict)  # (correct, paired) per track
    discarded: dict[str, tuple[int, int]] = field(default_factory=dict)
    ospa: dict[str, np.ndarray] = field(default_factory=dict)  # per step, m (metrics.ospa)
    failures: dict[str, Failure] = field(default_factory=dict)
    unused_kinds: dict[str, tuple[str, ...]] = field(default_factory=dict)  # registry.unused_kinds
    nis: dict[str, tuple[float, int]] = field(default_factory=dict)  # (Σ NIS, Σ dof), `_nis_total`
    # (correct, paired) V2F rows by the per-step measure (`metrics.score_association`)
    association_per_step: dict[str, tuple[int, int]] = field(default_factory=dict)
    # run 0 only: each estimator's estimates for the viewer (`cooploc.view.estimates`)
    estimates: dict[str, list[Estimate]] | None = None


@dataclass(frozen=True)
class ExperimentResult:
    """The runs of an experiment, in run order (all of them unless it was interrupted)."""

    config: ExperimentConfig
    runs: tuple[RunResult, ...]

    def errors(self, estimator: str) -> tuple[np.ndarray, ErrorTable]:
        """(run index per row, concatenated error table) of one estimator, over the runs
        it finished."""
        done = [r for r in self.runs if estimator in r.errors]
        tables = [r.errors[estimator] for r in done]
        run = np.concatenate([np.full(len(t), r.run) for t, r in zip(tables, done, strict=True)]
                             or [np.zeros(0, np.int64)])
        return run, ErrorTable.concatenate(tables)

    @property
    def complete(self) -> bool:
        """Whether every run of the configuration finished."""
        return len(self.runs) == self.config.runs

    def failures(self) -> list[Failure]:
        """Every failed estimator-run, in run order."""
        return [f for r in self.runs for f in r.failures.values()]

    def raise_failure(self) -> None:
        """Raise the first failure as its `EstimatorError` (for callers that need every
        estimator's numbers, e.g. a paper's figures)."""
        for failure in self.failures():
            raise EstimatorError(failure.estimator, failure.what, step=failure.step, run=failure.run)


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


def run_recording(config: ExperimentConfig, run: int) -> Recording:
    """The recording of run `run` of `config`: simulated from the run's scenario generator,
    so the same, bit for bit, wherever and whenever it is made again (the viewer, the
    paper experiments and `cooploc compare` rebuild runs this way instead of storing them)."""
    scenario_rng, _ = run_generators(config.seed, run, [e.name for e in config.estimators])
    return get_preset(config.scenario).generate(scenario_rng, config.scenario_params)


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

    Raises
    ------
    EstimatorError
        An exception inside `step` or `smooth` (see the module docstring for which), or
        an estimate with a non-finite mean or covariance; it names the estimator, the
        step (None for `smooth`) and what failed, and chains the original exception.
    """
    frames = recording.frames if isinstance(recording, Recording) else recording
    name = _name(estimator)
    clock = time.perf_counter
    estimates, spent = [], 0.0
    step: int | None = None
    in_smooth = False
    try:
        for step, frame in enumerate(frames):
            start = clock()
            estimates.append(estimator.step(frame))
            spent += clock() - start
            _check_finite(name, estimates[-1], step)
        smoother = getattr(estimator, "smooth", None)
        if smooth and callable(smoother):  # batch smoother: its estimates replace the per-step ones
            step, in_smooth = None, True
            start = clock()
            estimates = list(smoother())
            spent += clock() - start
            for k, smoothed in enumerate(estimates):
                _check_finite(name, smoothed, k)
    except EstimatorError as exc:
        if exc.step is not None or step is None:
            raise
        raise exc.at(step=step) from exc
    except MemoryError:
        raise
    except Exception as exc:  # the estimator's failure, see "Failures" in the module docstring
        what = ("in smooth: " if in_smooth else "") + _describe(exc)
        raise EstimatorError(name, what, step=step) from exc
    if timer is not None:
        timer.seconds += spent
        timer.steps += len(frames)
    return estimates


WHAT_MAX_CHARS = 200  # of an EstimatorError's `what`: one line, never an array dump


def _describe(exc: BaseException) -> str:
    """`Class: first line of the message`, at most WHAT_MAX_CHARS characters."""
    lines = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    return text if len(text) <= WHAT_MAX_CHARS else text[:WHAT_MAX_CHARS - 1] + "…"


def _name(estimator: Any) -> str:
    return getattr(type(estimator), "name", None) or type(estimator).__name__


def _check_finite(name: str, estimate_k: Estimate, step: int) -> None:
    """Raise unless every mean and covariance of the estimate is finite. A `StateSet` has
    been checked on construction (`types.float_array`) and its arrays are read-only, so
    only beliefs built some other way (a plug-in's own classes) are tested here: the
    check costs nothing for the built-in estimators."""
    for part in ("vehicles", "features"):
        states = getattr(estimate_k, part)
        if states is None or type(states) is StateSet:
            continue
        for array in ("mean", "cov"):
            if not np.isfinite(getattr(states, array)).all():
                raise EstimatorError(name, f"non-finite estimate ({part}.{array})", step=step)


def _nis_total(estimates: Sequence[Estimate]) -> tuple[float, int] | None:
    """(Σ NIS, Σ dof) over the steps of a run (``Estimate.info["nis"]``); None if no step has it."""
    steps = [e.info["nis"] for e in estimates if "nis" in e.info]
    return (float(sum(v for v, _ in steps)), int(sum(d for _, d in steps))) if steps else None


def run_one(config: ExperimentConfig, run: int, keep_estimates: bool | None = None) -> RunResult:
    """Simulate run `run` and process it with every estimator of the config.

    An estimator that fails (`EstimatorError`) is recorded in `RunResult.failures`; the
    other estimators go on. The estimates are kept in the result (for the viewer) for
    run 0, or as `keep_estimates` says.
    """
    recording = run_recording(config, run)
    _, estimator_rngs = run_generators(config.seed, run, [e.name for e in config.estimators])
    errors, seconds, steps, association, discarded, ospa, unused, nis = {}, {}, {}, {}, {}, {}, {}, {}
    per_step = {}
    failures = {}
    kept: dict[str, list[Estimate]] | None = {} if (run == 0 if keep_estimates is None
                                                    else keep_estimates) else None
    for spec in config.estimators:
        estimator = make_estimator(spec.name, recording.setup, spec.params,
                                   estimator_rngs[spec.name], recording.truth)
        unused[spec.name] = unused_kinds(get_estimator(spec.name), recording.setup, estimator) or ()
        timer = StepTimer()
        try:
            estimates = estimate(estimator, recording, timer=timer)
        except EstimatorError as exc:
            failures[spec.name] = Failure.of(exc, run)
            continue
        estimates, score = score_association(recording, estimates)
        if score is not None and score.total:
            association[spec.name] = (score.correct, score.total)
            per_step[spec.name] = (score.per_step_correct, score.total)
        if score is not None and score.discarded is not None:
            discarded[spec.name] = (score.discarded, score.rows)
        if (total := _nis_total(estimates)) is not None:
            nis[spec.name] = total
        with np.errstate(over="ignore"):  # a diverged estimate's error overflows: summarize flags it
            errors[spec.name] = evaluate(recording, estimates)
            ospa[spec.name] = ospa_per_step(recording, estimates)
        seconds[spec.name], steps[spec.name] = timer.seconds, timer.steps
        if kept is not None:
            from cooploc.view.estimates import kept_estimates

            kept[spec.name] = kept_estimates(recording, estimates)
    return RunResult(run, errors, seconds, steps, association, discarded, ospa, failures=failures,
                     unused_kinds=unused, nis=nis, association_per_step=per_step, estimates=kept)


# ----------------------------------------------------------------------------
# backends
# ----------------------------------------------------------------------------

Task = tuple[ExperimentConfig, int]


def _run_task(task: Task) -> RunResult:
    return run_one(*task)


def execute(tasks: Iterable[Task], backend: str = "processes", workers: int | None = None,
            progress: Callable[[], None] | None = None,
            on_result: Callable[[RunResult], None] | None = None, *, scheduler: str | None = None,
            announce: Callable[[str], None] | None = None) -> list[RunResult]:
    """Run every (config, run) task with the backend; results in task order.

    `on_result` is called with each result as it finishes (completion order), e.g. to
    write it to disk; `progress` is called once per finished task. `scheduler` and
    `announce` are those of `cooploc.backends.completed` (a Dask scheduler address, and
    where to say which cluster runs the tasks).
    """
    results: dict[int, RunResult] = {}
    for i, result in completed(_run_task, tasks, backend, workers, scheduler=scheduler, announce=announce):
        results[i] = result
        if on_result is not None:
            on_result(result)
        if progress is not None:
            progress()
    return [results[i] for i in sorted(results)]


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

    def note(self, text: str) -> None:
        """Print one line above the bar (nothing when the bar is not shown)."""
        if self.enabled:
            self.bar.console.print(text, highlight=False, markup=False, soft_wrap=True)


class _Tasks:
    """The (config, run) tasks of every config in order, made as they are taken (a large
    `runs` builds no list up front); the runs in `skip` are left out (of every config)."""

    def __init__(self, configs: Sequence[ExperimentConfig], skip: frozenset[int] = frozenset()) -> None:
        self.configs, self.skip = tuple(configs), skip

    def __len__(self) -> int:
        return sum(c.runs - sum(1 for r in self.skip if 0 <= r < c.runs) for c in self.configs)

    def __iter__(self) -> Iterator[Task]:
        return ((c, r) for c in self.configs for r in range(c.runs) if r not in self.skip)


def run_experiment(config: ExperimentConfig, progress: bool = False,
                   on_result: Callable[[RunResult], None] | None = None) -> ExperimentResult:
    """All runs of `config` with its backend; `on_result` is called with each run as it
    finishes (completion order; the returned result is in run order either way).

    An experiment that surely does not fit in memory is refused first
    (`cooploc.budget.check_memory`)."""
    from cooploc.budget import check_memory

    check_memory(config)
    tasks = _Tasks([config])
    bar = _Progress(len(tasks), f"{config.scenario}: runs", progress)
    with bar as tick:
        results = execute(tasks, config.backend, config.workers, tick, on_result,
                          scheduler=config.scheduler, announce=bar.note)
    return ExperimentResult(config, tuple(results))


def iter_runs(config: ExperimentConfig, progress: bool = False,
              skip: Iterable[int] = ()) -> Iterator[RunResult]:
    """The runs of `config` as they finish (completion order), with its backend; the run
    numbers in `skip` are not run (a resumed experiment's finished runs).

    Stopping the iteration (or an interrupt) cancels the runs not started yet. The
    numbers are those of `run_experiment`: sort by `RunResult.run` to get its order.
    """
    tasks = _Tasks([config], frozenset(skip))
    bar = _Progress(len(tasks), f"{config.scenario}: runs", progress)
    with bar as tick:
        for _, result in completed(_run_task, tasks, config.backend, config.workers,
                                   scheduler=config.scheduler, announce=bar.note):
            tick()
            yield result


def iter_tasks(tasks: Sequence[Task], backend: str = "processes", workers: int | None = None, *,
               scheduler: str | None = None, label: str = "runs", progress: bool = False
               ) -> Iterator[tuple[int, RunResult]]:
    """(index in `tasks`, result) of every (config, run) task as it finishes, with the
    backend, under one progress bar labelled `label` (for callers that keep each run as it
    finishes, e.g. `reproduce`'s checkpoints)."""
    bar = _Progress(len(tasks), label, progress)
    with bar as tick:
        for i, result in completed(_run_task, tasks, backend, workers, scheduler=scheduler,
                                   announce=bar.note):
            tick()
            yield i, result


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
    configs = sweep_configs(config, key, values, target)
    return list(zip(values, run_configs(configs, progress, f"sweep {key}"), strict=True))


def sweep_configs(config: ExperimentConfig, key: str, values: Sequence[Any],
                  target: str = "scenario") -> list[ExperimentConfig]:
    """`config` with `key` set to each of `values` in the scenario's params
    (`target="scenario"`) or in one estimator's params (`target=<estimator name>`)."""
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
    return configs


def run_configs(configs: Sequence[ExperimentConfig], progress: bool = False, label: str = "runs"
                ) -> list[ExperimentResult]:
    """Every run of every config, scheduled together on the first config's backend (the
    workers stay busy from one config to the next; put the longest first), results in
    config order."""
    if not configs:
        return []
    first = configs[0]
    tasks = _Tasks(configs)
    bar = _Progress(len(tasks), label, progress)
    with bar as tick:
        results = execute(tasks, first.backend, first.workers, tick, scheduler=first.scheduler,
                          announce=bar.note)
    out, i = [], 0
    for cfg in configs:
        out.append(ExperimentResult(cfg, tuple(results[i:i + cfg.runs])))
        i += cfg.runs
    return out
