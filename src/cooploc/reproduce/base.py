"""What every paper experiment shares: its options, its run context, its entry.

A paper module declares one `PaperExperiment` — name, title, paper file, the
estimators the paper compares, default and quick run counts, the figure files — and
two or three functions of its own:

- `compute(context) -> data`: the runs, sweeps and figures; every number the figures
  show goes into the returned dict;
- `report(data) -> lines`: the Markdown text that sets the paper's statements beside
  ours;
- `claims(data) -> [Claim]` (optional): the paper's statements with verdicts computed
  from `data` (`cooploc.reproduce.claims`), written to claims.json.

`PaperExperiment.run(options)` does the rest: it keeps the compared estimators that
are registered (a method issue only registers its estimator), resolves the run count,
makes the results folder, writes `data.json` (the common keys ``runs``, ``seed``,
``quick`` and ``compared`` ahead of the module's data) and `report.md` (the module's
text, then the figures and a pointer to data.json).

The `ReproduceContext` handed to `compute` builds `ExperimentConfig`s with the
options' seed, backend and workers and runs them (or a sweep, or any function over
tasks) with the options' progress bars.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cooploc.backends import completed
from cooploc.experiment import (
    ExperimentConfig,
    ExperimentResult,
    RunResult,
    estimate,
    iter_tasks,
    run_generators,
    run_recording,
    sweep_configs,
)
from cooploc.registry import estimators, make_estimator
from cooploc.reproduce.checkpoint import Checkpoint, task_key
from cooploc.reproduce.claims import Claim
from cooploc.types import Estimate, Recording

__all__ = [
    "PaperExperiment",
    "ReproduceContext",
    "ReproduceOptions",
    "registered",
    "replay",
]


@dataclass(frozen=True)
class ReproduceOptions:
    """How to run a paper experiment.

    Attributes
    ----------
    out : output folder.
    runs : Monte Carlo runs per point (None: the experiment's default).
    seed : the one seed of every number.
    backend, workers, scheduler : as for `cooploc run`.
    quick : a small version (few runs, short trajectories) to check the pipeline.
    progress : show progress bars.
    resume : go on with an interrupted experiment in `out`: its finished runs and tasks
        (``out/runs/``, `cooploc.reproduce.checkpoint`) are kept, not run again.
    """

    out: Path
    runs: int | None = None
    seed: int = 0
    backend: str = "processes"
    workers: int | None = None
    quick: bool = False
    progress: bool = False
    scheduler: str | None = None
    resume: bool = False


def registered(names: Sequence[str]) -> list[str]:
    """The registered ones of `names`, in their order."""
    known = estimators()
    return [n for n in names if n in known]


@dataclass(frozen=True)
class ReproduceContext:
    """What a paper's computation needs besides its own code.

    Attributes
    ----------
    options : as given on the command line.
    out : the results folder (exists).
    runs : Monte Carlo runs per point: ``--runs``, else the experiment's quick or default count.
    compared : the registered ones of the paper's compared estimators.
    checkpoint : where each finished run and task is kept for ``--resume`` (None: nowhere).
    """

    options: ReproduceOptions
    out: Path
    runs: int
    compared: list[str]
    checkpoint: Checkpoint | None = None

    @property
    def quick(self) -> bool:
        return self.options.quick

    @property
    def seed(self) -> int:
        return self.options.seed

    def runs_or(self, default: int, quick: int) -> int:
        """A second run count (e.g. per sweep point): ``--runs``, else `quick` or `default`."""
        return self.options.runs or (quick if self.quick else default)

    def config(self, scenario: str, names: Sequence[str] | None = None, *, runs: int | None = None,
               scenario_overrides: Mapping[str, Any] | None = None,
               estimator_overrides: Mapping[str, Mapping[str, Any]] | None = None) -> ExperimentConfig:
        """The experiment of `names` (default: `compared`) on a scenario preset, seeded, with
        the options' backend and workers; overrides of estimators not in `names` are ignored."""
        names = list(self.compared if names is None else names)
        overrides = {k: v for k, v in (estimator_overrides or {}).items() if k in names}
        return ExperimentConfig.build(scenario, names, scenario_overrides=scenario_overrides,
                                      estimator_overrides=overrides, runs=runs or self.runs,
                                      seed=self.seed, backend=self.options.backend,
                                      workers=self.options.workers, scheduler=self.options.scheduler)

    def run(self, config: ExperimentConfig) -> ExperimentResult:
        """Every run of `config` (progress bar if asked); a paper's figures need every
        estimator-run, so a failed one stops here with its `EstimatorError`."""
        from cooploc.budget import check_memory

        check_memory(config)
        (result,) = self._results([config], f"{config.scenario}: runs")
        result.raise_failure()
        return result

    def sweep(self, config: ExperimentConfig, key: str, values: Sequence[Any]
              ) -> list[tuple[Any, ExperimentResult]]:
        """`config` at each value of scenario parameter `key` (common random numbers); a
        failed estimator-run stops here, as in `run`."""
        configs = sweep_configs(config, key, values)
        points = list(zip(values, self._results(configs, f"sweep {key}"), strict=True))
        for _, result in points:
            result.raise_failure()
        return points

    def run_all(self, configs: Sequence[ExperimentConfig], label: str = "runs") -> list[ExperimentResult]:
        """Every run of several configs as one pool of tasks (the workers stay busy across
        configs; put the longest first); a failed estimator-run stops here, as in `run`."""
        results = self._results(configs, label)
        for result in results:
            result.raise_failure()
        return results

    def _results(self, configs: Sequence[ExperimentConfig], label: str) -> list[ExperimentResult]:
        """The runs of every config, all scheduled together; runs the checkpoint holds are
        taken from it, the others saved to it as they finish (failed ones are not)."""
        tasks = [(c, r) for c in configs for r in range(c.runs)]
        keys = [self.checkpoint.run_key(c, r) for c, r in tasks] if self.checkpoint else []
        results: dict[int, RunResult] = self.checkpoint.held(keys) if self.checkpoint else {}
        todo = [i for i in range(len(tasks)) if i not in results]
        first = configs[0]
        for j, result in iter_tasks([tasks[i] for i in todo], first.backend, first.workers,
                                    scheduler=first.scheduler, label=label,
                                    progress=self.options.progress):
            results[todo[j]] = result
            if self.checkpoint is not None and not result.failures:
                self.checkpoint.save(keys[todo[j]], result)
        out, i = [], 0
        for c in configs:
            out.append(ExperimentResult(c, tuple(results[k] for k in range(i, i + c.runs))))
            i += c.runs
        return out

    def map(self, fn: Callable[[Any], Any], tasks: Sequence[Any], label: str) -> list[Any]:
        """`fn` over `tasks`, results in task order, on the options' backend (worker
        processes, or the Dask scheduler of ``--scheduler``) for work that is not an
        `ExperimentConfig`; a progress bar if asked; finished tasks are kept in the
        checkpoint. `fn` must be a module-level function."""
        keys = [task_key(fn, t) for t in tasks] if self.checkpoint else []
        results: dict[int, Any] = self.checkpoint.held(keys) if self.checkpoint else {}
        todo = [i for i in range(len(tasks)) if i not in results]
        progress = None
        if self.options.progress:
            from rich.progress import Progress
            progress = Progress()
            bar = progress.add_task(label, total=len(todo))
            progress.start()
        try:
            for j, result in completed(fn, [tasks[i] for i in todo], self.options.backend,
                                       self.options.workers, scheduler=self.options.scheduler):
                results[todo[j]] = result
                if self.checkpoint is not None:
                    self.checkpoint.save(keys[todo[j]], result)
                if progress is not None:
                    progress.advance(bar)
        finally:
            if progress is not None:
                progress.stop()
        return [results[i] for i in range(len(tasks))]


def replay(config: ExperimentConfig, run: int = 0) -> tuple[Recording, dict[str, list[Estimate]]]:
    """Run `run` of `config` again, keeping what `run_experiment` scores and drops: the
    recording and every estimator's estimates (smoothed where it smooths)."""
    recording = run_recording(config, run)
    _, rngs = run_generators(config.seed, run, [e.name for e in config.estimators])
    estimates = {}
    for spec in config.estimators:
        estimator = make_estimator(spec.name, recording.setup, spec.params, rngs[spec.name],
                                   recording.truth)
        estimates[spec.name] = estimate(estimator, recording)
    return recording, estimates


@dataclass(frozen=True)
class PaperExperiment:
    """A paper's whole experiment: `run(options)` writes figures, data.json and report.md.

    Attributes
    ----------
    name, title : as `cooploc list` shows them.
    paper : the paper's file in `papers/`.
    compute : the runs and figures; returns the data of data.json.
    report : data → the report's Markdown lines (the figures and the pointer to data.json
        are appended).
    compared : the estimators the paper compares (only the registered ones run).
    runs, quick_runs : Monte Carlo runs per point, by default and with ``--quick``.
    figures : (caption, file name) of each figure `compute` writes, in report order.
    data_indent : JSON indentation of data.json (None: one line, for bulky data).
    claims : data → the paper's claims with computed verdicts (`cooploc.reproduce.claims`);
        written to claims.json. The report shows them where it calls `claims_table`.
    """

    name: str
    title: str
    paper: str
    compute: Callable[[ReproduceContext], dict[str, Any]]
    report: Callable[[dict[str, Any]], list[str]]
    compared: tuple[str, ...] = ()
    runs: int = 20
    quick_runs: int = 2
    figures: tuple[tuple[str, str], ...] = ()
    data_indent: int | None = 2
    claims: Callable[[dict[str, Any]], Sequence[Claim]] | None = None

    def run(self, options: ReproduceOptions) -> Path:
        out = Path(options.out)
        out.mkdir(parents=True, exist_ok=True)
        runs = options.runs or (self.quick_runs if options.quick else self.runs)
        checkpoint = Checkpoint(out, resume=options.resume)
        context = ReproduceContext(options, out, runs, registered(self.compared), checkpoint)
        data = {"runs": runs, "seed": options.seed, "quick": options.quick,
                "compared": context.compared, **self.compute(context)}
        (out / "data.json").write_text(json.dumps(data, indent=self.data_indent) + "\n")
        if self.claims is not None:
            records = [c.to_dict() for c in self.claims(data)]
            (out / "claims.json").write_text(json.dumps(records, indent=2, ensure_ascii=False) + "\n")
        (out / "report.md").write_text(self.markdown(data))
        checkpoint.remove()  # finished: nothing to resume
        return out

    def markdown(self, data: dict[str, Any]) -> str:
        """report.md: the module's text, each figure, and the pointer to data.json."""
        lines = list(self.report(data))
        for caption, file in self.figures:
            lines += ["", f"![{caption}]({file})"]
        lines += ["", "All numbers: `data.json`."]
        return "\n".join(lines) + "\n"
