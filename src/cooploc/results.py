"""What a Monte Carlo experiment leaves behind (DESIGN §6): summary, error table, folder.

- `summarize(result)`: the `summary.json` contract — per estimator, vehicle RMSE per id
  and pooled, per-run RMSE, feature and heading RMSE, association accuracy, the share
  of V2F rows left unused, steps per second, and Zhang 2016's total error (eq. 20) and
  OSPA.
- `errors_frame(result)`: the long `errors.parquet` table (one row per run × step ×
  estimator × entity).
- `write_results(result, out)`: summary.json, errors.parquet, config.toml, the figures
  and report.md of `cooploc.plots` in one folder.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from cooploc._version import __version__
from cooploc.experiment import ExperimentResult
from cooploc.metrics import FEATURE, KIND_NAMES, VEHICLE, per_entity_rmse, rmse, total_rmse
from cooploc.plots import run_figures, run_report

__all__ = ["errors_frame", "summarize", "write_results"]


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
            # consistency (metrics.nees_band) and what the estimator left aside (registry.unused_kinds)
            "nees_mean": _finite_or_none(float(np.nanmean(table.nees[vehicles])))
            if np.isfinite(table.nees[vehicles]).any() else None,
            "unused_kinds": sorted({k for r in result.runs for k in r.unused_kinds.get(spec.name, ())}),
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


def write_results(result: ExperimentResult, out: str | os.PathLike[str]) -> Path:
    """Write summary.json, errors.parquet, config.toml, figures and report.md to `out`."""
    import pyarrow.parquet as pq
    import tomli_w

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    summary = summarize(result)
    (folder / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    pq.write_table(errors_frame(result), folder / "errors.parquet")
    (folder / "config.toml").write_text(tomli_w.dumps(_toml_ready(result.config.to_dict())))
    figures = run_figures(result, summary, folder)
    (folder / "report.md").write_text(run_report(summary, figures))
    return folder

