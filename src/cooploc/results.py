"""What a Monte Carlo experiment leaves behind (DESIGN §6): summary, error table, folder.

- `summarize(result)`: the `summary.json` contract — per estimator, vehicle RMSE per id
  and pooled, per-run RMSE, feature and heading RMSE, association accuracy (per track
  over the run, and per step as Brambilla 2020 measures it: `cooploc.metrics`), the share
  of V2F rows left unused, steps per second, and Zhang 2016's total error (eq. 20) and
  OSPA; consistency (mean NEES, and NIS per degree of freedom of the filters that report
  ``Estimate.info["nis"]``); the failed and the diverged estimator-runs; whether every run
  finished.
- `errors_frame(result)`: the long `errors.parquet` table (one row per run × step ×
  estimator × entity).
- `write_results(result, out)`: summary.json, errors.parquet, config.toml, failures.log
  (if any estimator-run failed), the figures and report.md of `cooploc.plots` in one
  folder.
- `run_to_folder(config, out)`: runs the experiment writing each run to `out/runs/` as
  it finishes (`write_run`), then merges the runs into the files above (`merge_runs`);
  interrupted (Ctrl-C, an error), it still merges the finished runs, marked
  ``"complete": false``. A folder whose process was killed before merging is merged
  by `merge_runs(folder)`; `run_to_folder(config, out, resume=True)` goes on with the
  runs that are not in `out/runs/` yet (`finished_runs`), refusing a folder that holds
  another experiment.

Failures, divergence and strict JSON
------------------------------------
summary.json is strict JSON: every number is finite or null (non-finite parameter
values are written as the strings "inf", "-inf", "nan"). An estimator-run that ended
in an `EstimatorError` is listed in `failed_runs` and its metrics are computed over
the runs the estimator finished. A *diverged* estimator-run is one whose position
error is not finite (or whose square overflows) somewhere: it is listed in
`diverged_runs`, and every pooled figure that would include it (per id, per run, all
vehicles, features, heading, total error) is null rather than computed without it.
A NaN in `err_vel` / `err_heading` only means the layout has no such component, and
entities not estimated or not present have no rows at all; neither counts as
divergence.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cooploc._version import __version__
from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig, ExperimentResult, Failure, RunResult, iter_runs
from cooploc.metrics import FEATURE, KIND_NAMES, VEHICLE, ErrorTable, per_entity_rmse, rmse, total_rmse
from cooploc.plots import run_figures, run_report

__all__ = ["errors_frame", "finished_runs", "merge_runs", "read_runs", "run_to_folder", "summarize",
           "write_results", "write_run"]

RUNS_FOLDER = "runs"  # the per-run parts of `run_to_folder`, inside the results folder


def _finite_or_none(value: float) -> float | None:
    return None if value is None or not np.isfinite(value) else float(value)


def _diverged(err_pos: np.ndarray) -> np.ndarray:
    """Rows whose position error is not finite or overflows when squared (see the module
    docstring: position errors always apply, so a non-finite one is a diverged estimate)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return ~np.isfinite(np.square(err_pos))


def _pooled(errors: np.ndarray, diverged: np.ndarray) -> float | None:
    """RMSE of the rows, null if any of them diverged (never computed without them)."""
    return None if diverged.any() else _finite_or_none(rmse(errors))


