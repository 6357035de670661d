"""`cooploc reproduce brambilla2020`: §V of Brambilla, Nicoli, Soatti & Deflorio (T-ITS 2020).

- Fig. 7: vehicle and feature position RMSE over time on the single road
  (`brambilla-road`) for feature spacings d_f = 0.5, 3 and 6 m, with the association
  of ICP-DA-LC (the paper measured 54 % and 92 % correct at 0.5 and 3 m).
- Fig. 8: vehicle position RMSE against the distance to the junction centre on the
  crossroad (`brambilla-crossroad`) for N_f = 3, 10, 20, 60 static features.
- Fig. 9: association errors and discarded V2F measurements of ICP-DA-LC against N_f.
- Fig. 10: as Fig. 8 for N_f = 20 features moving at v_f = 1, 2, 5 m/s.
- Fig. 11: correct associations and discarded measurements against v_f.
- `bounds_ratio.png`: every method's vehicle RMSE divided by `oracle-kf`'s, per setting.

Compared: `gnss-kf` (the non-cooperative tracking filter), `icp-da-lc` with η_TH = 0.5
and, as "icp-da-lc η=1", with η_TH = 1, `icp-da-pf` on the road; and two bounds that
know the association (dashed): `icp` (the paper's "ICP with known DA", the same
distributed Gaussian BP) and `oracle-kf` (the centralised joint Kalman filter, the
best any filter can do with these sensors). "icp-recursion" is `icp` with the paper's
recursion over steps (eqs. 11–12: `feedback` and `feature_memory` on), run on the road
and on the crossroad at N_f = 20 to show why the defaults leave it off. The paper
averages 5000 Monte Carlo runs; the default here is 50 per road point and 20 per
crossroad point (`--runs`).

Association is scored both ways (`cooploc.metrics`): per step, as the paper measures
it (a row is right when it was paired with the belief of its true feature), and per
track over the run. The claims use the per-step measure.

Distance to the junction: |p| signed positive while the vehicle approaches the centre
(p · v < 0) and negative after it passed; RMSE pooled over vehicles in 25 m bins.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from cooploc.experiment import ExperimentConfig, ExperimentResult, run_recording
from cooploc.metrics import FEATURE, VEHICLE, rmse
from cooploc.plots import format_number, line_panels
from cooploc.reproduce import brambilla2020_claims as paper_claims
from cooploc.reproduce.base import PaperExperiment, ReproduceContext, registered
from cooploc.reproduce.claims import claims_table
from cooploc.results import summarize

__all__ = ["EXPERIMENT", "FEATURE_COUNTS", "FEATURE_SPACINGS", "FEATURE_SPEEDS"]

FEATURE_SPACINGS = (0.5, 3.0, 6.0)
FEATURE_COUNTS = (3, 10, 20, 60)
FEATURE_SPEEDS = (1.0, 2.0, 5.0)
ROAD = ("gnss-kf", "icp-da-pf", "icp-da-lc", "icp", "oracle-kf")
CROSSROAD = ("gnss-kf", "icp-da-lc", "icp", "oracle-kf")
ETA_ONE = paper_claims.ETA_ONE
RECURSION = paper_claims.RECURSION
RECURSION_FEATURES = 20            # the crossroad setting where the recursion is also run
DEFAULT_RUNS_ROAD, DEFAULT_RUNS_CROSSROAD = 50, 20
DISTANCE_BINS = np.arange(-250.0, 251.0, 25.0)
BOUND = "oracle-kf"


def _over_time(result: ExperimentResult, kind: int) -> dict[str, tuple[list[float], list[float]]]:
    """RMSE over runs and entities of one kind at each time, per estimator."""
    out = {}
    for spec in result.config.estimators:
        table = result.errors(spec.name)[1]
        rows = table.kind == kind
        if not rows.any():
            continue
        t, inverse = np.unique(table.t[rows], return_inverse=True)
        sq = np.bincount(inverse, weights=table.err_pos[rows] ** 2, minlength=t.size)
        count = np.bincount(inverse, minlength=t.size)
        out[spec.name] = (t.tolist(), np.sqrt(sq / np.maximum(count, 1)).tolist())
    return out


def _geometry(config: ExperimentConfig) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], float]:
    """Per run: (steps × vehicles) signed distance to the centre and the vehicle ids; and
    the mean number of V2F rows (features sensed) per vehicle and step over the runs.

    The recordings are simulated again from the run's seed (cheap, and identical).
    """
    out, rows, vehicle_steps = {}, 0, 0
    for r in range(config.runs):
        recording = run_recording(config, r)
        truth = recording.truth
        p, v = truth.vehicle_states[..., :2], truth.vehicle_states[..., 2:4]
        sign = np.where(np.einsum("tni,tni->tn", p, v) < 0, 1.0, -1.0)
        out[r] = (sign * np.linalg.norm(p, axis=2), truth.vehicle_ids)
        rows += sum(int(o.get("v2f", np.zeros(0)).size) for o in truth.origin)
        vehicle_steps += int(truth.vehicle_present.sum())
    return out, rows / max(vehicle_steps, 1)


def _rmse_vs_distance(result: ExperimentResult, distances: dict[int, tuple[np.ndarray, np.ndarray]],
                      label_of: dict[str, str] | None = None) -> dict[str, tuple[list[float], list[float]]]:
    centres = 0.5 * (DISTANCE_BINS[1:] + DISTANCE_BINS[:-1])
    out = {}
    for spec in result.config.estimators:
        run, table = result.errors(spec.name)
        rows = table.kind == VEHICLE
        dist = np.array([distances[int(r)][0][int(k), int(np.searchsorted(distances[int(r)][1], i))]
                         for r, k, i in zip(run[rows], table.step[rows], table.id[rows], strict=True)])
        b = np.digitize(dist, DISTANCE_BINS) - 1
        ok = (b >= 0) & (b < centres.size)
        sq = np.bincount(b[ok], weights=table.err_pos[rows][ok] ** 2, minlength=centres.size)
        count = np.bincount(b[ok], minlength=centres.size)
        keep = count > 0
        label = (label_of or {}).get(spec.name, spec.name)
        out[label] = (centres[keep].tolist(), np.sqrt(sq[keep] / count[keep]).tolist())
    return out


def _per_run_rmse(result: ExperimentResult, name: str, kind: int) -> list[float | None]:
    """Position RMSE of each run (pooled over its entities of `kind`; None: no rows, or not finite)."""
    run, table = result.errors(name)
    out: list[float | None] = []
    for r in range(result.config.runs):
        value = rmse(table.err_pos[(run == r) & (table.kind == kind)])
        out.append(float(value) if np.isfinite(value) else None)
    return out


def _point(result: ExperimentResult, label_of: dict[str, str] | None = None) -> dict[str, Any]:
    """The numbers of one setting per estimator label: pooled and per-run RMSE (vehicles,
    features), mean 2-D position NEES, and the association (both measures, discarded share,
    per-run per-step shares)."""
    summary = summarize(result)["estimators"]
    out: dict[str, Any] = {"rmse": {}, "feature_rmse": {}, "nees": {}, "per_run": {}, "association": {}}
    for spec in result.config.estimators:
        label = (label_of or {}).get(spec.name, spec.name)
        est = summary[spec.name]
        out["rmse"][label] = est["vehicle_rmse_all"]
        out["feature_rmse"][label] = est["feature_rmse_all"]
        out["nees"][label] = est["nees_mean"]
        out["per_run"][label] = {"vehicle": _per_run_rmse(result, spec.name, VEHICLE),
                                 "feature": _per_run_rmse(result, spec.name, FEATURE)}
        if est["association_accuracy"] is not None:
            counts = [r.association_per_step.get(spec.name, (0, 0)) for r in result.runs]
            out["association"][label] = {
                "per_step": est["association_accuracy_per_step"], "track": est["association_accuracy"],
                "discarded": est["discarded_share"],
                "per_step_per_run": [c / t if t else None for c, t in counts]}
    return out


def _merge(point: dict[str, Any], other: dict[str, Any]) -> dict[str, Any]:
    return {key: {**value, **other.get(key, {})} if isinstance(value, dict) else value
            for key, value in point.items()}


def _only(config: ExperimentConfig, name: str, overrides: dict[str, Any]) -> ExperimentConfig | None:
    """The same runs with estimator `name` alone, its parameters overridden (None: not compared)."""
    specs = tuple(dataclasses.replace(s, params=s.params.with_overrides(overrides))
                  for s in config.estimators if s.name == name)
    return dataclasses.replace(config, estimators=specs) if specs else None


def _variants(ctx: ReproduceContext, config: ExperimentConfig, recursion: bool,
              distances: dict[int, tuple[np.ndarray, np.ndarray]] | None = None
              ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Points and distance curves of `icp-da-lc` at η_TH = 1 and (if `recursion`) of `icp`
    with the paper's recursion, on the runs of `config`."""
    point: dict[str, Any] = {}
    curves: dict[str, Any] = {}
    variants = [("icp-da-lc", {"threshold": 1.0}, ETA_ONE)]
    if recursion:
        variants.append(("icp", {"feedback": True, "feature_memory": True}, RECURSION))
    for name, overrides, label in variants:
        config_v = _only(config, name, overrides)
        if config_v is None:
            continue
        result = ctx.run(config_v)
        point = _merge(point, _point(result, {name: label})) if point else _point(result, {name: label})
        if distances is not None:
            curves.update(_rmse_vs_distance(result, distances, {name: label}))
    return point, curves


