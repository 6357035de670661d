"""Figures and Markdown reports of experiment results (matplotlib, Agg backend).

- `rmse_over_time`: RMSE over runs at each step, one panel per vehicle, one line per
  estimator.
- `per_run_rmse_cdf`: empirical CDF of the per-run vehicle RMSE (Fröhle Fig. 3).
- `sweep_plot`: trajectory-average RMSE against a swept parameter, one panel per
  vehicle (Fröhle Figs. 4–5); the known-association bound is drawn dashed.
- `line_panels`: any family of curves, one panel per key (paper figures of other shapes).
- Pieces of the paper figures: `figure_panels` (a grid of panels under one title),
  `cdf_step` (an empirical CDF on a panel), `trajectory_panel` (true and estimated
  paths), `save_figure`.
- `run_figures` / `run_report`: what `cooploc run` writes beside summary.json;
  `run_notes`: the failed and diverged estimator-runs and an unfinished experiment, one
  line each (in the report and on the terminal).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cooploc.metrics import VEHICLE, ecdf

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from cooploc.experiment import ExperimentResult

__all__ = [
    "cdf_step",
    "figure_panels",
    "format_number",
    "line_panels",
    "per_run_rmse_cdf",
    "pyplot",
    "rmse_over_time",
    "run_figures",
    "run_notes",
    "run_report",
    "save_figure",
    "shown_ids",
    "sweep_plot",
    "trajectory_panel",
]

MAX_PANELS = 6  # more vehicles than this: `shown_ids` picks them, the pooled RMSE is in the report
BOUND_ESTIMATORS = ("oracle-kf", "icp", "kf-known-da", "oracle-pose", "oracle-pose-smoother")


def shown_ids(ids: Sequence[Any]) -> list[Any]:
    """The vehicles given a panel or a table column: all of sorted `ids` up to `MAX_PANELS`,
    else `MAX_PANELS` of them evenly spaced from the first to the last — the first few alone
    may all be alike (aoa-grid's six anchors are ids 0–5)."""
    ids = list(ids)
    if len(ids) <= MAX_PANELS:
        return ids
    return [ids[i] for i in np.linspace(0, len(ids) - 1, MAX_PANELS).round().astype(int)]


def _style(name: str) -> dict[str, Any]:
    """Known-association bounds dashed, so that nobody mistakes them for a method."""
    return {"linestyle": "--", "color": "0.3"} if name in BOUND_ESTIMATORS else {}


def pyplot() -> Any:
    """`matplotlib.pyplot` with the Agg backend (files only: no display on servers and CI),
    imported on first use so that `import cooploc` and the command line stay fast."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_panels(n: int, title: str, cols: int = 3, size: tuple[float, float] = (4.2, 3.3)
                  ) -> tuple[Figure, np.ndarray]:
    """A figure of `n` panels (flat array of axes), at most `cols` a row, each `size` inches."""
    cols = min(n, cols)
    rows = int(np.ceil(n / cols))
    fig, axes = pyplot().subplots(rows, cols, figsize=(size[0] * cols, size[1] * rows), squeeze=False)
    fig.suptitle(title)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    return fig, axes.ravel()


def save_figure(fig: Figure, path: Path) -> Path:
    """Lay out, write (110 dpi) and close the figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)
    return path


def _save(fig: Figure, axes: np.ndarray, path: Path) -> Path:
    if axes[0].get_legend_handles_labels()[0]:  # nothing drawn (no run finished): no legend
        axes[0].legend(fontsize=8)
    return save_figure(fig, path)


def cdf_step(ax: Any, values: npt.ArrayLike, **style: Any) -> None:
    """The empirical CDF of `values` on the panel `ax`, as a step curve."""
    x, p = ecdf(values)
    ax.step(x, p, where="post", **style)


