"""`cooploc reproduce gulati`: Tables I–II and Figs. 3–6 of Gulati et al. (IV 2017).

- Table I: average RMSE of eq. 21 over the runs, for 2, 3 and 4 vehicles: new topology
  factor (`fg-topology-new`), old factor (`fg-topology-old`) and the Kalman filter of
  eq. 20 (`gnss-kf`, fusing GPS and odometry), plus `fg-isam2` (the incremental,
  filtered variant the paper names as needed for run time). Eq. 21 sums the squared
  errors over the N vehicles before the mean over steps, so it grows with √N; we
  report it as `total_rmse` (mean over runs of the per-run value, as the paper's
  "average final RMSE") and the per-vehicle RMSE beside it. The paper's absolute values
  depend on its unstated trajectories and its Kalman tuning, so the report compares
  the ratios to the Kalman filter (paper: 0.62–0.69 for the new factor).
- Table II: average execution time per run (time inside `step` and `smooth`).
- Figs. 3/5: trajectories of run 0 (2 and 4 vehicles): truth and each method.
- Figs. 4/6: the eq. 21 error of the whole system at each step (root of the mean over
  runs of the summed squared errors).

Runs: 1000 per vehicle count by default, as the paper (`--runs` to change).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any

import numpy as np

from cooploc import least_squares
from cooploc.experiment import ExperimentConfig, estimate, run_recording
from cooploc.metrics import VEHICLE, total_rmse_per_run_and_step
from cooploc.plots import format_number, line_panels, pyplot, save_figure, trajectory_panel
from cooploc.registry import get_preset, make_estimator
from cooploc.reproduce.base import PaperExperiment, ReproduceContext, replay

__all__ = ["EXPERIMENT", "PAPER_TABLE_I", "PAPER_TABLE_II"]

KALMAN = "gnss-kf"
#: the known-association bound of the gulati-* presets (the radar pose estimated, smoothed)
BOUND = "oracle-pose-smoother"
#: the graphs of the solver and information study: label → (factor kind, topology factors
#: in the graph, the new factor's σ_s with the odometry's share)
GRAPHS = {"no topology": ("old", False, False), "old": ("old", True, False), "new": ("new", True, False),
          "new, odometry noise in σ_s": ("new", True, True)}
STUDY_RUNS, STUDY_REPEATS = 100, 3
VEHICLE_COUNTS = (2, 3, 4)
#: Table I of the paper: average RMSE (eq. 21) for new factor, old factor, Kalman filter.
PAPER_TABLE_I = {2: (5.211, 7.187, 8.423), 3: (7.065, 7.076, 10.310), 4: (7.321, 8.184, 11.908)}
#: Table II of the paper: average execution time per run (s), same columns (C++, GTSAM 3.2.1).
PAPER_TABLE_II = {2: (0.153, 0.692, 0.010), 3: (0.181, 0.468, 0.010), 4: (0.273, 0.583, 0.017)}
PAPER_COLUMNS = ("fg-topology-new", "fg-topology-old", "gnss-kf")
#: figure numbers (trajectories, per-step RMSE) by vehicle count
FIGURES = {2: (3, 4), 4: (5, 6)}


def _figures(ctx: ReproduceContext, config: ExperimentConfig, row: dict[str, Any], n: int) -> None:
    """Figs. 3/5 (trajectories of run 0) and 4/6 (eq. 21 error per step) for n vehicles."""
    names = [e.name for e in config.estimators]
    shown = [x for x in names if x != "fg-isam2"] if n == 4 else \
        [x for x in ("fg-topology-old", "fg-topology-new", BOUND) if x in names]
    fig_tracks, fig_rmse = FIGURES[n]
    recording, estimates = replay(config, 0)
    fig, ax = pyplot().subplots(figsize=(6.5, 5.5))
    trajectory_panel(ax, recording.truth.vehicle_states[:, :, :2],
                     {x: np.array([e.vehicles.mean[:, :2] for e in estimates[x]]) for x in shown},
                     f"Gulati Fig. {fig_tracks}: ground truth and estimates, {n} vehicles (run 0)")
    ax.legend(fontsize=8)
    save_figure(fig, ctx.out / f"fig{fig_tracks}_trajectories_{n}v.png")
    per_step = {x: row[x]["total_rmse_per_step"] for x in shown}
    line_panels({"": {x: (list(range(len(curve))), curve) for x, curve in per_step.items()}},
                ctx.out / f"fig{fig_rmse}_rmse_per_step_{n}v.png",
                f"Gulati Fig. {fig_rmse}: system RMSE per step, {n} vehicles ({ctx.runs} runs)",
                "step", "system RMSE, eq. 21 [m]", markers=False, size=(6.5, 4.0))


def _study_run(config: ExperimentConfig, run: int, repeats: int) -> dict[str, dict[str, float]]:
    """One run's solver and information study (module docstring, "New vs old").

    For each graph of `GRAPHS` (same recording, same initial guess): the LM solve alone,
    warm (best of `repeats`), its iterations, the claimed posterior position variance
    (mean of tr P / 2 over variables) and the achieved one (mean squared error / 2), and
    the position NEES; the same figures of the bound's smoothed estimates.
    """
    from cooploc.estimators.factor_graph import FactorGraphParams, GraphData, GraphProblem
    from cooploc.estimators.factor_graph.estimates import PositionFilter
    from cooploc.least_squares import solve_lm

    recording = run_recording(config, run)
    truth = recording.truth
    true_positions = np.concatenate([  # in the graphs' order: step by step, ids sorted
        truth.vehicle_states[k, np.searchsorted(truth.vehicle_ids, np.sort(f.vehicles)), :2]
        for k, f in enumerate(recording.frames)])
    out: dict[str, dict[str, float]] = {}
    for label, (kind, topology, odometry_noise) in GRAPHS.items():
        data = GraphData(recording.setup, kind, FactorGraphParams().gap_variance, odometry_noise)
        start = PositionFilter()  # the batch estimators' own initial guess
        x0 = np.concatenate([start.step(data.add_frame(frame)).mean for frame in recording.frames])
        problem = GraphProblem.of(data)
        if not topology:
            problem = dataclasses.replace(problem, topology=())
        best, result = np.inf, None
        for _ in range(repeats):
            start = time.perf_counter()
            result = solve_lm(problem.linearize, x0)
            best = min(best, time.perf_counter() - start)
        assert result is not None and result.cov is not None
        out[label] = {"solve_seconds": best, "iterations": result.iterations,
                      **_information(result.x, result.cov, true_positions)}
    bound = make_estimator(BOUND, recording.setup, None, np.random.default_rng(0), truth)
    smoothed = estimate(bound, recording)
    x = np.concatenate([e.vehicles.mean[:, :2] for e in smoothed])
    cov = np.concatenate([e.vehicles.cov[:, :2, :2] for e in smoothed])
    out[BOUND] = _information(x, cov, true_positions)
    return out


def _information(x: np.ndarray, cov: np.ndarray, true: np.ndarray) -> dict[str, float]:
    """Claimed variance (mean tr P / 2), achieved variance (mean ‖e‖² / 2), mean NEES (χ²₂: 2)."""
    e = x - true
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])
    return {"claimed_variance": float(np.trace(cov, axis1=1, axis2=2).mean() / 2),
            "achieved_variance": float(np.mean(e**2)), "nees": float(nees.mean())}


def _study(ctx: ReproduceContext, config: ExperimentConfig, runs: int) -> dict[str, Any]:
    """`_study_run` over the first `runs` runs, in the worker processes; per graph the
    per-run values (lists) and the JIT time of the solver's compiled kernel in this process."""
    start = time.perf_counter()
    least_squares.compile_kernels()  # numba: compiled, or loaded from its cache, once per process
    jit = time.perf_counter() - start
    rows = ctx.map(functools.partial(_study_run, config, repeats=STUDY_REPEATS), list(range(runs)),
                   f"gulati solver study, {config.scenario}")
    study: dict[str, Any] = {"runs": runs, "repeats": STUDY_REPEATS,
                             "kernel_first_call_seconds_main_process": jit}
    for label in rows[0]:
        study[label] = {key: [r[label][key] for r in rows] for key in rows[0][label]}
    return study


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    names, runs = ctx.compared, ctx.runs
    overrides: dict[str, Any] = {"n_steps": 30} if ctx.quick else {}
    study_runs = min(runs, 2 if ctx.quick else STUDY_RUNS)
    table: dict[str, Any] = {}
    studies: dict[str, Any] = {}
    for n in VEHICLE_COUNTS:
        config = ctx.config(f"gulati-{n}v", scenario_overrides=overrides)
        result = ctx.run(config)
        row: dict[str, Any] = {}
        for name in names:
            run, errors = result.errors(name)
            vehicles = errors.kind == VEHICLE
            per_run, per_step = total_rmse_per_run_and_step(run[vehicles], errors.step[vehicles],
                                                            errors.err_pos[vehicles])
            counts = np.bincount(run[vehicles], minlength=per_run.size)
            per_run_sq = np.bincount(run[vehicles], errors.err_pos[vehicles]**2, minlength=per_run.size)
            per_run_nees = np.bincount(run[vehicles], errors.nees[vehicles], minlength=per_run.size) / counts
            seconds = [r.step_seconds[name] for r in result.runs]
            row[name] = {
                "total_rmse": float(per_run.mean()),
                "total_rmse_std_error": float(per_run.std(ddof=1) / np.sqrt(runs)) if runs > 1 else None,
                "per_run_total_rmse": per_run.tolist(),
                "vehicle_rmse_all": float(np.sqrt(np.mean(errors.err_pos[vehicles]**2))),
                "per_run_vehicle_rmse": np.sqrt(per_run_sq / counts).tolist(),
                "nees": float(np.mean(errors.nees[vehicles])),
                "per_run_nees": per_run_nees.tolist(),
                "total_rmse_per_step": per_step.tolist(),
                "seconds_per_run": float(np.mean(seconds)),
                "per_run_seconds": [float(x) for x in seconds],
            }
        for reference, key in ((KALMAN, "ratio_to_kalman"), (BOUND, "ratio_to_bound")):
            if reference in row:
                for name in names:
                    row[name][key] = row[name]["total_rmse"] / row[reference]["total_rmse"]
        table[str(n)] = row
        if n in FIGURES:
            _figures(ctx, config, row, n)
        if {"fg-topology-old", "fg-topology-new"} <= set(names):
            studies[str(n)] = _study(ctx, config, study_runs)
    params = get_preset("gulati-2v").params
    return {"scenario_overrides": overrides, "table": table, "study": studies,
            "noise": {"odometry_variance": params.odometry_variance, "radar_variance": params.radar_variance,
                      "gnss_variance": params.gnss_variance},
            "paper_table_i": {str(k): dict(zip(PAPER_COLUMNS, v, strict=True))
                              for k, v in PAPER_TABLE_I.items()},
            "paper_table_ii": {str(k): dict(zip(PAPER_COLUMNS, v, strict=True))
                               for k, v in PAPER_TABLE_II.items()}}