def _crossroad_point(ctx: ReproduceContext, base: ExperimentConfig, overrides: dict[str, Any],
                     recursion: bool) -> dict[str, Any]:
    """RMSE-vs-distance curves and the numbers of one crossroad setting, with its variants."""
    config = dataclasses.replace(base, scenario_params=base.scenario_params.with_overrides(overrides))
    distances, sensed = _geometry(config)
    result = ctx.run(config)
    point = _point(result)
    curves = _rmse_vs_distance(result, distances)
    variants, variant_curves = _variants(ctx, config, recursion, distances)
    curves.update(variant_curves)
    return {**_merge(point, variants), "curves": curves, "sensed_per_vehicle": sensed}


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    road_names, cross_names = ctx.compared, registered(CROSSROAD)
    runs_road, runs_cross = ctx.runs, ctx.runs_or(DEFAULT_RUNS_CROSSROAD, quick=1)

    # Fig. 7: road, RMSE over time per feature spacing
    fig7_v, fig7_f, road = {}, {}, {}
    for spacing in FEATURE_SPACINGS:
        config = ctx.config("brambilla-road", scenario_overrides={"feature_spacing": spacing})
        result = ctx.run(config)
        key = paper_claims.spacing_key(spacing)
        fig7_v[key] = _over_time(result, VEHICLE)
        fig7_f[key] = _over_time(result, FEATURE)
        variants, _ = _variants(ctx, config, recursion=True)
        road[key] = _merge(_point(result), variants)
    line_panels({f"vehicles, {k}": v for k, v in fig7_v.items()} | {f"features, {k}": v for k, v in
                                                                     fig7_f.items()},
                ctx.out / "fig7_road_rmse_over_time.png",
                f"Brambilla 2020 Fig. 7: position RMSE over time ({runs_road} runs)", "time [s]",
                "position RMSE [m]", markers=False)

    # Figs. 8–11: crossroad, static features for N_f, moving features for v_f
    cross_base = ctx.config("brambilla-crossroad", cross_names, runs=runs_cross)
    static = {str(n): _crossroad_point(ctx, cross_base, {"n_features": n, "feature_speed": 0.0},
                                       recursion=n == RECURSION_FEATURES) for n in FEATURE_COUNTS}
    moving = {f"{v:g}": _crossroad_point(ctx, cross_base, {"n_features": 20, "feature_speed": v},
                                         recursion=False) for v in FEATURE_SPEEDS}
    line_panels({f"N_f = {k}": p["curves"] for k, p in static.items()},
                ctx.out / "fig8_rmse_vs_distance_features.png",
                f"Brambilla 2020 Fig. 8: vehicle RMSE vs distance to the centre, static features "
                f"({runs_cross} runs)", "signed distance to the junction [m] (> 0 approaching)",
                "position RMSE [m]")
    line_panels({f"v_f = {k} m/s": p["curves"] for k, p in moving.items()},
                ctx.out / "fig10_rmse_vs_distance_speed.png",
                f"Brambilla 2020 Fig. 10: vehicle RMSE vs distance, N_f = 20 moving features "
                f"({runs_cross} runs)", "signed distance to the junction [m] (> 0 approaching)",
                "position RMSE [m]")
    line_panels(_association_panels(static), ctx.out / "fig9_association_vs_features.png",
                "Brambilla 2020 Fig. 9: association of ICP-DA-LC vs number of features",
                "number of features N_f", "share of V2F measurements [%]")
    line_panels(_association_panels(moving), ctx.out / "fig11_association_vs_speed.png",
                "Brambilla 2020 Fig. 11: association of ICP-DA-LC vs feature speed",
                "feature speed v_f [m/s]", "share of V2F measurements [%]")
    line_panels(_ratio_panels(road, static, moving), ctx.out / "bounds_ratio.png",
                f"Vehicle RMSE / {BOUND} (the known-association bound)", "setting",
                f"RMSE / {BOUND}")
    return {
        "runs_road": runs_road, "runs_crossroad": runs_cross,
        "road_estimators": road_names, "crossroad_estimators": cross_names,
        "fig7_vehicles": fig7_v, "fig7_features": fig7_f,
        "road": road, "crossroad_features": static, "crossroad_speed": moving,
    }


