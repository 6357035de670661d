"""Every method on every scenario: the method × scenario table of `cooploc compare`.

`plan` decides, per scenario preset, which estimators run, exactly as `cooploc run`
does: each is constructed (`cooploc.registry.construct`) on the setup of the
scenario's run 0 (generated with run 0's seed); a refusal's message is the reason it
is listed as not run, never as a number. `run_compare` runs each scenario's runnable
estimators with `cooploc.results.run_to_folder` into ``OUT/<preset>/`` (so each is an
ordinary results folder, with the same seeding, backends and progress bar as `cooploc
run`: the numbers equal those of `cooploc run <preset> -e … --seed S`), then writes
at the top:

- ``compare.json`` (strict JSON) and ``compare.md``: one table per scenario — pooled
  vehicle RMSE (``vehicle_rmse_all``), its 90 % interval over runs, its ratio to
  ``gnss-kf``, to the scenario's bound (`Preset.bound`) and to the bound of the
  method's own sensors (the estimator's `bound`, `cooploc.registry`), association accuracy
  (per step as Brambilla 2020 measures it, and per track over the run:
  `cooploc.metrics`), steps per second, failed runs and the measurement kinds left
  unused;
- ``compare.png``: estimators × scenarios, colour and text the ratio to the bound,
  refused cells grey "n/a", cells of a scenario without a bound "—".

The 90 % interval is a percentile bootstrap of the pooled RMSE over runs: runs are
resampled with replacement (`BOOTSTRAP` times, seeded by the experiment's seed) and the
RMSE pooled over the resampled runs' vehicle rows (from ``errors.parquet``); its 5th
and 95th percentiles are the interval. With one run, or where a run diverged, there is
none (null).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.config import ExperimentConfig
from cooploc.errors import ConfigError
from cooploc.experiment import run_generators, run_recording
from cooploc.registry import construct, estimators, get_estimator, get_preset, presets
from cooploc.types import Recording

__all__ = ["BOOTSTRAP", "ScenarioPlan", "default_presets", "own_bounds_overview", "plan", "run_compare",
           "tables", "write_compare"]

BOOTSTRAP = 2000  # resamples of the 90 % interval
REFERENCE = "gnss-kf"  # the second ratio: how much cooperation gains over GNSS alone


def default_presets() -> list[str]:
    """The presets compared when none is named: every registered one but the SUMO cities
    (each needs SUMO and minutes per run; name them with ``-s``)."""
    return [name for name, p in presets().items() if p.family != "sumo"]


@dataclass(frozen=True)
class ScenarioPlan:
    """One scenario of a comparison: what runs (`config`, None if nothing can) and what
    is refused, with the reason."""

    preset: str
    config: ExperimentConfig | None
    refused: dict[str, str] = field(default_factory=dict)
    order: tuple[str, ...] = ()  # every estimator asked for, in the order asked

    @property
    def bound(self) -> str | None:
        return get_preset(self.preset).bound


def plan(scenarios: Sequence[str], names: Sequence[str], *,
         scenario_overrides: Mapping[str, Any] | None = None, runs: int = 10, seed: int = 0,
         backend: str = "processes", workers: int | None = None,
         scheduler: str | None = None) -> list[ScenarioPlan]:
    """Resolve the comparison before anything runs: unknown names, bad overrides and
    repeated entries are one `ConfigError` each. `names` empty: every registered
    estimator."""
    for name in [*scenarios, *names]:
        if list(scenarios).count(name) > 1 or list(names).count(name) > 1:
            raise ConfigError(f"{name!r} is listed twice")
    for name in names:
        get_estimator(name)
    names = list(names) or list(estimators())
    plans = []
    for scenario in scenarios:
        full = ExperimentConfig.build(scenario, names, scenario_overrides=scenario_overrides, runs=runs,
                                      seed=seed, backend=backend, workers=workers, scheduler=scheduler)
        refused = refusals(full)
        runnable = [n for n in names if n not in refused]
        plans.append(ScenarioPlan(scenario, full.with_overrides(runnable) if runnable else None,
                                  refused, tuple(names)))
    return plans


def refusals(config: ExperimentConfig, recording: Recording | None = None) -> dict[str, str]:
    """The estimators of `config` that `construct` refuses on the setup of its run 0 (or of
    `recording`, if given), each with the refusal's message."""
    recording = run_recording(config, 0) if recording is None else recording
    _, rngs = run_generators(config.seed, 0, [e.name for e in config.estimators])
    out = {}
    for spec in config.estimators:
        try:
            construct(get_estimator(spec.name), recording.setup, spec.params, rngs[spec.name],
                      recording.truth)
        except ConfigError as exc:
            out[spec.name] = str(exc)
    return out