def _groups(*keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows grouped by equal `keys` in one sort: (order, starts, ends), where group g is the
    rows ``order[starts[g]:ends[g]]``, groups sorted by the keys (the last key first) and
    rows in their original order within a group (a stable sort). Linear after the sort:
    what `summarize` computes per run never masks every row once per run."""
    order = np.lexsort(keys[::-1]) if keys[0].size else np.zeros(0, np.int64)
    if order.size == 0:
        return order, np.zeros(0, np.int64), np.zeros(0, np.int64)
    ordered = [k[order] for k in keys]
    new = np.zeros(order.size, dtype=bool)
    new[0] = True
    for k in ordered:
        new[1:] |= k[1:] != k[:-1]
    starts = np.flatnonzero(new)
    return order, starts, np.append(starts[1:], order.size)


def _per_run_rmse(run: np.ndarray, table: ErrorTable, diverged: np.ndarray, vehicles: np.ndarray,
                  runs: list[int]) -> dict[str, list[float | None]]:
    """Per vehicle id, the pooled RMSE of each of `runs` (null where the vehicle has no rows in
    a run, or diverged there). The rows of each (id, run) keep their table order and their
    squares are summed by the same pairwise reduction as `metrics.rmse`, so every number is,
    bit for bit, the one `_pooled` gives on that run's rows."""
    rows = np.flatnonzero(vehicles)
    ids, runs_of = table.id[rows], run[rows]
    order, starts, ends = _groups(ids, runs_of)
    with np.errstate(over="ignore"):  # diverged rows overflow; their groups are null anyway
        squares = np.square(table.err_pos[rows[order]])
    bad = np.logical_or.reduceat(diverged[rows[order]], starts) if starts.size else np.zeros(0, bool)
    position = {r: i for i, r in enumerate(runs)}
    out: dict[str, list[float | None]] = {}
    for g, (start, end) in enumerate(zip(starts, ends, strict=True)):
        per_run = out.setdefault(str(int(ids[order[start]])), [None] * len(runs))
        at = position.get(int(runs_of[order[start]]))
        if at is not None and not bad[g]:
            per_run[at] = _finite_or_none(float(np.sqrt(np.add.reduce(squares[start:end]) / (end - start))))
    return out


def _diverged_runs(run: np.ndarray, table: ErrorTable, diverged: np.ndarray) -> list[dict[str, Any]]:
    """Per diverged run: its first diverged step and the vehicle and feature ids that diverged."""
    rows = np.flatnonzero(diverged)
    order, starts, ends = _groups(run[rows])
    out = []
    for start, end in zip(starts, ends, strict=True):
        group = rows[order[start:end]]
        kind, ids = table.kind[group], table.id[group]
        out.append({"run": int(run[group[0]]), "step": int(table.step[group].min()),
                    "vehicles": sorted({int(i) for i in ids[kind == VEHICLE]}),
                    "features": sorted({int(i) for i in ids[kind == FEATURE]})})
    return out


def _nis_mean(totals: list[tuple[float, int]]) -> float | None:
    """Σ NIS / Σ dof over the runs' (Σ NIS, Σ dof) (1 for a consistent filter); null without dof."""
    dof = sum(d for _, d in totals)
    return _finite_or_none(sum(v for v, _ in totals) / dof) if dof else None


def _json_ready(value: Any) -> Any:
    """Non-finite floats (parameters such as an unlimited range) as strings: strict JSON."""
    if isinstance(value, Mapping):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    return value


@np.errstate(over="ignore")  # a diverged error overflows when squared: it is flagged, not warned about
def summarize(result: ExperimentResult) -> dict[str, Any]:
    """The `summary.json` contract of DESIGN §6 (plus the keys the module docstring and the
    README list: failures, divergence, completeness)."""
    config = result.config
    out: dict[str, Any] = {
        "cooploc_version": __version__,
        "scenario": config.scenario,
        "params": _json_ready(config.scenario_params.to_dict()),
        "runs": config.runs,
        "seed": config.seed,
        "complete": result.complete,
        "runs_finished": len(result.runs),
        "estimators": {},
    }
    if not result.complete:  # the per-run lists below follow these runs
        out["finished_runs"] = [r.run for r in result.runs]
    for spec in config.estimators:
        run, table = result.errors(spec.name)
        vehicles = table.kind == VEHICLE
        features = table.kind == FEATURE
        diverged = _diverged(table.err_pos)
        per_run = _per_run_rmse(run, table, diverged, vehicles, [r.run for r in result.runs])
        done = [r for r in result.runs if spec.name in r.errors]
        seconds = sum(r.step_seconds[spec.name] for r in done)
        steps = sum(r.n_steps[spec.name] for r in done)
        assoc = [r.association[spec.name] for r in result.runs if spec.name in r.association]
        assoc_step = [r.association_per_step[spec.name] for r in result.runs
                      if spec.name in r.association_per_step]
        dropped = [r.discarded[spec.name] for r in result.runs if spec.name in r.discarded]
        heading = table.err_heading[vehicles]
        ospa_steps = [r.ospa[spec.name] for r in result.runs if spec.name in r.ospa]
        out["estimators"][spec.name] = {
            "params": _json_ready(spec.params.to_dict()),
            "vehicle_rmse": {str(k): _finite_or_none(v) for k, v in
                             per_entity_rmse(table.id[vehicles], table.err_pos[vehicles]).items()},
            "vehicle_rmse_all": _pooled(table.err_pos[vehicles], diverged[vehicles]),
            "per_run_vehicle_rmse": per_run,
            "feature_rmse_all": _pooled(table.err_pos[features], diverged[features]),
            "heading_rmse_all": _pooled(heading, diverged[vehicles]) if np.isfinite(heading).any()
            else None,
            "association_accuracy": (sum(c for c, _ in assoc) / sum(t for _, t in assoc))
            if assoc else None,
            # added by issue 15: Brambilla 2020's per-step measure (metrics module docstring)
            "association_accuracy_per_step": (sum(c for c, _ in assoc_step) / sum(t for _, t in assoc_step))
            if assoc_step else None,
            "discarded_share": (sum(d for d, _ in dropped) / sum(t for _, t in dropped))
            if dropped and sum(t for _, t in dropped) else None,
            "steps_per_second": steps / seconds if seconds > 0 else None,
            # added for Zhang 2016 (DESIGN §6 allows new keys): eq. (20) and OSPA (m)
            "total_rmse": None if diverged[vehicles].any() else _finite_or_none(
                total_rmse(table.step[vehicles], table.err_pos[vehicles], run[vehicles])),
            "ospa": _finite_or_none(float(np.mean(np.concatenate(ospa_steps))))
            if ospa_steps else None,
            # added by issue 16: nothing silent (the module docstring says what they mean)
            "failed_runs": [{"run": f.run, "step": f.step, "error": f.what}
                            for r in result.runs if (f := r.failures.get(spec.name)) is not None],
            "diverged_runs": _diverged_runs(run, table, diverged),
            # consistency (metrics.nees_band) and what the estimator left aside (registry.unused_kinds)
            "nees_mean": _finite_or_none(float(np.nanmean(table.nees[vehicles])))
            if np.isfinite(table.nees[vehicles]).any() else None,
            "unused_kinds": sorted({k for r in result.runs for k in r.unused_kinds.get(spec.name, ())}),
            "nis_mean": _nis_mean([r.nis[spec.name] for r in result.runs if spec.name in r.nis]),
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
            "nees": pa.array(table.nees, pa.float64(), from_pandas=True),
        }))
    return pa.concat_tables(parts)


