"""`cooploc reproduce froehle2018`: Figs. 3–5 of Fröhle, Lindberg & Wymeersch (WCNC 2018).

- Fig. 3: CDF of the per-run vehicle RMSE on the §V-A scenario.
- Fig. 4: trajectory-average RMSE against the V2F variance σ²_V2F ∈ {0.1, 0.5, 1, 2, 3,
  5, 10} m².
- Fig. 5: trajectory-average RMSE against the number of features K ∈ {0, …, 6}.

Each figure shows every registered estimator of the comparison: the GNSS-only
Kalman filter (`gnss-kf`), the paper's method (`rsu-bp`, once registered) and the
known-association joint Kalman filter (`oracle-kf`, dashed) as the accuracy bound.
The paper does not state its number of Monte Carlo runs; we default to 20 per point.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from cooploc.plots import format_number, per_run_rmse_cdf, sweep_plot
from cooploc.reproduce.base import PaperExperiment, ReproduceContext
from cooploc.results import summarize
from cooploc.scenarios.froehle2018 import FroehleParams

__all__ = ["EXPERIMENT", "FEATURE_COUNTS", "V2F_VARIANCES", "analytic_gnss_rmse"]

V2F_VARIANCES = (0.1, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0)
FEATURE_COUNTS = (0, 1, 2, 3, 4, 5, 6)
PAPER_GNSS_RMSE_VEHICLE2 = 3.5  # m, §V-B
#: quick mode: 40 s of the scenario (the paper: 250 s) and N_p = 200 (paper: 600), 2 runs for
#: Fig. 3 and 1 per sweep point — the smallest sizes at which rsu-bp already beats GNSS on
#: vehicle 2 at every point, for several seeds (N_p = 60 did not; the first ≈ 10 s are a
#: transient that 41 steps could not outweigh)
QUICK_SCENARIO = {"n_steps": 81}
QUICK_RSU_BP = {"n_particles": 200}
QUICK_SWEEP_RUNS = 1
#: issue target: rsu-bp vehicle-2 RMSE within 25 % of the known-association bound
ORACLE_RATIO_TARGET = 1.25


def analytic_gnss_rmse(params: FroehleParams, vehicle: int) -> float:
    """Steady-state posterior position RMSE of the GNSS-only Kalman filter (DARE)."""
    from scipy.linalg import solve_discrete_are

    from cooploc.motion import ConstantVelocity

    model = ConstantVelocity(params.noise_density)
    F, Q = model.transition_matrix(params.dt), model.noise_covariance(params.dt)
    H = np.kron(np.array([[1.0, 0.0]]), np.eye(2))
    R = params.gnss_variance_of(vehicle) * np.eye(2)
    P_prior = solve_discrete_are(F.T, H.T, Q, R)                 # P⁻ of the steady state
    K = P_prior @ H.T @ np.linalg.inv(H @ P_prior @ H.T + R)
    P_post = (np.eye(4) - K @ H) @ P_prior
    return float(np.sqrt(np.trace(P_post[:2, :2])))


def _curves(sweep: list[tuple[Any, Any]]) -> dict[str, dict[str, list[float]]]:
    curves: dict[str, dict[str, list[float]]] = {}
    for _, result in sweep:
        for name, est in summarize(result)["estimators"].items():
            for vid, value in est["vehicle_rmse"].items():
                curves.setdefault(name, {}).setdefault(vid, []).append(value)
    return curves


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    overrides = QUICK_SCENARIO if ctx.quick else {}
    base = ctx.config("froehle2018", scenario_overrides=overrides,
                      estimator_overrides={"rsu-bp": QUICK_RSU_BP} if ctx.quick else {})
    sweep_runs = ctx.runs_or(ctx.runs, quick=QUICK_SWEEP_RUNS)
    sweep_base = dataclasses.replace(base, runs=sweep_runs)
    params: FroehleParams = base.scenario_params  # type: ignore[assignment]

    # Fig. 3: CDF of the per-run RMSE at the §V-A defaults
    summary3 = summarize(ctx.run(base))
    per_run = {n: e["per_run_vehicle_rmse"] for n, e in summary3["estimators"].items()}
    per_run_rmse_cdf(per_run, ctx.out / "fig3_rmse_cdf.png",
                     f"Fröhle 2018 Fig. 3: CDF of per-run vehicle RMSE ({ctx.runs} runs)")

    # Fig. 4: against the V2F variance
    curves4 = _curves(ctx.sweep(sweep_base, "v2f_variance", V2F_VARIANCES))
    sweep_plot(V2F_VARIANCES, curves4, ctx.out / "fig4_rmse_vs_v2f_variance.png",
               f"Fröhle 2018 Fig. 4: RMSE vs V2F variance ({sweep_runs} runs per point)",
               "V2F variance σ²_V2F [m²]", log_x=True)

    # Fig. 5: against the number of features
    curves5 = _curves(ctx.sweep(sweep_base, "n_features", FEATURE_COUNTS))
    sweep_plot(FEATURE_COUNTS, curves5, ctx.out / "fig5_rmse_vs_features.png",
               f"Fröhle 2018 Fig. 5: RMSE vs number of features ({sweep_runs} runs per point)",
               "number of features K")

    return {
        "sweep_runs": sweep_runs,
        "scenario_params": params.to_dict(),
        "fig3_per_run_vehicle_rmse": per_run,
        "fig3_vehicle_rmse": {n: e["vehicle_rmse"] for n, e in summary3["estimators"].items()},
        "fig3_steps_per_second": {n: e["steps_per_second"] for n, e in summary3["estimators"].items()},
        "fig3_association_accuracy": {n: e.get("association_accuracy")
                                      for n, e in summary3["estimators"].items()},
        "estimator_params": {spec.name: spec.params.to_dict() for spec in base.estimators},
        "fig4": {"v2f_variance": list(V2F_VARIANCES), "vehicle_rmse": curves4},
        "fig5": {"n_features": list(FEATURE_COUNTS), "vehicle_rmse": curves5},
        "analytic_gnss_rmse": {str(s): analytic_gnss_rmse(params, s)
                               for s in range(params.n_vehicles)},
    }


def report(data: dict[str, Any]) -> list[str]:
    fig3 = data["fig3_vehicle_rmse"]
    c4, c5 = data["fig4"]["vehicle_rmse"], data["fig5"]["vehicle_rmse"]
    oracle4 = c4.get("oracle-kf", {})
    oracle5 = c5.get("oracle-kf", {})
    gnss = fig3.get("gnss-kf", {})
    analytic = data["analytic_gnss_rmse"]
    method = "rsu-bp" if "rsu-bp" in data["compared"] else None

    def span(curve: list[float] | None) -> str:
        return "–" if not curve else f"{min(curve):.3g} – {max(curve):.3g} m"

    def ends(curve: list[float] | None) -> str:
        return "–" if not curve else f"{curve[0]:.3g} m → {curve[-1]:.3g} m"

    lines = [
        "# Fröhle, Lindberg & Wymeersch 2018 — reproduction",
        "",
        f"{data['runs']} Monte Carlo runs for Fig. 3 and {data.get('sweep_runs', data['runs'])} per point of "
        f"Figs. 4–5, seed {data['seed']}; estimators: "
        + ", ".join(data["compared"]) + ". Paper vehicle 1 / 2 = our vehicle 0 / 1. "
        "`oracle-kf` knows the true association: it is the accuracy bound (dashed), not a method.",
    ]
    if data["quick"]:
        lines += ["", f"**Quick mode**: {QUICK_SCENARIO['n_steps']} steps, few runs and (for `rsu-bp`) "
                  f"N_p = {QUICK_RSU_BP['n_particles']} particles — large enough that `rsu-bp` beats "
                  "GNSS on vehicle 2 as in the paper, but not converged averages."]
    if method is None:
        lines += ["", "The paper's method `rsu-bp` is not registered in this version; the "
                  "figures show the GNSS-only baseline and the bound."]
    lines += [
        "",
        "| statement of the paper | paper | ours |",
        "|---|---|---|",
        f"| GNSS-only Kalman filter RMSE, vehicle 2 (§V-B) | {PAPER_GNSS_RMSE_VEHICLE2} m | "
        f"{format_number(gnss.get('1'))} m simulated; {analytic.get('1', float('nan')):.2f} m analytic "
        "steady state (DARE) |",
        f"| GNSS-only Kalman filter RMSE, vehicle 1 | low (σ² = 0.01 m²) | "
        f"{format_number(gnss.get('0'))} m; {analytic.get('0', float('nan')):.2f} m analytic |",
        f"| Fig. 4: vehicle 1 RMSE almost constant in σ²_V2F | flat | bound: {span(oracle4.get('0'))}"
        " over σ²_V2F = 0.1 … 10 m² |",
        f"| Fig. 4: vehicle 2 RMSE grows with σ²_V2F, flattening beyond ≈ 3 m² | grows | bound: "
        f"{ends(oracle4.get('1'))} from 0.1 to 10 m² |",
        f"| Fig. 5: K = 0 is the GNSS-only filter | equal | bound at K = 0: "
        f"{format_number((oracle5.get('1') or [None])[0])} m vs gnss-kf "
        f"{format_number((c5.get('gnss-kf', {}).get('1') or [None])[0])} m (vehicle 2) |",
        f"| Fig. 5: vehicle 2 RMSE decreases with K | decreases | bound: {ends(oracle5.get('1'))}"
        " from K = 0 to 6 |",
        f"| Fig. 5: vehicle 1 RMSE almost constant in K | flat | bound: {span(oracle5.get('0'))} |",
        "",
        "The paper's 3.5 m for the GNSS-only filter does not follow from its stated parameters "
        "(r = 0.1, ΔT = 0.5 s, σ² = 15 m²): the steady-state Kalman filter gives 2.53 m, and our "
        "simulation agrees with that. The paper's figures give no other numbers in its text.",
    ]
    if method is not None:
        lines += ["", *_method_rows(data)]
    return lines


def _method_rows(data: dict[str, Any]) -> list[str]:
    """The paper's statements about its own method beside our `rsu-bp` numbers."""
    fig3 = data["fig3_vehicle_rmse"]
    c4, c5 = data["fig4"]["vehicle_rmse"], data["fig5"]["vehicle_rmse"]
    bp, gnss, oracle = fig3.get("rsu-bp", {}), fig3.get("gnss-kf", {}), fig3.get("oracle-kf", {})
    bp4, bp5 = c4.get("rsu-bp", {}), c5.get("rsu-bp", {})
    ratio = (bp.get("1") or float("nan")) / (oracle.get("1") or float("nan"))
    params = data.get("estimator_params", {}).get("rsu-bp", {})

    def curve(values: list[float] | None) -> str:
        return "–" if not values else ", ".join(f"{v:.2f}" for v in values)

    speed = data.get("fig3_steps_per_second", {}).get("rsu-bp")
    accuracy = data.get("fig3_association_accuracy", {}).get("rsu-bp")
    return [
        f"`rsu-bp` (N_p = {params.get('n_particles')}, P = {params.get('n_da_iterations')}, "
        f"I = {params.get('n_correction_iterations')}) against the paper's statements about it:",
        "",
        "| statement of the paper about its method | paper | ours (`rsu-bp`) |",
        "|---|---|---|",
        f"| Fig. 3: the method reduces vehicle 2's RMSE significantly vs GNSS-only | "
        f"significant | {format_number(bp.get('1'))} m vs {format_number(gnss.get('1'))} m "
        f"(bound {format_number(oracle.get('1'))} m) |",
        f"| Fig. 3: vehicle 1 keeps its low RMSE | low | {format_number(bp.get('0'))} m vs "
        f"{format_number(gnss.get('0'))} m GNSS-only |",
        f"| (issue target) vehicle-2 RMSE within 25 % of the known-association bound | ≤ "
        f"{ORACLE_RATIO_TARGET:.2f} × bound | {ratio:.2f} × bound "
        f"({'met' if ratio <= ORACLE_RATIO_TARGET else 'not met'}) |",
        f"| Fig. 4: vehicle 1 almost constant in σ²_V2F (slight increase from loopy BP) | flat | "
        f"{curve(bp4.get('0'))} m over σ²_V2F = 0.1 … 10 m² |",
        f"| Fig. 4: vehicle 2 grows with σ²_V2F, flattening beyond ≈ 3 m² | grows | "
        f"{curve(bp4.get('1'))} m |",
        f"| Fig. 5: K = 0 is the GNSS-only filter | equal | {format_number((bp5.get('1') or [None])[0])}"
        f" m at K = 0 (a particle filter on GNSS only) |",
        f"| Fig. 5: vehicle 2 decreases with K | decreases | {curve(bp5.get('1'))} m for K = 0 … 6 |",
        f"| Fig. 5: vehicle 1 almost constant in K | flat | {curve(bp5.get('0'))} m |",
        f"| speed (not in the paper) | – | {format_number(speed)} steps/s inside `step` |",
        f"| association accuracy (not in the paper) | – | {format_number(accuracy)} — share of V2F "
        "rows given to the estimated feature whose rows mostly come from the same true feature "
        "(`rsu-bp` names its features itself: they share one prior) |",
    ]


EXPERIMENT = PaperExperiment(
    name="froehle2018",
    title="Fröhle, Lindberg & Wymeersch 2018, Figs. 3–5",
    paper="000_a7dd486b38b8eaff.txt",
    compute=compute,
    report=report,
    compared=("gnss-kf", "rsu-bp", "oracle-kf"),
    runs=20,
    figures=(("Fig. 3", "fig3_rmse_cdf.png"), ("Fig. 4", "fig4_rmse_vs_v2f_variance.png"),
             ("Fig. 5", "fig5_rmse_vs_features.png")),
)