def run_compare(plans: Sequence[ScenarioPlan], out: str | os.PathLike[str], *,
                progress: bool = False, resume: bool = False) -> Path:
    """Run every plan into ``out/<preset>/``, then write compare.json, compare.md, compare.png;
    `resume` keeps the runs each folder has already (`cooploc.results.run_to_folder`)."""
    from cooploc.results import run_to_folder

    folder = Path(out)
    for p in plans:
        if p.config is not None:
            run_to_folder(p.config, folder / p.preset, progress=progress, resume=resume)
    return write_compare(plans, folder)


# ----------------------------------------------------------------------------
# the tables
# ----------------------------------------------------------------------------


def _interval(folder: Path, name: str, seed: int) -> list[float] | None:
    """The 90 % percentile-bootstrap interval of the pooled vehicle RMSE over runs."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    table = pq.read_table(folder / "errors.parquet", columns=["run", "estimator", "kind", "err_pos"])
    table = table.filter(pc.and_(pc.equal(table["estimator"], name), pc.equal(table["kind"], "vehicle")))
    run = table["run"].to_numpy()
    err = table["err_pos"].to_numpy(zero_copy_only=False)
    ids = np.unique(run)
    if len(ids) < 2:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        sq = np.square(err)
    if not np.isfinite(sq).all():
        return None
    index = np.searchsorted(ids, run)
    sums, counts = np.bincount(index, sq, len(ids)), np.bincount(index, minlength=len(ids))
    draws = np.random.default_rng(seed).integers(0, len(ids), (BOOTSTRAP, len(ids)))
    pooled = np.sqrt(sums[draws].sum(axis=1) / counts[draws].sum(axis=1))
    return [float(v) for v in np.percentile(pooled, [5.0, 95.0])]


def _ratio(value: float | None, reference: float | None) -> float | None:
    if value is None or reference is None or reference <= 0:
        return None
    return value / reference


def _why_no_ratio(reference: str | None, rows: Mapping[str, Mapping[str, Any]], what: str) -> str | None:
    """Why the ratios to `reference` are missing for every row (None if they are not)."""
    if reference is None:
        return f"no {what} is declared for this scenario"
    row = rows.get(reference)
    if row is None:
        return f"{reference} was not among the estimators compared"
    if "refused" in row:
        return f"{reference} does not run here: {row['refused']}"
    if row["vehicle_rmse"] is None:
        return f"{reference} has no vehicle RMSE here (diverged or failed runs)"
    return None


def _kinds_beyond(rows: Mapping[str, Mapping[str, Any]], name: str, reference: str | None) -> list[str]:
    """The measurement kinds `name` uses that the estimator `reference` leaves aside."""
    if reference is None or reference == name or "unused_kinds" not in rows.get(reference, {}):
        return []
    return sorted(set(rows[reference]["unused_kinds"]) - set(rows[name]["unused_kinds"]))


def scenario_table(p: ScenarioPlan, folder: Path) -> dict[str, Any]:
    """One scenario's table (the JSON form; see the module docstring)."""
    summary = json.loads((folder / "summary.json").read_text()) if p.config is not None else None
    rows: dict[str, dict[str, Any]] = {}
    for name in p.order:
        if name in p.refused:
            rows[name] = {"refused": p.refused[name]}
            continue
        est = summary["estimators"][name]
        rows[name] = {
            "vehicle_rmse": est["vehicle_rmse_all"],
            "interval_90": None if est["vehicle_rmse_all"] is None
            else _interval(folder, name, summary["seed"]),
            "association_accuracy": est["association_accuracy"],
            "association_accuracy_per_step": est.get("association_accuracy_per_step"),
            "steps_per_second": est["steps_per_second"],
            "failed_runs": len(est["failed_runs"]),
            "unused_kinds": est["unused_kinds"],
        }
    notes = {"gnss_kf": _why_no_ratio(REFERENCE, rows, "GNSS reference"),
             "bound": _why_no_ratio(p.bound, rows, "bound")}
    for name, row in rows.items():
        if "refused" not in row:
            row["ratio_gnss_kf"] = None if notes["gnss_kf"] else _ratio(row["vehicle_rmse"],
                                                                          rows[REFERENCE]["vehicle_rmse"])
            row["ratio_bound"] = None if notes["bound"] else _ratio(row["vehicle_rmse"],
                                                                      rows[p.bound]["vehicle_rmse"])
            own = getattr(get_estimator(name), "bound", None)
            why = _why_no_ratio(own, rows, f"known-association bound for the sensors of {name}")
            row["own_bound"] = own
            row["ratio_own_bound"] = None if why else _ratio(row["vehicle_rmse"], rows[own]["vehicle_rmse"])
            if why:
                row["own_bound_note"] = why
            # a bound is one only for the sensors it reads: a method that also reads a kind
            # the bound leaves aside (e.g. radar) may legitimately beat it
            for key, ref in (("beyond_bound", p.bound), ("beyond_own_bound", own)):
                extra = _kinds_beyond(rows, name, ref)
                if extra:
                    row[key] = extra
    return {"scenario": p.preset, "bound": p.bound, "runs": None if summary is None else summary["runs"],
            "seed": None if summary is None else summary["seed"],
            "results": p.preset if summary is not None else None,
            "no_ratio": {k: v for k, v in notes.items() if v}, "estimators": rows}