def write_results(result: ExperimentResult, out: str | os.PathLike[str], *,
                  stopped_by: str | None = None) -> Path:
    """Write summary.json, errors.parquet, config.toml, failures.log (if any estimator-run
    failed), figures and report.md to `out`; `stopped_by` (for an incomplete result) says
    what interrupted it. summary.json is written last: once it is there, so is the rest."""
    import pyarrow.parquet as pq

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    summary = summarize(result)
    if stopped_by is not None:
        summary["stopped_by"] = stopped_by
    text = json.dumps(summary, indent=2, allow_nan=False) + "\n"  # strict JSON, or an error here
    _atomic(folder / "errors.parquet", lambda path: pq.write_table(errors_frame(result), path))
    _write_config(result.config, folder)
    _write_failures_log(result.failures(), folder / FAILURES_LOG)
    if any(r.estimates for r in result.runs):  # the Python API path; run_to_folder writes run 0's
        from cooploc.view.estimates import write_estimates

        write_estimates({r.run: r.estimates for r in result.runs if r.estimates}, folder)
    figures = run_figures(result, summary, folder)
    (folder / "report.md").write_text(run_report(summary, figures))
    _atomic(folder / "summary.json", lambda path: path.write_text(text))
    return folder


FAILURES_LOG = "failures.log"


def _write_config(config: ExperimentConfig, folder: Path) -> None:
    import tomli_w

    (folder / "config.toml").write_text(tomli_w.dumps(_toml_ready(config.to_dict())))


def _write_failures_log(failures: list[Failure], path: Path) -> None:
    """One entry per failed estimator-run: its one-line message, then the traceback. No
    failures: no file (a stale one from an earlier experiment is removed)."""
    if not failures:
        path.unlink(missing_ok=True)
        return
    entries = [f"{f.message}\n\n{f.traceback.rstrip()}\n" for f in failures]
    path.write_text(("\n" + "-" * 78 + "\n\n").join(entries))


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    """`write(tmp)` then rename onto `path`: a reader never sees half a file."""
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


