"""`cooploc reproduce brambilla2020`: §V of Brambilla, Nicoli, Soatti & Deflorio (T-ITS 2020).

- Fig. 7: vehicle and feature position RMSE over time on the single road
  (`brambilla-road`) for feature spacings d_f = 0.5, 3 and 6 m, with the association
  accuracy of ICP-DA-LC (the paper measured 54 % and 92 % at 0.5 and 3 m).
- Fig. 8: vehicle position RMSE against the distance to the junction centre on the
  crossroad (`brambilla-crossroad`) for N_f = 3, 10, 20, 60 static features.
- Fig. 9: association errors and discarded V2F measurements of ICP-DA-LC against N_f.
- Fig. 10: as Fig. 8 for N_f = 20 features moving at v_f = 1, 2, 5 m/s.
- Fig. 11: correct associations and discarded measurements against v_f.

Compared: `gnss-kf` (the non-cooperative tracking filter), `icp` (known association,
the paper's bound, dashed), `icp-da-lc` with η_TH = 0.5 and, as "icp-da-lc η=1", with
η_TH = 1, `icp-da-pf` on the road, and `oracle-kf` (the centralised joint Kalman filter
with known association) on the road. The paper averages 5000 Monte Carlo runs; the
default here is 50 per road point and 20 per crossroad point (`--runs`).

Distance to the junction: |p| signed positive while the vehicle approaches the centre
(p · v < 0) and negative after it passed; RMSE pooled over vehicles in 25 m bins.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from cooploc.experiment import ExperimentConfig, ExperimentResult, run_recording
from cooploc.metrics import FEATURE, VEHICLE
from cooploc.plots import format_number, line_panels
from cooploc.reproduce.base import PaperExperiment, ReproduceContext, registered
from cooploc.results import summarize

__all__ = ["EXPERIMENT", "FEATURE_COUNTS", "FEATURE_SPACINGS", "FEATURE_SPEEDS"]

FEATURE_SPACINGS = (0.5, 3.0, 6.0)
FEATURE_COUNTS = (3, 10, 20, 60)
FEATURE_SPEEDS = (1.0, 2.0, 5.0)
ROAD = ("gnss-kf", "icp-da-pf", "icp-da-lc", "icp", "oracle-kf")
CROSSROAD = ("gnss-kf", "icp-da-lc", "icp")
ETA_ONE = "icp-da-lc η=1"
DEFAULT_RUNS_ROAD, DEFAULT_RUNS_CROSSROAD = 50, 20
DISTANCE_BINS = np.arange(-250.0, 251.0, 25.0)
PAPER_LC_ACCURACY = {0.5: 0.54, 3.0: 0.92}


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


def _signed_distances(config: ExperimentConfig) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per run: (steps × vehicles) signed distance to the centre, and the vehicle ids.

    The recordings are simulated again from the run's seed (cheap, and identical).
    """
    out = {}
    for r in range(config.runs):
        truth = run_recording(config, r).truth
        p, v = truth.vehicle_states[..., :2], truth.vehicle_states[..., 2:4]
        sign = np.where(np.einsum("tni,tni->tn", p, v) < 0, 1.0, -1.0)
        out[r] = (sign * np.linalg.norm(p, axis=2), truth.vehicle_ids)
    return out


def _rmse_vs_distance(result: ExperimentResult, label_of: dict[str, str] | None = None
                      ) -> dict[str, tuple[list[float], list[float]]]:
    distances = _signed_distances(result.config)
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


def _association(summary: dict[str, Any], name: str) -> tuple[float | None, float | None]:
    est = summary["estimators"].get(name, {})
    return est.get("association_accuracy"), est.get("discarded_share")


def _with_eta_one(config: ExperimentConfig) -> ExperimentConfig:
    """The same runs with icp-da-lc at η_TH = 1 alone."""
    specs = tuple(dataclasses.replace(s, params=s.params.with_overrides({"threshold": 1.0}))
                  for s in config.estimators if s.name == "icp-da-lc")
    return dataclasses.replace(config, estimators=specs)