Panels = dict[str, dict[str, tuple[list[float], list[float]]]]


def _association_panels(points: dict[str, dict[str, Any]]) -> Panels:
    """Panels of the LC variants' association against the setting (in %): wrong pairings by
    the paper's per-step measure, by the per-track measure, and discarded rows."""
    panels: Panels = {
        "wrong pairings (per step, the paper's)": {}, "wrong (per track over the run)": {},
        "discarded measurements": {}}
    keys = list(points)
    for label in sorted({lab for p in points.values() for lab in p["association"]}):
        for panel, field, wrong in (("wrong pairings (per step, the paper's)", "per_step", True),
                                    ("wrong (per track over the run)", "track", True),
                                    ("discarded measurements", "discarded", False)):
            xs, ys = [], []
            for k in keys:
                value = points[k]["association"].get(label, {}).get(field)
                if value is not None:
                    xs.append(float(k))
                    ys.append(100 * (1 - value) if wrong else 100 * value)
            panels[panel][label] = (xs, ys)
    return panels


def _ratio_panels(road: dict[str, Any], static: dict[str, Any], moving: dict[str, Any]) -> Panels:
    """RMSE / oracle-kf against d_f, N_f and v_f, one curve per other estimator label."""
    panels = {}
    # every label in every panel, in one order, so that a label keeps its colour
    labels = list(dict.fromkeys(label for points in (road, static, moving) for point in points.values()
                                for label in point["rmse"] if label != BOUND))
    for title, points, parse in (("road: d_f [m]", road, paper_claims.spacing_of),
                                 ("crossroad, static: N_f", static, float),
                                 ("crossroad, N_f = 20: v_f [m/s]", moving, float)):
        curves: dict[str, tuple[list[float], list[float]]] = {label: ([], []) for label in labels}
        for key, point in points.items():
            bound = point["rmse"].get(BOUND)
            for label, value in point["rmse"].items():
                if label != BOUND and bound and value is not None:
                    xs, ys = curves[label]
                    xs.append(parse(key))
                    ys.append(value / bound)
        panels[title] = curves
    return panels