# ----------------------------------------------------------------------------
# run by run: parts in out/runs/, merged at the end
# ----------------------------------------------------------------------------


def run_to_folder(config: ExperimentConfig, out: str | os.PathLike[str], *,
                  progress: bool = False, resume: bool = False) -> Path:
    """Run the experiment, writing each run to `out/runs/` as it finishes, then merge.

    With `resume`, the runs already in `out/runs/` (an interrupted or killed experiment
    of the same configuration) are kept and not run again, and a folder whose merged
    summary says it is complete is left as it is; a folder of another experiment is a
    `ConfigError` naming what differs (`finished_runs`). Without `resume`, what an
    earlier experiment left in the folder is removed first.

    An experiment that surely does not fit in memory is refused first
    (`cooploc.budget.check_memory`); then config.toml is written. If the experiment is
    interrupted (KeyboardInterrupt) or a run raises, the runs finished so far are merged
    into summary.json (with
    ``"complete": false``, ``"runs_finished"``, ``"stopped_by"``), errors.parquet, the
    figures and report.md, and the exception is raised again. Once a complete
    experiment is merged, `out/runs/` is removed; an incomplete one keeps it. A
    configuration refused before any run finished (a `ConfigError`, e.g. an estimator
    that can use nothing the scenario offers) leaves nothing behind.
    """
    from cooploc.budget import check_memory

    check_memory(config)  # before anything is written: a refused experiment leaves no folder
    folder = Path(out)
    parts = folder / RUNS_FOLDER
    done = finished_runs(folder, config) if resume else frozenset()
    if resume and (folder / "config.toml").is_file() and _merged_complete(folder):
        return folder
    parts.mkdir(parents=True, exist_ok=True)
    # what an earlier experiment left here would be taken for this one's until the merge
    from cooploc.view.estimates import ESTIMATES_FILE

    stale = [folder / "summary.json"] if resume else [*parts.glob("run-*"), folder / "summary.json",
                                                      folder / ESTIMATES_FILE]
    for path in stale:
        path.unlink(missing_ok=True)
    _write_config(config, folder)
    finished = len(done)
    try:
        with contextlib.closing(iter_runs(config, progress, skip=done)) as runs:
            for run in runs:
                write_run(run, config, folder)
                finished += 1
    except ConfigError:
        if finished == 0:  # refused (e.g. an estimator that can use nothing): no results to keep
            (folder / "config.toml").unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                parts.rmdir()
            raise
        merge_runs(folder, config, stopped_by="ConfigError")
        raise
    except BaseException as exc:  # Ctrl-C or an error: keep what finished, then stop
        merge_runs(folder, config, stopped_by=type(exc).__name__)
        raise
    return merge_runs(folder, config)


def finished_runs(folder: str | os.PathLike[str], config: ExperimentConfig) -> frozenset[int]:
    """The runs of `config` already written to `folder/runs/` (for `resume`): a run counts
    once its JSON part is there (`write_run` writes it last). A folder without config.toml
    has none; one whose config.toml is another experiment is a `ConfigError` naming the
    first setting that differs."""
    folder = Path(folder)
    if not (folder / "config.toml").is_file():
        return frozenset()
    try:
        previous = ExperimentConfig.read(folder / "config.toml")
    except ConfigError as exc:
        raise ConfigError(f"--resume: {folder}/config.toml cannot be read ({exc}); give another --out") \
            from None
    if not previous.same_experiment(config):
        diff = previous.differences(config)
        what = (f"{diff[0][0]} is {diff[0][1]!r} there and {diff[0][2]!r} here" if diff
                else "the estimators are listed in another order")
        raise ConfigError(f"--resume: {folder} holds another experiment ({what}); resume it with "
                          f"`cooploc run --config {folder}/config.toml --resume`, or give another --out")
    runs = set()
    for path in (folder / RUNS_FOLDER).glob("run-*.json"):
        with contextlib.suppress(ValueError):
            if path.with_suffix(".parquet").is_file():
                runs.add(int(path.stem.removeprefix("run-")))
    return frozenset(r for r in runs if 0 <= r < config.runs)