def _crossroad_point(ctx: ReproduceContext, base: ExperimentConfig, overrides: dict[str, Any]
                     ) -> tuple[dict, dict, dict]:
    """RMSE-vs-distance curves and association numbers of one crossroad setting."""
    config = dataclasses.replace(base, scenario_params=base.scenario_params.with_overrides(overrides))
    result = ctx.run(config)
    curves = _rmse_vs_distance(result)
    summary = summarize(result)
    assoc = {"icp-da-lc": _association(summary, "icp-da-lc")}
    rmse_all = {n: e["vehicle_rmse_all"] for n, e in summary["estimators"].items()}
    if any(s.name == "icp-da-lc" for s in config.estimators):
        eta_one = ctx.run(_with_eta_one(config))
        curves.update(_rmse_vs_distance(eta_one, {"icp-da-lc": ETA_ONE}))
        summary_one = summarize(eta_one)
        assoc[ETA_ONE] = _association(summary_one, "icp-da-lc")
        rmse_all[ETA_ONE] = summary_one["estimators"]["icp-da-lc"]["vehicle_rmse_all"]
    return curves, assoc, rmse_all


def compute(ctx: ReproduceContext) -> dict[str, Any]:
    road_names, cross_names = ctx.compared, registered(CROSSROAD)
    runs_road, runs_cross = ctx.runs, ctx.runs_or(DEFAULT_RUNS_CROSSROAD, quick=1)

    # Fig. 7: road, RMSE over time per feature spacing
    fig7_v, fig7_f, road_assoc, road_rmse = {}, {}, {}, {}
    for spacing in FEATURE_SPACINGS:
        result = ctx.run(ctx.config("brambilla-road", scenario_overrides={"feature_spacing": spacing}))
        summary = summarize(result)
        key = f"d_f = {spacing:g} m"
        fig7_v[key] = _over_time(result, VEHICLE)
        fig7_f[key] = _over_time(result, FEATURE)
        road_assoc[key] = {n: _association(summary, n) for n in ("icp-da-lc", "icp-da-pf") if n in road_names}
        road_rmse[key] = {n: e["vehicle_rmse_all"] for n, e in summary["estimators"].items()}
    line_panels({f"vehicles, {k}": v for k, v in fig7_v.items()} | {f"features, {k}": v for k, v in
                                                                     fig7_f.items()},
                ctx.out / "fig7_road_rmse_over_time.png",
                f"Brambilla 2020 Fig. 7: position RMSE over time ({runs_road} runs)", "time [s]",
                "position RMSE [m]", markers=False)

    # Figs. 8–11: crossroad, static features for N_f, moving features for v_f
    cross_base = ctx.config("brambilla-crossroad", cross_names, runs=runs_cross)
    fig8, fig9, rmse8 = {}, {}, {}
    for n_features in FEATURE_COUNTS:
        static = {"n_features": n_features, "feature_speed": 0.0}
        curves, assoc, rmse_all = _crossroad_point(ctx, cross_base, static)
        fig8[f"N_f = {n_features}"], fig9[n_features], rmse8[n_features] = curves, assoc, rmse_all
    fig10, fig11, rmse10 = {}, {}, {}
    for speed in FEATURE_SPEEDS:
        moving = {"n_features": 20, "feature_speed": speed}
        curves, assoc, rmse_all = _crossroad_point(ctx, cross_base, moving)
        fig10[f"v_f = {speed:g} m/s"], fig11[speed], rmse10[speed] = curves, assoc, rmse_all
    line_panels(fig8, ctx.out / "fig8_rmse_vs_distance_features.png",
                f"Brambilla 2020 Fig. 8: vehicle RMSE vs distance to the centre, static features "
                f"({runs_cross} runs)", "signed distance to the junction [m] (> 0 approaching)",
                "position RMSE [m]")
    line_panels(fig10, ctx.out / "fig10_rmse_vs_distance_speed.png",
                f"Brambilla 2020 Fig. 10: vehicle RMSE vs distance, N_f = 20 moving features "
                f"({runs_cross} runs)", "signed distance to the junction [m] (> 0 approaching)",
                "position RMSE [m]")
    line_panels(_association_panels(fig9), ctx.out / "fig9_association_vs_features.png",
                "Brambilla 2020 Fig. 9: association of ICP-DA-LC vs number of features",
                "number of features N_f", "share of V2F measurements [%]")
    line_panels(_association_panels(fig11), ctx.out / "fig11_association_vs_speed.png",
                "Brambilla 2020 Fig. 11: association of ICP-DA-LC vs feature speed",
                "feature speed v_f [m/s]", "share of V2F measurements [%]")

    return {
        "runs_road": runs_road, "runs_crossroad": runs_cross,
        "road_estimators": road_names, "crossroad_estimators": cross_names,
        "fig7_vehicles": fig7_v, "fig7_features": fig7_f, "road_association": road_assoc,
        "road_vehicle_rmse_all": road_rmse,
        "fig8": fig8, "fig8_vehicle_rmse_all": {str(k): v for k, v in rmse8.items()},
        "fig9": {str(k): v for k, v in fig9.items()},
        "fig10": fig10, "fig10_vehicle_rmse_all": {str(k): v for k, v in rmse10.items()},
        "fig11": {str(k): v for k, v in fig11.items()},
    }


