"""`cooploc reproduce plbp`: Figs. 4–6 of "Cooperative Localization with Angular
Measurements and Posterior Linearization" (`papers/002_dfdb230c2e4252cd.txt`), on two
scenes (`SCENES`): `aoa-grid`, the dense intersection the paper's statements imply, and
`aoa-manhattan`, the few Manhattan blocks the model notes describe.

Per scene:

- Fig. 4: position and heading RMSE against the number of linearization iterations J,
  posterior (`plbp`, solid) and prior (`prior-lbp`, dotted) linearization, for
  L ∈ {1, 2, 3} BP iterations per linearization. One solve with J = `J_MAX` gives every
  J ≤ J_MAX: iteration j does not depend on how many follow (`info["iterate_means"]`).
- Fig. 5: CDFs of the position and heading error for J ∈ {1, 2, 3, 5} (L = 3), and
  prior linearization at J = 5.
- Fig. 6: RMSE (J = 5, L = 3) against R_c, σ²_θ, σ_p and σ_α, the others at Table I;
  the prior's position RMSE σ_p √2 is drawn dashed in the σ_p panel. σ_p starts at
  0.5 m instead of the paper's 0 (a zero prior variance has no information form).
- A reference: the centralized maximum a posteriori estimate of the same priors and AoA
  rows (`map_estimate`), on every snapshot of Figs. 4–5.
- Beyond the paper: the share of vehicles within 4 m and 0.15 rad against the arrays'
  field of view Δ (`FOV_SWEEP`), whose value was lost from the paper (the default is
  π/2; narrower arrays miss the vehicles ahead and behind).

Every number is over non-anchor vehicles (anchors are ids 0–5, `aoa.anchor_ids`) and
pooled over Monte Carlo snapshots (the paper does not state how many; default 100 for
Figs. 4–5, 40 per point for Fig. 6 and the field of view). The paper's statements are
claims with computed verdicts (`cooploc.reproduce.plbp_claims`, written to
claims.json); data.json keeps the per-snapshot values the paired comparisons use.
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
from cooploc.reproduce import plbp_claims
from cooploc.reproduce.base import PaperExperiment, ReproduceContext
from cooploc.reproduce.claims import claims_table
from cooploc.scenarios import get_preset
from cooploc.scenarios.aoa import AoaParams, anchor_ids
from cooploc.types import Recording

__all__ = ["BP_ITERATIONS", "CDF_ITERATIONS", "COMPARED_J", "EXPERIMENT", "FOV_SWEEP", "J_MAX", "SCENES",
           "SWEEPS", "iteration_study", "map_estimate", "within_target"]

ESTIMATORS = ("plbp", "prior-lbp")
#: the two scenes, each reported in full
SCENES = ("aoa-grid", "aoa-manhattan")
J_MAX = 10
#: J of the comparisons (plbp's default), with L = 3
COMPARED_J = 5
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
DEFAULT_RUNS, DEFAULT_SWEEP_RUNS = 100, 40
TARGET_POSITION, TARGET_HEADING = 4.0, 0.15


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


def _snapshot_errors(task: tuple[str, AoaParams, int, int]) -> dict[str, np.ndarray]:
    """Per-iteration errors (J_MAX + 1, n_non_anchor) of both estimators and every L, one run.

    Keys "{estimator}/L{l}/pos" and ".../heading"; "map/pos", "map/heading"
    (1, n_non_anchor), the MAP reference; "rows_per_vehicle" (1, n_non_anchor): AoA rows
    each non-anchor vehicle measured. Seeded exactly as `cooploc run` seeds run r
    (`experiment.run_generators`), so the snapshots are those of `cooploc run SCENE`.
    """
    from cooploc.estimators.plbp import PLBPParams, PriorLBPParams, iteration_errors

    scene, params, seed, run = task
    scenario_rng, estimator_rngs = run_generators(seed, run, ESTIMATORS)
    recording = get_preset(scene).generate(scenario_rng, params)
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
    x_map = map_estimate(recording)[keep]
    true_states = truth.vehicles_at(0, frame.vehicles[keep])
    out["map/pos"] = np.linalg.norm(x_map[:, :2] - true_states[:, :2], axis=1)[None]
    out["map/heading"] = np.abs(wrap_angle(x_map[:, 2] - true_states[:, 2]))[None]
    sensors = frame.batch("aoa", 1).sensor
    out["rows_per_vehicle"] = np.array([[np.sum(sensors == i) for i in frame.vehicles[keep]]], dtype=float)
    return out


def _per_snapshot(part: dict[str, np.ndarray]) -> dict[str, float]:
    """One snapshot's numbers for the paired comparisons (J = `COMPARED_J`, L = 3)."""
    J = COMPARED_J
    plbp_pos, plbp_head = part["plbp/L3/pos"], part["plbp/L3/heading"]
    return {
        "plbp/pos": rmse(plbp_pos[J]), "plbp/heading": rmse(plbp_head[J]),
        "prior-lbp/pos": rmse(part["prior-lbp/L3/pos"][J]),
        "prior-lbp/heading": rmse(part["prior-lbp/L3/heading"][J]),
        "map/pos": rmse(part["map/pos"][0]), "map/heading": rmse(part["map/heading"][0]),
        "plbp/within_J3": within_target(plbp_pos[3], plbp_head[3]),
        "plbp/within_J5": within_target(plbp_pos[J], plbp_head[J]),
    }