def _merged_complete(folder: Path) -> bool:
    """Whether `folder` holds the merged summary of a complete experiment."""
    try:
        return json.loads((folder / "summary.json").read_text()).get("complete") is True
    except (OSError, ValueError, AttributeError):
        return False


def write_run(run: RunResult, config: ExperimentConfig, folder: str | os.PathLike[str]) -> None:
    """Write one finished run to `folder/runs/`: `run-NNNNNN.parquet` (its rows of the error
    table) and `run-NNNNNN.json` (what `summarize` needs besides: timing, association
    counts, OSPA per step, failures with tracebacks), each atomically, the JSON last (its
    presence marks the run as written)."""
    import pyarrow.parquet as pq

    parts = Path(folder) / RUNS_FOLDER
    parts.mkdir(parents=True, exist_ok=True)
    stem = f"run-{run.run:06d}"
    table = errors_frame(ExperimentResult(config, (run,)))
    _atomic(parts / f"{stem}.parquet", lambda path: pq.write_table(table, path))
    record = {
        "run": run.run,
        "step_seconds": run.step_seconds,
        "n_steps": run.n_steps,
        "association": run.association,
        "association_per_step": run.association_per_step,
        "discarded": run.discarded,
        "ospa": {name: values.tolist() for name, values in run.ospa.items()},
        "failures": {name: {"step": f.step, "what": f.what, "traceback": f.traceback}
                     for name, f in run.failures.items()},
        "unused_kinds": {name: list(kinds) for name, kinds in run.unused_kinds.items()},
        "nis": run.nis,
    }
    if run.estimates:  # run 0's estimates, for the viewer: straight to the folder
        from cooploc.view.estimates import write_estimates

        write_estimates({run.run: run.estimates}, folder)
    _atomic(parts / f"{stem}.json", lambda path: path.write_text(json.dumps(record)))


def read_runs(folder: str | os.PathLike[str]) -> list[RunResult]:
    """The runs written by `write_run` to `folder/runs/`, in run order."""
    import pyarrow.parquet as pq

    parts = Path(folder) / RUNS_FOLDER
    kinds = {name: kind for kind, name in KIND_NAMES.items()}
    runs = []
    for path in parts.glob("run-*.json"):
        record = json.loads(path.read_text())
        table = pq.read_table(path.with_suffix(".parquet"))
        columns = {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}
        columns["kind"] = np.array([kinds[k] for k in columns["kind"]], dtype=np.int64)
        of = columns["estimator"]
        errors = {name: ErrorTable(**{f: columns[f][of == name] for f in ErrorTable.__dataclass_fields__})
                  for name in record["n_steps"]}
        runs.append(RunResult(
            record["run"], errors, record["step_seconds"], record["n_steps"],
            association={k: tuple(v) for k, v in record["association"].items()},
            association_per_step={k: tuple(v) for k, v in record.get("association_per_step", {}).items()},
            discarded={k: tuple(v) for k, v in record["discarded"].items()},
            ospa={k: np.array(v, dtype=float) for k, v in record["ospa"].items()},
            failures={k: Failure(k, record["run"], f["step"], f["what"], f["traceback"])
                      for k, f in record["failures"].items()},
            unused_kinds={k: tuple(v) for k, v in record.get("unused_kinds", {}).items()},
            nis={k: (float(v[0]), int(v[1])) for k, v in record.get("nis", {}).items()},
        ))
    runs.sort(key=lambda r: r.run)
    return runs


def merge_runs(folder: str | os.PathLike[str], config: ExperimentConfig | None = None, *,
               stopped_by: str | None = None) -> Path:
    """Merge the runs in `folder/runs/` into the results files (`write_results`); remove
    the parts if every run of the configuration is there. `config` defaults to the
    folder's config.toml (e.g. to merge a folder whose process was killed)."""
    folder = Path(folder)
    if config is None:
        config = ExperimentConfig.read(folder / "config.toml")
    result = ExperimentResult(config, tuple(r for r in read_runs(folder) if 0 <= r.run < config.runs))
    write_results(result, folder, stopped_by=None if result.complete else stopped_by or "not finished")
    if result.complete:
        for part in (folder / RUNS_FOLDER).glob("run-*"):
            part.unlink()
        with contextlib.suppress(OSError):  # not empty: files that are not ours stay
            (folder / RUNS_FOLDER).rmdir()
    return folder