def trajectory_panel(ax: Any, truth: npt.ArrayLike, estimates: Mapping[str, Any], title: str = "",
                     markers: Mapping[str, str] | None = None) -> None:
    """True paths (T, N, 2) as black lines and each estimator's positions, in metres.

    `estimates[name]` is (T, N, 2), one line per vehicle; with `markers` (name → marker)
    it is a sequence of (n_k, 2) position sets drawn as points, for set-valued
    estimates whose slots are not identities.
    """
    truth = np.asarray(truth)
    for i in range(truth.shape[1]):
        ax.plot(truth[:, i, 0], truth[:, i, 1], "k-", lw=1.4, label="truth" if i == 0 else None)
    for k, (name, positions) in enumerate(estimates.items()):
        if markers is not None:
            points = np.concatenate([np.asarray(p).reshape(-1, 2) for p in positions])
            ax.plot(points[:, 0], points[:, 1], markers.get(name, "."), ms=2.5, alpha=0.6,
                    label=name, mfc="none")
            continue
        paths = np.asarray(positions)
        for i in range(paths.shape[1]):
            ax.plot(paths[:, i, 0], paths[:, i, 1], color=f"C{k}", lw=0.8, alpha=0.85,
                    label=name if i == 0 else None)
    ax.set_title(title)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)


def rmse_over_time(result: ExperimentResult, path: Path) -> Path:
    """RMSE (over runs) of each vehicle at each time, per estimator."""
    names = [e.name for e in result.config.estimators]
    tables = {name: result.errors(name)[1] for name in names}
    ids = np.unique(np.concatenate([t.id[t.kind == VEHICLE] for t in tables.values()]))
    ids = np.array(shown_ids(ids))
    fig, axes = figure_panels(max(ids.size, 1), f"{result.config.scenario}: position RMSE over time "
                        f"({result.config.runs} runs)")
    for ax, vid in zip(axes, ids, strict=False):
        for name, table in tables.items():
            rows = (table.kind == VEHICLE) & (table.id == vid)
            t, inverse = np.unique(table.t[rows], return_inverse=True)
            sq = np.bincount(inverse, weights=table.err_pos[rows] ** 2, minlength=t.size)
            count = np.bincount(inverse, minlength=t.size)
            ax.plot(t, np.sqrt(sq / np.maximum(count, 1)), label=name, lw=1, **_style(name))
        ax.set_title(f"vehicle {vid}")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position RMSE [m]")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    return _save(fig, axes, path)


def per_run_rmse_cdf(per_run: Mapping[str, Mapping[str, Sequence[float | None]]], path: Path,
                     title: str) -> Path:
    """CDF of per-run RMSE: `per_run[estimator][vehicle id]` = RMSE of each run."""
    ids = shown_ids(sorted({vid for by_id in per_run.values() for vid in by_id}, key=int))
    fig, axes = figure_panels(max(len(ids), 1), title)
    for ax, vid in zip(axes, ids, strict=False):
        for name, by_id in per_run.items():
            values = [v for v in by_id.get(vid, []) if v is not None]
            if values:
                cdf_step(ax, values, label=name, **_style(name))
        ax.set_title(f"vehicle {vid}")
        ax.set_xlabel("per-run position RMSE [m]")
        ax.set_ylabel("CDF")
        ax.grid(alpha=0.3)
    return _save(fig, axes, path)