def iteration_study(scene: str, params: AoaParams, runs: int, ctx: ReproduceContext
                    ) -> tuple[dict[str, np.ndarray], dict[str, list[float]]]:
    """Errors (J_MAX + 1, runs × non-anchors) per "{estimator}/L{l}/{pos|heading}", the MAP
    reference ("map/..."), "rows_per_vehicle", pooled over the snapshots of `scene`; and
    the per-snapshot numbers of `_per_snapshot`, one list entry a snapshot."""
    parts = ctx.map(_snapshot_errors, [(scene, params, ctx.seed, r) for r in range(runs)],
                    f"{scene}: iterations")
    pooled = {key: np.concatenate([p[key] for p in parts], axis=1) for key in parts[0]}
    snapshots = [_per_snapshot(p) for p in parts]
    return pooled, {key: [s[key] for s in snapshots] for key in snapshots[0]}


# ----------------------------------------------------------------------------
# Fig. 6 and the field of view: sweeps of the scenario parameters
# ----------------------------------------------------------------------------


def _sweep_curves(ctx: ReproduceContext, base: ExperimentConfig, key: str, values: Sequence[float]
                  ) -> dict[str, dict[str, list[Any]]]:
    """curves[estimator]["pos" | "heading"] = non-anchor RMSE at each value,
    curves[estimator]["within"] = the share of non-anchor vehicles within the target, and
    ["within_per_run"] that share per run (a list per value)."""
    curves: dict[str, dict[str, list[Any]]] = {
        n: {"pos": [], "heading": [], "within": [], "within_per_run": []} for n in ESTIMATORS}
    for _, result in ctx.sweep(base, key, values):
        anchors = anchor_ids(result.config.scenario_params)  # type: ignore[arg-type]
        for name in ESTIMATORS:
            run, table = result.errors(name)
            rows = ~np.isin(table.id, anchors)
            pos, head = table.err_pos[rows], table.err_heading[rows]
            curves[name]["pos"].append(rmse(pos))
            curves[name]["heading"].append(rmse(head))
            curves[name]["within"].append(within_target(pos, head))
            curves[name]["within_per_run"].append(
                [within_target(pos[run[rows] == r], head[run[rows] == r]) for r in np.unique(run[rows])])
    return curves


# ----------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------


def _figure(n_panels: int, title: str) -> tuple[Any, np.ndarray]:
    """Two panels a row, 10 inches wide."""
    return figure_panels(n_panels, title, cols=2, size=(5.0, 4.0 if n_panels <= 2 else 3.75))


def _fig4(curves: dict[str, dict[str, list[float]]], path: Path, runs: int, scene: str) -> None:
    fig, axes = _figure(2, f"Fig. 4 on {scene}: RMSE vs linearization iterations J ({runs} snapshots)")
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


def _fig5(errors: dict[str, np.ndarray], path: Path, runs: int, scene: str) -> None:
    fig, axes = _figure(2, f"Fig. 5 on {scene}: CDF of the errors, L = 3 ({runs} snapshots)")
    for ax, kind, unit, target in ((axes[0], "pos", "position error [m]", TARGET_POSITION),
                                   (axes[1], "heading", "heading error [rad]", TARGET_HEADING)):
        for i, J in enumerate(CDF_ITERATIONS):
            cdf_step(ax, errors[f"plbp/L3/{kind}"][J], color=f"C{i}", label=f"posterior LF, J = {J}")
        cdf_step(ax, errors[f"prior-lbp/L3/{kind}"][COMPARED_J], color="0.4", linestyle=":",
                 label=f"prior LF, J = {COMPARED_J}")
        ax.axvline(target, color="red", lw=0.8, linestyle="--")
        ax.set_xlabel(unit)
        ax.set_ylabel("CDF")
        ax.set_xlim(0, 3 * target)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    save_figure(fig, path)