def tables(plans: Sequence[ScenarioPlan], out: str | os.PathLike[str]) -> dict[str, Any]:
    """compare.json's content: the interval method and one table per scenario."""
    return {"interval_90": f"percentile bootstrap of the pooled vehicle RMSE over runs ({BOOTSTRAP} "
                           f"resamples; 5th and 95th percentiles)",
            "scenarios": [scenario_table(p, Path(out) / p.preset) for p in plans]}


def _num(value: float | None, digits: int = 2, unit: str = "") -> str:
    return "—" if value is None else f"{value:.{digits}f}{unit}"


def _grid(data: Mapping[str, Any], cell: Any, header: Sequence[str] = ()) -> list[str]:
    """An estimators × scenarios Markdown table: `cell(row)` for each estimator that ran,
    "n/a" where it was refused; `header` rows after the column line."""
    scenarios = data["scenarios"]
    names = list(dict.fromkeys(n for t in scenarios for n in t["estimators"]))
    lines = ["| estimator | " + " | ".join(t["scenario"] for t in scenarios) + " |",
             "| --- |" + " ---: |" * len(scenarios), *header]
    for name in names:
        rows = [t["estimators"].get(name) for t in scenarios]
        cells = ["" if row is None else "n/a" if "refused" in row else cell(row) for row in rows]
        lines.append(f"| `{name}` | " + " | ".join(cells) + " |")
    return lines


def overview(data: Mapping[str, Any]) -> list[str]:
    """The estimators × scenarios table at the top of compare.md: RMSE (ratio to the bound)."""
    def cell(row: Mapping[str, Any]) -> str:
        ratio = row["ratio_bound"]
        return _num(row["vehicle_rmse"], unit=" m") + ("" if ratio is None else f" ({ratio:.2f}×)")

    bounds = "| *bound* | " + " | ".join(t["bound"] or "none" for t in data["scenarios"]) + " |"
    return _grid(data, cell, [bounds])


def own_bounds_overview(data: Mapping[str, Any]) -> list[str]:
    """The estimators × scenarios table of each method's ratio to the bound of its own
    sensors (`registry`: an estimator's `bound`): RMSE (ratio × that bound)."""
    def cell(row: Mapping[str, Any]) -> str:
        ratio = row.get("ratio_own_bound")
        mark = "†" if row.get("beyond_own_bound") else ""
        shown = " (no bound)" if ratio is None else f" ({ratio:.2f}× {row['own_bound']}{mark})"
        return _num(row["vehicle_rmse"], unit=" m") + shown

    return _grid(data, cell)