def _table(points: dict[str, dict[str, Any]], setting: str) -> list[str]:
    """One row per setting and estimator label: RMSE, its ratio to the bounds, NEES, association."""
    lines = [f"| {setting} | estimator | vehicle RMSE [m] | / {BOUND} | / icp | feature RMSE [m] | NEES | "
             "correct pairings per step | per track | discarded |", "|---" * 10 + "|"]
    for key, point in points.items():
        bound, icp = point["rmse"].get(BOUND), point["rmse"].get("icp")
        for label, value in point["rmse"].items():
            assoc = point["association"].get(label, {})
            cells = [key, label, format_number(value), _ratio(value, bound), _ratio(value, icp),
                     format_number(point["feature_rmse"].get(label)), format_number(point["nees"].get(label)),
                     _pct(assoc.get("per_step")), _pct(assoc.get("track")), _pct(assoc.get("discarded"))]
            lines.append("| " + " | ".join(cells) + " |")
    return lines


def _ratio(value: float | None, bound: float | None) -> str:
    return "–" if value is None or not bound else f"{value / bound:.3g}"


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.1f} %"


def report(data: dict[str, Any]) -> list[str]:
    lines = [
        "# Brambilla, Nicoli, Soatti & Deflorio 2020 — reproduction of §V",
        "",
        f"Road: {data['runs_road']} runs per spacing; crossroad: {data['runs_crossroad']} runs per "
        f"point; seed {data['seed']}. Road estimators: {', '.join(data['road_estimators'])}; crossroad: "
        f"{', '.join(data['crossroad_estimators'])}; and the variants `{ETA_ONE}` (η_TH = 1) and "
        f"`{RECURSION}` (`icp` with the paper's recursion, eqs. 11–12). `icp` and `{BOUND}` know the "
        "association: they are bounds (dashed), not methods. Ratios are to the vehicle RMSE of "
        f"`{BOUND}` (the centralised filter with the true association) and of `icp` (the paper's "
        "bound, ICP with known DA). Association: the share of V2F rows paired with the belief of "
        "their true feature at their step, as the paper measures it, and the share whose track "
        "stands for their feature over the whole run (`cooploc.metrics`); both count paired rows "
        "only. Verdicts are computed from the numbers (`claims.json`); each claim states its test "
        "and tolerance, chosen from the paper's wording.",
    ]
    if data["quick"]:
        lines += ["", "**Quick mode**: few runs — the orderings may show, the averages are not "
                  "converged and most intervals are wide."]
    lines += ["", "## Claims of the paper", "", *claims_table(paper_claims.claims(data)),
              "", "## Single road (§V-A, Fig. 7)", "", *_table(data["road"], "d_f"),
              "", "## Crossroad, static features (§V-B, Figs. 8–9)", "",
              *_table(data["crossroad_features"], "N_f"),
              "", "## Crossroad, N_f = 20 moving features (§V-B, Figs. 10–11)", "",
              *_table(data["crossroad_speed"], "v_f [m/s]"),
              "", "## The paper's recursion (eqs. 11–12) and why it is off by default", "",
              *paper_claims.recursion_lines(data),
              "", "Differences from the paper:",
              "- Every step's BPA-L starts from each vehicle's GNSS-only filter and a uniform feature "
              f"prior (`icp` docstring); `{RECURSION}` above is the paper's recursion.",
              "- The association (13) uses the same GNSS-only vehicle beliefs, not the paper's refined "
              "ones.",
              "- ICP-DA-PF uses J = 500 particles by default (paper: 5000) and a Silverman-widened pair "
              "kernel; without it the 0.2 m V2F noise leaves almost no particle pair inside the kernel.",
              "- Our DA estimators start their own feature tracks; the paper's hold one belief per "
              "known feature. The per-step measure matches tracks to true features at every step "
              "(`cooploc.metrics.paired_features`)."]
    return lines


EXPERIMENT = PaperExperiment(
    name="brambilla2020",
    title="Brambilla, Nicoli, Soatti & Deflorio 2020, §V (Figs. 7–11)",
    paper="003_dd51a52f1e371d91.txt",
    compute=compute,
    report=report,
    compared=ROAD,                  # the crossroad compares the registered ones of CROSSROAD
    runs=DEFAULT_RUNS_ROAD,
    figures=(("Fig. 7", "fig7_road_rmse_over_time.png"), ("Fig. 8", "fig8_rmse_vs_distance_features.png"),
             ("Fig. 9", "fig9_association_vs_features.png"), ("Fig. 10", "fig10_rmse_vs_distance_speed.png"),
             ("Fig. 11", "fig11_association_vs_speed.png"),
             ("Vehicle RMSE divided by oracle-kf's", "bounds_ratio.png")),
    claims=paper_claims.claims,
)