def report(data: dict[str, Any]) -> list[str]:
    names, table = data["compared"], data["table"]
    lines = [
        "# Gulati et al. 2017 — reproduction",
        "",
        f"{data['runs']} Monte Carlo runs per vehicle count, seed {data['seed']}; estimators: "
        + ", ".join(names) + ". `gnss-kf` is the Kalman filter of eq. 20 (CV model, GPS and "
        "odometry). Batch factor graphs are scored on their smoothed estimates, `fg-isam2` "
        "and the Kalman filter on their filtered ones.",
    ]
    if data["quick"]:
        lines += ["", "**Quick mode**: short trajectories and few runs — checks the pipeline, "
                  "the numbers are not the paper's setting."]
    lines += [
        "",
        "## Table I — average RMSE (eq. 21, summed over vehicles) [m]",
        "",
        "eq. 21 total RMSE (ours ± standard error | paper), its ratio to the Kalman filter "
        "(ours | paper), and our per-vehicle RMSE.",
        "",
        "| N | estimator | total RMSE ours | paper | ratio to Kalman ours | paper | per-vehicle RMSE |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, row in table.items():
        paper = data["paper_table_i"][n]
        for name in names:
            r = row[name]
            p = paper.get(name)
            p_ratio = None if p is None else p / paper[KALMAN]
            se = r["total_rmse_std_error"]
            lines.append(
                f"| {n} | {name} | {r['total_rmse']:.3f}" + (f" ± {se:.3f}" if se else "")
                + f" | {format_number(p, 4)} | {format_number(r.get('ratio_to_kalman'))} | "
                f"{format_number(p_ratio)} | {r['vehicle_rmse_all']:.3f} |")
    lines += [
        "",
        "## Table II — average execution time per run [s]",
        "",
        "Ours: Python, wall-clock time inside `step` (and `smooth`) per run, measured in the "
        "worker processes of this experiment — a shared or loaded machine inflates it; "
        "`benchmarks/factor_graph.py` measures CPU time and the LM solve alone. The paper: "
        "C++ with GTSAM 3.2.1 on an i7-4710MQ.",
        "",
        "| N | estimator | ours | paper |",
        "|---|---|---|---|",
    ]
    for n, row in table.items():
        paper = data["paper_table_ii"][n]
        for name in names:
            lines.append(f"| {n} | {name} | {row[name]['seconds_per_run']:.4f} | "
                         f"{format_number(paper.get(name), 3)} |")
    lines += [
        "",
        "## What differs from the paper, and why",
        "",
        "- Absolute values: the paper's Kalman filter has a per-vehicle RMSE near 6 m, above "
        "its GPS noise (3 m per axis, 4.2 m in 2-D), so its trajectories or tuning differ from "
        "anything its text states. Our trajectories are documented in "
        "`cooploc.scenarios.gulati`; compare the ratios.",
        "- New vs old factor: the paper finds the new factor better (27 % for 2 vehicles). "
        "With the residual derived in `cooploc.estimators.factor_graph` the old factor is the "
        "first-order likelihood of the radar topology given the current states, while the new "
        "one uses the odometry a second time and ignores its noise; it cannot carry more "
        "information, and in our runs it is slightly worse than the old one (see the table).",
        "- Run time: our batch LM is a banded sparse solver in NumPy (about 10 ms per solve "
        "of a 250-step graph); most of the time per run is the per-step bookkeeping of "
        "Python `Estimate`s (one per step, and one per step again after smoothing), which "
        "the Kalman filter pays too. `fg-isam2` is a filter here, not a smoother: its "
        "estimates do not use later data, so it lies between the Kalman filter and the "
        "batch graphs.",
    ]
    return lines


EXPERIMENT = PaperExperiment(
    name="gulati",
    title="Gulati et al. 2017, Tables I–II and Figs. 3–6",
    paper="004_1b86586d95b593ad.txt",
    compute=compute,
    report=report,
    compared=("fg-topology-new", "fg-topology-old", "gnss-kf", "fg-isam2", BOUND),
    runs=1000,
    figures=(("Fig. 3", "fig3_trajectories_2v.png"), ("Fig. 4", "fig4_rmse_per_step_2v.png"),
             ("Fig. 5", "fig5_trajectories_4v.png"), ("Fig. 6", "fig6_rmse_per_step_4v.png")),
)