def markdown(data: Mapping[str, Any]) -> str:
    """compare.md: the overview, then one Markdown table per scenario."""
    lines = ["# cooploc compare", "",
             "Vehicle RMSE pooled over vehicles, steps and runs (ratio to the scenario's bound); n/a: the "
             "estimator cannot run there (the reason is in the scenario's table).", "",
             *overview(data), "",
             "Each method against the known-association bound of its own sensors (an estimator's "
             "`bound`: `oracle-kf` for GNSS + V2F (+ odometry), `oracle-pose` for GNSS + radar, "
             "`oracle-pose-smoother` for the smoothed factor graphs, `kf-known-da` for GNSS alone): "
             "RMSE (ratio × that bound); \"no bound\" where cooploc has none or it did not run; "
             "† where the method also reads a kind that bound leaves aside (e.g. radar), so the "
             "bound is not one for it there (the scenario's table names the kind).", "",
             *own_bounds_overview(data), "",
             f"90 % interval: {data['interval_90']}. "
             "Ratios are RMSE / RMSE of gnss-kf, of the scenario's bound and of the bound of the "
             "method's own sensors; \"—\" where there is none (the reason follows the table).", ""]
    for t in data["scenarios"]:
        lines += [f"## {t['scenario']}", "",
                  f"{t['runs']} runs, seed {t['seed']}; bound: {t['bound'] or 'none'}; "
                  f"results in `{t['results']}/`" if t["results"] else "no estimator can run here", "",
                  "| estimator | vehicle RMSE [m] | 90 % interval [m] | / gnss-kf | / bound "
                  "| own bound | / own bound | association per step | per track | steps/s | notes |",
                  "| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | --- |"]
        for name, row in t["estimators"].items():
            if "refused" in row:
                lines.append(f"| `{name}` | not run | | | | | | | | | {row['refused']} |")
                continue
            interval = row["interval_90"]
            notes = [f"{row['failed_runs']} failed runs"] if row["failed_runs"] else []
            if row["unused_kinds"]:
                notes.append("not using " + ", ".join(row["unused_kinds"]))
            if "own_bound_note" in row and row["own_bound"] is not None:
                notes.append(f"no own-bound ratio: {row['own_bound_note']}")
            beyond = {ref: row[key] for key, ref in (("beyond_bound", t["bound"]),
                                                     ("beyond_own_bound", row["own_bound"])) if row.get(key)}
            notes += [f"uses {', '.join(kinds)}, which {ref} leaves aside: {ref} is not a bound for it here"
                      for ref, kinds in beyond.items()]
            lines.append(
                f"| `{name}` | {_num(row['vehicle_rmse'])} | "
                f"{'—' if interval is None else f'{interval[0]:.2f}–{interval[1]:.2f}'} | "
                f"{_num(row['ratio_gnss_kf'])} | {_num(row['ratio_bound'])} | "
                f"{row['own_bound'] or 'none'} | {_num(row['ratio_own_bound'])} | "
                f"{_num(row['association_accuracy_per_step'], 3)} | {_num(row['association_accuracy'], 3)} | "
                f"{_num(row['steps_per_second'], 0)} | "
                f"{'; '.join(notes)} |")
        lines.append("")
        for key, why in t["no_ratio"].items():
            lines += [f"No ratio to {'gnss-kf' if key == 'gnss_kf' else 'the bound'}: {why}.", ""]
    return "\n".join(lines)


def heat_map(data: Mapping[str, Any], path: Path) -> Path:
    """compare.png: estimators × scenarios, colour and text the ratio to the bound."""
    from matplotlib.colors import LogNorm
    from matplotlib.ticker import ScalarFormatter

    from cooploc.plots import pyplot

    plt = pyplot()
    scenarios = data["scenarios"]
    names = list(dict.fromkeys(n for t in scenarios for n in t["estimators"]))
    ratio = np.full((len(names), len(scenarios)), np.nan)
    fig, ax = plt.subplots(figsize=(1.3 * len(scenarios) + 2.5, 0.42 * len(names) + 1.8))
    for j, t in enumerate(scenarios):
        for i, name in enumerate(names):
            row = t["estimators"].get(name)
            if row is None or "refused" in row:
                ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, color="0.8"))
                text = "n/a" if row is not None else ""
            elif row["ratio_bound"] is None:
                text = "—"
            else:
                ratio[i, j] = row["ratio_bound"]
                text = f"{row['ratio_bound']:.2f}"
            dark = np.isfinite(ratio[i, j]) and ratio[i, j] > 2.5  # readable on the dark end
            ax.text(j, i, text, ha="center", va="center", fontsize=8, color="white" if dark else "black")
    shown = ratio[np.isfinite(ratio)]
    top = max(2.0, float(shown.max())) if shown.size else 2.0
    image = ax.imshow(np.ma.masked_invalid(ratio), cmap="YlOrRd", aspect="auto",
                      norm=LogNorm(vmin=min(1.0, float(shown.min())) if shown.size else 1.0, vmax=top))
    ax.set_xticks(range(len(scenarios)), [t["scenario"] for t in scenarios], rotation=35, ha="right")
    ax.set_yticks(range(len(names)), names)
    ax.set_xlim(-0.5, len(scenarios) - 0.5)
    ax.set_ylim(len(names) - 0.5, -0.5)
    bar = fig.colorbar(image, ax=ax, label="vehicle RMSE / bound's")
    bar.ax.yaxis.set_major_formatter(ScalarFormatter())
    bar.ax.yaxis.set_minor_formatter(ScalarFormatter())
    ax.set_title("vehicle RMSE / bound's (n/a: not run; —: no bound)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def write_compare(plans: Sequence[ScenarioPlan], out: str | os.PathLike[str]) -> Path:
    """Write compare.json (strict), compare.md and compare.png into `out` from the
    scenarios' results folders."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    data = tables(plans, folder)
    (folder / "compare.json").write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
    (folder / "compare.md").write_text(markdown(data))
    heat_map(data, folder / "compare.png")
    return folder