def _fov_figure(curves: dict[str, dict[str, list[Any]]], path: Path, runs: int, scene: str) -> None:
    fig, axes = _figure(
        2, f"Beyond the paper, {scene}: field of view Δ, J = 5, L = 3 ({runs} snapshots per point)")
    degrees = np.degrees(FOV_SWEEP)
    for name, style in (("plbp", "-o"), ("prior-lbp", ":s")):
        axes[0].plot(degrees, 100 * np.asarray(curves[name]["within"]), style, ms=3, label=name)
        axes[1].plot(degrees, curves[name]["heading"], style, ms=3, label=name)
    axes[0].axhline(100 * plbp_claims.NEARLY_ALL, color="red", lw=0.8, linestyle="--", label="nearly all")
    axes[0].set_ylabel(f"% within {TARGET_POSITION:g} m and {TARGET_HEADING:g} rad")
    axes[1].set_ylabel("heading RMSE [rad]")
    axes[1].set_ylim(bottom=0)
    for ax in axes:
        ax.set_xlabel("Δ, half-width of each array's field of view [deg]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    save_figure(fig, path)


def _fig6(sweeps: dict[str, dict[str, dict[str, list[Any]]]], path: Path, runs: int, scene: str) -> None:
    fig, axes = _figure(
        4, f"Fig. 6 on {scene}: RMSE vs scenario parameters, J = 5, L = 3 ({runs} snapshots per point)")
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


def figure_files(scene: str) -> dict[str, str]:
    """The figure files of one scene, by caption."""
    return {"Fig. 4": f"fig4_rmse_vs_iterations_{scene}.png", "Fig. 5": f"fig5_error_cdf_{scene}.png",
            "Fig. 6": f"fig6_rmse_vs_parameters_{scene}.png", "Field of view": f"field_of_view_{scene}.png"}


# ----------------------------------------------------------------------------
# the experiment
# ----------------------------------------------------------------------------


def _scene(ctx: ReproduceContext, scene: str, sweep_runs: int) -> dict[str, Any]:
    """Everything of one scene: Figs. 4–6, the MAP reference, the field of view."""
    runs, files = ctx.runs, figure_files(scene)
    params: AoaParams = get_preset(scene).params  # type: ignore[assignment]

    # Figs. 4–5: per-iteration errors, and the MAP reference on the same snapshots
    errors, snapshots = iteration_study(scene, params, runs, ctx)
    curves4: dict[str, dict[str, list[float]]] = {}
    for key, e in errors.items():
        if "/L" in key:
            prefix, kind = key.rsplit("/", 1)
            curves4.setdefault(prefix, {})[kind] = [rmse(row) for row in e]
    _fig4(curves4, ctx.out / files["Fig. 4"], runs, scene)
    _fig5(errors, ctx.out / files["Fig. 5"], runs, scene)
    within = {}
    for name, J in [("plbp", j) for j in CDF_ITERATIONS] + [("prior-lbp", COMPARED_J)]:
        pos, head = errors[f"{name}/L3/pos"][J], errors[f"{name}/L3/heading"][J]
        within[f"{name}/J{J}"] = {
            "both": within_target(pos, head),
            "position": float(np.mean(pos <= TARGET_POSITION)),
            "heading": float(np.mean(head <= TARGET_HEADING)),
        }
    map_pos, map_head = errors["map/pos"][0], errors["map/heading"][0]
    plbp_pos, plbp_head = errors["plbp/L3/pos"][COMPARED_J], errors["plbp/L3/heading"][COMPARED_J]
    rows = errors["rows_per_vehicle"][0]
    reference = {
        "map": {"pos_rmse": rmse(map_pos), "heading_rmse": rmse(map_head),
                "within_both": within_target(map_pos, map_head)},
        "plbp": {"pos_rmse": rmse(plbp_pos), "heading_rmse": rmse(plbp_head),
                 "within_both": within_target(plbp_pos, plbp_head)},
        "aoa_rows_per_vehicle": float(np.mean(rows)),
        "share_without_rows": float(np.mean(rows == 0)),
    }

    # Fig. 6 and the field of view (plbp and prior-lbp at their defaults J = 5, L = 3)
    base = ctx.config(scene, runs=sweep_runs)
    sweeps = {key: _sweep_curves(ctx, base, key, values) for key, (_, values) in SWEEPS.items()}
    _fig6(sweeps, ctx.out / files["Fig. 6"], sweep_runs, scene)
    fov = _sweep_curves(ctx, base, "field_of_view", FOV_SWEEP)
    _fov_figure(fov, ctx.out / files["Field of view"], sweep_runs, scene)

    return {
        "scenario_params": params.to_dict(),
        "fig4": curves4,
        "fig5_within_target": within,
        "per_snapshot": snapshots,
        "map_reference": reference,
        "fig6": {key: {"values": list(values), "curves": sweeps[key]}
                 for key, (_, values) in SWEEPS.items()},
        "field_of_view": {"values": list(FOV_SWEEP), "curves": fov},
    }


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    sweep_runs = ctx.runs_or(DEFAULT_SWEEP_RUNS, quick=1)
    return {"sweep_runs": sweep_runs, "j_max": J_MAX, "compared_j": COMPARED_J,
            "scenes": {scene: _scene(ctx, scene, sweep_runs) for scene in SCENES}}


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def _scene_report(scene: str, d: dict[str, Any]) -> list[str]:
    """The section of one scene: what it is, its claims, the reference and the field of view."""
    preset = get_preset(scene)
    ref, w5 = d["map_reference"], d["fig5_within_target"]
    found = plbp_claims.scene_claims(scene, d)
    lines = [
        f"## `{scene}`",
        "",
        f"{preset.summary} (field of view Δ = {np.degrees(d['scenario_params']['field_of_view']):.0f}°; "
        f"`cooploc.scenarios.{preset.generator.__module__.rsplit('.', 1)[-1]}`). A non-anchor vehicle "  # type: ignore[union-attr]
        f"measures {ref['aoa_rows_per_vehicle']:.1f} AoA rows on average; {_pct(ref['share_without_rows'])} "
        "measure none (no neighbour within R_c).",
        "",
        "### The paper's statements",
        "",
        *claims_table(found.paper),
        "",
        f"At J = {COMPARED_J}: within 4 m {_pct(w5['plbp/J5']['position'])}, within 0.15 rad "
        f"{_pct(w5['plbp/J5']['heading'])}, both {_pct(w5['plbp/J5']['both'])}; prior linearization "
        f"{_pct(w5['prior-lbp/J5']['both'])}.",
        "",
        "### The centralized optimum of the same data",
        "",
        *claims_table(found.reference),
        "",
        "The reference is the maximum a posteriori estimate of the whole network on every snapshot "
        "of Figs. 4–5 (`map_estimate`: centralized nonlinear least squares of the same priors and AoA "
        f"rows): position RMSE {format_number(ref['map']['pos_rmse'])} m, heading RMSE "
        f"{format_number(ref['map']['heading_rmse'])} rad, {_pct(ref['map']['within_both'])} within 4 m and "
        f"0.15 rad; `plbp` (J = {COMPARED_J}, L = 3): {format_number(ref['plbp']['pos_rmse'])} m, "
        f"{format_number(ref['plbp']['heading_rmse'])} rad, {_pct(ref['plbp']['within_both'])}. "
        + plbp_claims.reference_sentence(found, ref["aoa_rows_per_vehicle"], d["scenario_params"]),
        "",
        "### Beyond the paper: the field of view",
        "",
        "The half-width Δ of each array's field of view was lost from the paper; the default is "
        "π/2 (each array sees its half-plane). With Δ < 90° a vehicle is blind to the vehicles ahead "
        "of and behind it, which on a street are most of its neighbours.",
        "",
        *claims_table(found.field_of_view),
        "",
        plbp_claims.field_of_view_sentence(scene, found),
    ]
    return lines


def report(data: dict[str, Any]) -> list[str]:
    lines = [
        "# Cooperative localization with angular measurements and posterior linearization — reproduction",
        "",
        f"{data['runs']} snapshots per scene for Figs. 4–5 and {data['sweep_runs']} per point for Fig. 6 "
        f"and the field of view, seed {data['seed']}; every number is over non-anchor vehicles. "
        "Estimators: `plbp` (posterior linearization) and `prior-lbp` (linearized once at the priors), "
        f"L = 3 BP iterations per linearization and J = {COMPARED_J} unless stated. The paper's map is not "
        "available; two scenes stand for it: `aoa-grid`, one dense Manhattan intersection (what the "
        "paper's own statements imply), and `aoa-manhattan`, a few Manhattan blocks as the model notes "
        "describe the scene. Verdicts are computed from the numbers with the tolerances stated in each "
        "row (chosen from the paper's wording; `cooploc.reproduce.plbp_claims`), 90 % intervals over "
        "snapshots where a comparison is paired; all of them are in `claims.json`.",
    ]
    if data["quick"]:
        lines += ["", "**Quick mode**: a handful of snapshots — checks the pipeline; the numbers "
                  "are not converged Monte Carlo averages."]
    for scene, d in data["scenes"].items():
        lines += ["", *_scene_report(scene, d)]
    return lines


EXPERIMENT = PaperExperiment(
    name="plbp",
    title="AoA cooperative localization with posterior-linearization BP, Figs. 4–6, two scenes",
    paper="002_dfdb230c2e4252cd.txt",
    compute=compute,
    report=report,
    compared=ESTIMATORS,
    runs=DEFAULT_RUNS,
    figures=tuple((f"{caption}, {scene}", file) for scene in SCENES
                  for caption, file in figure_files(scene).items()),
    claims=plbp_claims.claims,
)