def sweep_plot(x: Sequence[float], curves: Mapping[str, Mapping[str, Sequence[float]]],
               path: Path, title: str, xlabel: str, log_x: bool = False) -> Path:
    """`curves[estimator][vehicle id]` = RMSE at each x."""
    ids = shown_ids(sorted({vid for c in curves.values() for vid in c}, key=int))
    fig, axes = figure_panels(max(len(ids), 1), title)
    for ax, vid in zip(axes, ids, strict=False):
        for name, by_id in curves.items():
            if vid in by_id:
                ax.plot(x, by_id[vid], marker="o", ms=4, label=name, **_style(name))
        ax.set_title(f"vehicle {vid}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("trajectory-average RMSE [m]")
        if log_x:
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    return _save(fig, axes, path)


def line_panels(panels: Mapping[str, Mapping[str, tuple[Sequence[float], Sequence[float]]]], path: Path,
                title: str, xlabel: str, ylabel: str, markers: bool = True,
                size: tuple[float, float] = (4.2, 3.3)) -> Path:
    """`panels[panel title][curve label]` = (x, y); known-association bounds dashed; `size`
    of a panel in inches."""
    fig, axes = figure_panels(max(len(panels), 1), title, size=size)
    for ax, (name, curves) in zip(axes, panels.items(), strict=False):
        for label, (x, y) in curves.items():
            style = _style(label.split(" ")[0])
            ax.plot(x, y, marker="o" if markers else None, ms=3, lw=1, label=label, **style)
        ax.set_title(name)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    return _save(fig, axes, path)


def run_figures(result: ExperimentResult, summary: Mapping[str, Any], folder: Path
                ) -> list[tuple[str, str]]:
    """The figures of `cooploc run`: [(caption, file name)]."""
    figures = [("Position RMSE over time per vehicle", "rmse_over_time.png"),
               ("CDF of per-run vehicle RMSE", "rmse_cdf.png")]
    rmse_over_time(result, folder / figures[0][1])
    per_run = {name: est["per_run_vehicle_rmse"] for name, est in summary["estimators"].items()}
    per_run_rmse_cdf(per_run, folder / figures[1][1],
                     f"{summary['scenario']}: per-run vehicle RMSE ({summary['runs']} runs)")
    return figures


def format_number(value: float | None, digits: int = 3) -> str:
    """`digits` significant digits, or an en dash where there is no value."""
    return "–" if value is None else f"{value:.{digits}g}"


def run_notes(summary: Mapping[str, Any]) -> list[str]:
    """What did not go as planned, one line each: an unfinished experiment, every failed
    estimator-run (with what failed) and every diverged one."""
    notes = []
    if summary.get("complete") is False:
        notes.append(f"incomplete: {summary['runs_finished']} of {summary['runs']} runs finished"
                     + (f" (stopped by {summary['stopped_by']})" if summary.get("stopped_by") else ""))
    for name, e in summary["estimators"].items():
        for f in e.get("failed_runs", []):
            at = f" at step {f['step']}" if f["step"] is not None else ""
            notes.append(f"{name} failed in run {f['run']}{at}: {f['error']}")
        for d in e.get("diverged_runs", []):
            notes.append(f"{name} diverged in run {d['run']} from step {d['step']} (non-finite error)")
    return notes


def run_report(summary: Mapping[str, Any], figures: Sequence[tuple[str, str]]) -> str:
    """Short Markdown report of a `cooploc run` results folder."""
    est = summary["estimators"]
    ids = sorted({vid for e in est.values() for vid in e["vehicle_rmse"]}, key=int)
    shown = shown_ids(ids)
    notes = run_notes(summary)
    lines = [
        f"# {summary['scenario']}: {summary['runs']} runs, seed {summary['seed']}",
        "",
        *(["**Not everything ran** (details in `summary.json`, tracebacks in `failures.log`); the "
           "figures are over the estimator-runs that finished; a diverged one leaves its pooled "
           "RMSE blank:", "",
           *(f"- {n}" for n in notes), ""] if notes else []),
        f"cooploc {summary['cooploc_version']}. RMSE = sqrt(mean squared 2-D position error)"
        " over steps and runs. Estimators marked † know the true association "
        "(accuracy bound, not a method).",
        "",
        "| estimator | " + " | ".join(f"vehicle {v} [m]" for v in shown)
        + " | all vehicles [m] | features [m] | steps/s |",
        "|---" * (len(shown) + 4) + "|",
    ]
    for name, e in est.items():
        mark = " †" if name in BOUND_ESTIMATORS else ""
        cells = [format_number(e["vehicle_rmse"].get(v)) for v in shown]
        lines.append(f"| {name}{mark} | " + " | ".join(cells)
                     + f" | {format_number(e['vehicle_rmse_all'])} | {format_number(e['feature_rmse_all'])}"
                     f" | {format_number(e['steps_per_second'], 4)} |")
    lines.append("")
    lines += [f"{name} did not use this scenario's {', '.join(e['unused_kinds'])} measurements.\n"
              for name, e in est.items() if e.get("unused_kinds")]
    if any(e.get("total_rmse") is not None for e in est.values()):  # Zhang 2016 eq. (20), OSPA
        lines += ["| estimator | total error, eq. (20) [m] | OSPA (c = 10 m, p = 2) [m] |", "|---|---|---|"]
        lines += [f"| {name} | {format_number(e.get('total_rmse'))} | {format_number(e.get('ospa'))} |"
                  for name, e in est.items()]
        lines.append("")
    for caption, name in figures:
        lines += [f"![{caption}]({name})", ""]
    lines.append("Data: `summary.json`, `errors.parquet`; configuration: `config.toml`.")
    return "\n".join(lines) + "\n"