def _association_panels(points: dict[Any, dict[str, tuple[float | None, float | None]]]
                        ) -> dict[str, dict[str, tuple[list[float], list[float]]]]:
    """Panels 'association errors' and 'discarded' with one curve per LC variant (in %)."""
    xs = list(points)
    panels: dict[str, dict[str, tuple[list[float], list[float]]]] = {"wrong associations": {},
                                                                     "discarded measurements": {}}
    for label in sorted({lab for v in points.values() for lab in v}):
        acc = [points[x].get(label, (None, None))[0] for x in xs]
        disc = [points[x].get(label, (None, None))[1] for x in xs]
        panels["wrong associations"][label] = (
            [float(x) for x, a in zip(xs, acc, strict=True) if a is not None],
            [100 * (1 - a) for a in acc if a is not None])
        panels["discarded measurements"][label] = (
            [float(x) for x, d in zip(xs, disc, strict=True) if d is not None],
            [100 * d for d in disc if d is not None])
    return panels


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.0f} %"


def _near_centre(curves: dict[str, tuple[list[float], list[float]]], name: str) -> float | None:
    """RMSE in the bins within 50 m of the centre (pooled by mean of squares)."""
    if name not in curves:
        return None
    x, y = np.array(curves[name][0]), np.array(curves[name][1])
    near = np.abs(x) <= 50
    return float(np.sqrt(np.mean(y[near] ** 2))) if near.any() else None


