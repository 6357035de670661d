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

Smoothers: an estimator with a `smooth() -> list[Estimate]` method (batch smoothers,
DESIGN §4) is asked for it after its last `step`; the smoothed estimates (one per
frame) replace the per-step ones in the scores, and the time of `smooth` counts as
step time.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cooploc import __version__
from cooploc.errors import ConfigError
from cooploc.estimators import get_estimator, make_estimator
from cooploc.metrics import (
    FEATURE,
    KIND_NAMES,
    VEHICLE,
    ErrorTable,
    evaluate,
    ospa_per_step,
    per_entity_rmse,
    relabel,
    rmse,
    total_rmse,
    track_identities,
)
from cooploc.params import Params
from cooploc.scenarios import get_preset

__all__ = [
    "BACKENDS",
    "EstimatorSpec",
    "ExperimentConfig",
    "ExperimentResult",
    "run_experiment",
    "run_sweep",
    "summarize",
    "write_results",
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
        if isinstance(self.runs, bool) or not isinstance(self.runs, int) or self.runs < 1:
            raise ConfigError(f"runs must be a positive integer, got {self.runs!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        if self.backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if self.workers is not None and (not isinstance(self.workers, int) or self.workers < 1):
            raise ConfigError(f"workers must be a positive integer, got {self.workers!r}")
        if not self.estimators:
            raise ConfigError("at least one estimator is needed (-e NAME)")
        names = [e.name for e in self.estimators]
        if len(set(names)) != len(names):
            raise ConfigError(f"estimators are listed twice: {names}")

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
        estimator_overrides = dict(estimator_overrides or {})
        stray = sorted(set(estimator_overrides) - set(estimators))
        if stray:
            raise ConfigError(
                f"--est-set names estimator {stray[0]!r}, which is not in -e: {list(estimators)}"
            )
        specs = tuple(EstimatorSpec.of(n, estimator_overrides.get(n)) for n in estimators)
        return cls(scenario, preset.params.with_overrides(scenario_overrides or {}), specs,
                   runs, seed, backend, workers)

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
        """Inverse of `to_dict` (e.g. a config.toml written by `cooploc run`)."""
        try:
            preset = get_preset(data["scenario"])
            specs = tuple(
                EstimatorSpec(name, get_estimator(name).Params.from_dict(params))
                for name, params in dict(data.get("estimators", {})).items()
            )
            return cls(
                data["scenario"],
                type(preset.params).from_dict(data.get("scenario_params", {})),
                specs,
                runs=data.get("runs", 10),
                seed=data.get("seed", 0),
                backend=data.get("backend", "processes"),
                workers=data.get("workers"),
            )
        except KeyError as exc:
            raise ConfigError(f"configuration is missing the key {exc.args[0]!r}") from None


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
        estimates, spent = [], 0.0
        correct = total = dropped = rows = 0
        tracks, track_origins = [], []
        for frame in recording.frames:
            start = time.perf_counter()
            estimate = estimator.step(frame)
            spent += time.perf_counter() - start
            estimates.append(estimate)
            true = recording.truth.origin[frame.k].get("v2f", np.zeros(0, np.int64))
            decided = estimate.info.get("v2f_association")
            if decided is not None and "v2f_track" not in estimate.info:
                # decided origin per V2F row, for association accuracy (self-named tracks below)
                correct += int(np.sum(np.asarray(decided) == true))
                total += int(true.size)
            track = estimate.info.get("v2f_track")
            if track is not None:    # the estimator's own track id per V2F row (−1: none)
                tracks.append(np.asarray(track))
                track_origins.append(true)
                dropped += int(estimate.info.get("v2f_discarded", 0))
                rows += int(true.size)
        smooth = getattr(estimator, "smooth", None)
        if callable(smooth):  # batch smoother: score the smoothed estimates (module doc)
            start = time.perf_counter()
            estimates = list(smooth())
            spent += time.perf_counter() - start
        if tracks:
            # score self-named feature tracks as the true feature most of their rows came from
            identity = track_identities(tracks, track_origins)
            for track, true in zip(tracks, track_origins, strict=True):
                paired = track >= 0
                named = np.array([identity.get(int(t), -2) for t in track[paired]], dtype=np.int64)
                correct += int(np.sum(named == true[paired]))
                total += int(paired.sum())
            estimates = [dataclasses.replace(e, features=relabel(e.features, identity))
                         if e.features is not None else e for e in estimates]
            discarded[spec.name] = (dropped, rows)
        errors[spec.name] = evaluate(recording, estimates)
        ospa[spec.name] = ospa_per_step(recording, estimates)
        seconds[spec.name], steps[spec.name] = spent, len(recording.frames)
        if total:
            association[spec.name] = (correct, total)
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


# ----------------------------------------------------------------------------
# summary and results folder
# ----------------------------------------------------------------------------


def _finite_or_none(value: float) -> float | None:
    return None if value is None or not np.isfinite(value) else float(value)


def summarize(result: ExperimentResult) -> dict[str, Any]:
    """The `summary.json` contract of DESIGN §6."""
    config = result.config
    out: dict[str, Any] = {
        "cooploc_version": __version__,
        "scenario": config.scenario,
        "params": config.scenario_params.to_dict(),
        "runs": config.runs,
        "seed": config.seed,
        "estimators": {},
    }
    for spec in config.estimators:
        run, table = result.errors(spec.name)
        vehicles = table.kind == VEHICLE
        features = table.kind == FEATURE
        per_run: dict[str, list[float | None]] = {}
        vehicle_ids = np.unique(table.id[vehicles])
        for vid in vehicle_ids:
            rows = vehicles & (table.id == vid)
            per_run[str(int(vid))] = [
                _finite_or_none(rmse(table.err_pos[rows & (run == r.run)])) for r in result.runs
            ]
        seconds = sum(r.step_seconds[spec.name] for r in result.runs)
        steps = sum(r.n_steps[spec.name] for r in result.runs)
        assoc = [r.association[spec.name] for r in result.runs if spec.name in r.association]
        dropped = [r.discarded[spec.name] for r in result.runs if spec.name in r.discarded]
        heading = table.err_heading[vehicles]
        ospa_steps = [r.ospa[spec.name] for r in result.runs if spec.name in r.ospa]
        out["estimators"][spec.name] = {
            "params": spec.params.to_dict(),
            "vehicle_rmse": {str(k): v for k, v in
                             per_entity_rmse(table.id[vehicles], table.err_pos[vehicles]).items()},
            "vehicle_rmse_all": _finite_or_none(rmse(table.err_pos[vehicles])),
            "per_run_vehicle_rmse": per_run,
            "feature_rmse_all": _finite_or_none(rmse(table.err_pos[features])),
            "heading_rmse_all": _finite_or_none(rmse(heading)) if np.isfinite(heading).any()
            else None,
            "association_accuracy": (sum(c for c, _ in assoc) / sum(t for _, t in assoc))
            if assoc else None,
            "discarded_share": (sum(d for d, _ in dropped) / sum(t for _, t in dropped))
            if dropped and sum(t for _, t in dropped) else None,
            "steps_per_second": steps / seconds if seconds > 0 else None,
            # added for Zhang 2016 (DESIGN §6 allows new keys): eq. (20) and OSPA (m)
            "total_rmse": _finite_or_none(total_rmse(table.step[vehicles], table.err_pos[vehicles],
                                                     run[vehicles])),
            "ospa": _finite_or_none(float(np.mean(np.concatenate(ospa_steps))))
            if ospa_steps else None,
        }
    return out


def _toml_ready(value: Any) -> Any:
    """TOML has no null: drop None entries (absent key = default) recursively."""
    if isinstance(value, Mapping):
        return {k: _toml_ready(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_toml_ready(v) for v in value]
    return value


def errors_frame(result: ExperimentResult):  # -> pyarrow.Table
    """The long error table of every estimator (DESIGN §6 `errors.parquet` columns)."""
    import pyarrow as pa

    parts = []
    for spec in result.config.estimators:
        run, table = result.errors(spec.name)
        kind_names = np.array([KIND_NAMES[VEHICLE], KIND_NAMES[FEATURE]])
        parts.append(pa.table({
            "run": pa.array(run, pa.int64()),
            "step": pa.array(table.step, pa.int64()),
            "t": pa.array(table.t, pa.float64()),
            "estimator": pa.array([spec.name] * len(table), pa.string()),
            "kind": pa.array(kind_names[table.kind] if len(table) else [], pa.string()),
            "id": pa.array(table.id, pa.int64()),
            "err_pos": pa.array(table.err_pos, pa.float64()),
            "err_vel": pa.array(table.err_vel, pa.float64(), from_pandas=True),
            "err_heading": pa.array(table.err_heading, pa.float64(), from_pandas=True),
        }))
    return pa.concat_tables(parts)


def write_results(result: ExperimentResult, out: str | os.PathLike[str]) -> Path:
    """Write summary.json, errors.parquet, config.toml, figures and report.md to `out`."""
    import pyarrow.parquet as pq
    import tomli_w

    from cooploc import plots

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    summary = summarize(result)
    (folder / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    pq.write_table(errors_frame(result), folder / "errors.parquet")
    (folder / "config.toml").write_text(tomli_w.dumps(_toml_ready(result.config.to_dict())))
    figures = plots.run_figures(result, summary, folder)
    (folder / "report.md").write_text(plots.run_report(summary, figures))
    return folder