def report(data: dict[str, Any]) -> list[str]:
    ra = data["road_association"]
    lines = [
        "# Brambilla, Nicoli, Soatti & Deflorio 2020 — reproduction of §V",
        "",
        f"Road: {data['runs_road']} runs per spacing; crossroad: {data['runs_crossroad']} runs per "
        f"point; seed {data['seed']}. Road estimators: {', '.join(data['road_estimators'])}; crossroad: "
        f"{', '.join(data['crossroad_estimators'])} and `{ETA_ONE}` (η_TH = 1). `icp` and `oracle-kf` "
        "know the association: they are bounds (dashed), not methods.",
    ]
    if data["quick"]:
        lines += ["", "**Quick mode**: the scenarios' full length and default particle counts, but "
                  "few runs — the orderings against GNSS show, the averages are not converged."]
    rmse_road = data["road_vehicle_rmse_all"]

    def road(key: str, name: str) -> str:
        return format_number(rmse_road.get(key, {}).get(name))

    lc = "icp-da-lc"
    lines += [
        "",
        "## Single road (§V-A, Fig. 7)",
        "",
        "| statement of the paper | paper | ours |",
        "|---|---|---|",
    ]
    for spacing, paper in PAPER_LC_ACCURACY.items():
        key = f"d_f = {spacing:g} m"
        lines.append(f"| ICP-DA-LC correct association at d_f = {spacing:g} m | {paper:.0%} | "
                     f"{_pct(ra.get(key, {}).get(lc, (None, None))[0])} |")
    for key in ra:
        lines.append(f"| vehicle RMSE (all steps), {key}: GNSS / ICP-DA-PF / ICP-DA-LC / ICP known DA / "
                     f"oracle | DA methods reach the known-DA bound at 0.5 and ≥ 6 m, lose some at 3 m "
                     f"(PF slightly better) | {road(key, 'gnss-kf')} / {road(key, 'icp-da-pf')} / "
                     f"{road(key, lc)} / {road(key, 'icp')} / {road(key, 'oracle-kf')} m |")
    f8 = data["fig8_vehicle_rmse_all"]
    lines += [
        "",
        "## Crossroad (§V-B, Figs. 8–11)",
        "",
        "| statement of the paper | paper | ours |",
        "|---|---|---|",
    ]
    for nf, values in f8.items():
        near = {n: _near_centre(data["fig8"][f"N_f = {nf}"], n) for n in ("gnss-kf", lc, ETA_ONE, "icp")}
        lines.append(
            f"| N_f = {nf}: ICP-DA-LC close to ICP known DA; with η_TH = 1 and N_f = 60 worse than GNSS "
            f"except near the junction | qualitative | RMSE GNSS {format_number(values.get('gnss-kf'))}, "
            f"LC {format_number(values.get(lc))}, LC η=1 {format_number(values.get(ETA_ONE))}, ICP "
            f"{format_number(values.get('icp'))} m; within 50 m of the centre: "
            + " / ".join(format_number(near[n]) for n in ("gnss-kf", lc, ETA_ONE, "icp")) + " m |")
    f9 = data["fig9"]
    lines.append("| Fig. 9: wrong associations grow with N_f, much more with η_TH = 1; discarded grow "
                 "with N_f | qualitative | wrong (η 0.5 / η 1): "
                 + ", ".join(f"N_f={k}: {_pct(_inv(v.get(lc)))} / {_pct(_inv(v.get(ETA_ONE)))}"
                             for k, v in f9.items())
                 + "; discarded (η 0.5): " + ", ".join(f"{k}: {_pct((v.get(lc) or (None, None))[1])}"
                                                        for k, v in f9.items()) + " |")
    f10 = data["fig10_vehicle_rmse_all"]
    lines.append("| Fig. 10: feature mobility above 1.5 m/s degrades ICP-DA-LC, which still beats GNSS "
                 "| qualitative | RMSE GNSS / LC: " + ", ".join(
                     f"v_f={k}: {format_number(v.get('gnss-kf'))} / {format_number(v.get(lc))} m"
                     for k, v in f10.items()) + " |")
    lines += [
        "",
        "Differences from the paper, and why:",
        "- Every vehicle's BPA-L prior is its own GNSS-only filter and the features start uniform at "
        "every step (`icp` docstring): feeding the cooperative posterior back as the next prior, as "
        "eqs. (11)–(12) do, double-counts information through the static features, and measured here "
        "it locks the vehicles onto overconfident beliefs worse than GNSS. Both variants are "
        "parameters (`feedback`, `feature_memory`).",
        "- The association (13) uses the same GNSS-only vehicle beliefs, so it sees larger "
        "uncertainty than the paper's refined beliefs: more association errors at a given spacing.",
        "- ICP-DA-PF uses J = 500 particles by default (paper: 5000) and a Silverman-widened pair "
        "kernel; without it the 0.2 m V2F noise leaves almost no particle pair inside the kernel.",
    ]
    return lines


def _inv(pair: tuple[float | None, float | None] | None) -> float | None:
    """1 − accuracy (the share of wrong associations), None where unknown."""
    return None if not pair or pair[0] is None else 1.0 - pair[0]


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
             ("Fig. 11", "fig11_association_vs_speed.png")),
)

