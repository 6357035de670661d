"""`cooploc reproduce PAPER --quick` shows each method working (issue 14, deliverable 4).

Each test runs one paper's quick mode end to end (seed 0, serial) and asserts, from the
numbers it wrote to data.json, every ordering against the non-cooperative baseline that
its paper claims:

- froehle2018 (§V-B, Figs. 3–5): `rsu-bp` reduces vehicle 2's RMSE below the GNSS-only
  Kalman filter — in Fig. 3, at every V2F variance of Fig. 4 and for every K ≥ 1 of
  Fig. 5 (K = 0 *is* the GNSS-only filter, so it is not an ordering);
- gulati (Table I): both factor graphs beat the Kalman filter of eq. 20;
- plbp (Figs. 4–6): on the dense intersection, posterior linearization beats prior
  linearization, and both beat the prior (the non-cooperative estimate), in every panel
  of Fig. 6 too; on the sparse Manhattan blocks plbp still beats the prior;
- brambilla2020 (§V, Figs. 7, 8, 10): ICP-DA-PF and ICP-DA-LC beat GNSS on the road at
  every feature spacing; ICP-DA-LC (η_TH = 0.5) beats GNSS on the crossroad for every
  N_f and feature speed, significantly from N_f = 10 on;
- sumo (§VI, Fig. 16a): ICP-DA-LC beats GNSS in both TLR and VSR.

zhang2016 has no such test: the paper claims SME beats the Kalman filter given the
association, which does not reproduce at any size (`tests/test_zhang2016.py` holds the
measured reverse ordering); its quick mode is exercised in
`tests/integration/test_zhang2016_cli.py`.

The quick sizes are chosen in each `cooploc.reproduce` module so that these orderings
hold with margin for several seeds, not only seed 0; the margins asserted here are
looser than the worst of those seeds (the ratios measured are in each test).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from cooploc.cli import app
from cooploc.reproduce import ReproduceOptions, get_experiment


def _quick(paper: str, out: Path) -> dict[str, Any]:
    get_experiment(paper).run(ReproduceOptions(out, quick=True, backend="serial"))
    return json.loads((out / "data.json").read_text())


@pytest.mark.slow
def test_froehle2018(tmp_path: Path) -> None:
    out = tmp_path / "rep"
    result = CliRunner().invoke(app, ["reproduce", "froehle2018", "--quick", "--out", str(out),
                                      "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    for name in ("fig3_rmse_cdf.png", "fig4_rmse_vs_v2f_variance.png",
                 "fig5_rmse_vs_features.png", "report.md", "data.json"):
        assert (out / name).is_file(), name
    report = (out / "report.md").read_text()
    assert "3.5 m" in report and "2.53 m analytic" in report
    data = json.loads((out / "data.json").read_text())
    assert "rsu-bp" in data["compared"]

    # Fig. 3: the method reduces vehicle 2's RMSE significantly (seeds 0–2: 0.27–0.47 × GNSS)
    fig3 = data["fig3_vehicle_rmse"]
    assert fig3["rsu-bp"]["1"] < 0.75 * fig3["gnss-kf"]["1"], fig3
    # Fig. 4: below GNSS at every V2F variance (worst of seeds 0–2: 0.78 × at 10 m²)
    c4 = data["fig4"]["vehicle_rmse"]
    assert all(m < g for m, g in zip(c4["rsu-bp"]["1"], c4["gnss-kf"]["1"], strict=True)), c4
    # Fig. 5: K = 0 is the GNSS-only filter; every K ≥ 1 is below it (worst: 0.62 × at K = 1)
    c5, counts = data["fig5"]["vehicle_rmse"], data["fig5"]["n_features"]
    assert c5["oracle-kf"]["1"][0] == pytest.approx(c5["gnss-kf"]["1"][0], rel=1e-9)
    for name in ("rsu-bp", "oracle-kf"):
        for k, m, g in zip(counts, c5[name]["1"], c5["gnss-kf"]["1"], strict=True):
            assert k == 0 or m < g, (name, k, m, g)


@pytest.mark.slow
def test_gulati(tmp_path: Path) -> None:
    data = _quick("gulati", tmp_path)
    report = (tmp_path / "report.md").read_text()
    assert "5.211" in report and "0.153" in report  # the paper's numbers beside ours
    for fig in ("fig3_trajectories_2v", "fig4_rmse_per_step_2v", "fig5_trajectories_4v",
                "fig6_rmse_per_step_4v"):
        assert (tmp_path / f"{fig}.png").stat().st_size > 1000
    for n in ("2", "3", "4"):
        row = data["table"][n]
        assert set(row) == {"fg-topology-new", "fg-topology-old", "gnss-kf", "fg-isam2",
                            "oracle-pose-smoother"}
        for value in row.values():
            assert np.isfinite(value["total_rmse"]) and value["seconds_per_run"] > 0
            # eq. 21 sums over vehicles: total² = N × per-vehicle² (every vehicle present)
            np.testing.assert_allclose(np.mean(np.square(value["per_run_total_rmse"])),
                                       int(n) * value["vehicle_rmse_all"] ** 2, rtol=1e-9)
        # Table I: both factor graphs beat the Kalman filter (paper 0.62–0.85; seeds 0–2: ≤ 0.72)
        for name in ("fg-topology-new", "fg-topology-old"):
            assert row[name]["ratio_to_kalman"] < 0.85, (n, name, row[name]["ratio_to_kalman"])
        # the known-association bound with the radar pose estimated beats every method
        # (seed 0: the others ≥ 2.07 × it)
        assert all(v["ratio_to_bound"] > 1.3 for k, v in row.items() if k != "oracle-pose-smoother"), n
        study = data["study"][n]
        assert study["runs"] == 2 and set(study["new"]) >= {"solve_seconds", "iterations", "nees"}
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert {c["outcome"] for c in claims} <= {"reproduced", "not reproduced", "not checked"}
    assert "## New vs old factor" in report


@pytest.mark.slow
def test_plbp(tmp_path: Path) -> None:
    data = _quick("plbp", tmp_path)
    for scene in ("aoa-grid", "aoa-manhattan"):
        for name in ("fig4_rmse_vs_iterations", "fig5_error_cdf", "fig6_rmse_vs_parameters", "field_of_view"):
            assert (tmp_path / f"{name}_{scene}.png").stat().st_size > 0
    report = (tmp_path / "report.md").read_text()
    assert "within 4 m and 0.15 rad" in report and "maximum a posteriori" in report
    assert "field of view" in report and "## `aoa-manhattan`" in report
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert len(claims) == 2 * 23 and all(c["outcome"] in ("reproduced", "not reproduced") for c in claims)
    grid, manhattan = data["scenes"]["aoa-grid"], data["scenes"]["aoa-manhattan"]
    fov = grid["field_of_view"]
    assert len(fov["curves"]["plbp"]["within"]) == len(fov["values"])
    assert all(0.0 <= w <= 1.0 for w in fov["curves"]["plbp"]["within"])
    assert len(grid["per_snapshot"]["plbp/pos"]) == data["runs"]

    # Fig. 4 on the dense intersection (J = 0 is the prior): posterior < prior linearization
    # < prior, at J = 5 (seeds 0–2: 1.1–1.5 < 2.6–3.0 < 6.8–7.1 m; heading 0.05–0.06 vs
    # 0.31–0.36 rad)
    post, prior = grid["fig4"]["plbp/L3"], grid["fig4"]["prior-lbp/L3"]
    assert len(post["pos"]) == data["j_max"] + 1
    assert post["pos"][5] < 0.8 * prior["pos"][5] < 0.8 * post["pos"][0]
    assert post["heading"][5] < 0.5 * post["heading"][0]
    # Fig. 6: better than the prior at every σ_p, even above 10 m (prior RMSE σ_p √2; ≤ 0.73 ×)
    sigma_p = grid["fig6"]["prior_position_std"]
    for s, rmse in zip(sigma_p["values"], sigma_p["curves"]["plbp"]["pos"], strict=True):
        assert rmse < 0.9 * math.sqrt(2.0) * s, (s, rmse)
    # the sparse Manhattan blocks: still better than the prior, posterior no worse than prior
    # linearization (seeds 0–2: 0.86–0.92 × the prior, 0.94–0.99 × prior linearization)
    post, prior = manhattan["fig4"]["plbp/L3"], manhattan["fig4"]["prior-lbp/L3"]
    assert post["pos"][5] < 0.97 * post["pos"][0] and post["pos"][5] <= prior["pos"][5]


@pytest.mark.slow
def test_brambilla2020(tmp_path: Path) -> None:
    data = _quick("brambilla2020", tmp_path)
    for name in ("fig7_road_rmse_over_time", "fig8_rmse_vs_distance_features", "fig9_association_vs_features",
                 "fig10_rmse_vs_distance_speed", "fig11_association_vs_speed", "bounds_ratio"):
        assert (tmp_path / f"{name}.png").stat().st_size > 0
    assert set(data["crossroad_features"]) == {"3", "10", "20", "60"}
    assert "icp-da-lc η=1" in data["crossroad_features"]["20"]["curves"]
    report = (tmp_path / "report.md").read_text()
    assert "54%" in report and "92%" in report            # the paper's association figures
    claims = json.loads((tmp_path / "claims.json").read_text())
    assert len(claims) > 20
    assert {c["outcome"] for c in claims} <= {"reproduced", "not reproduced", "not checked"}

    # Fig. 7: both DA methods below GNSS at every spacing (seeds 0–2: ≤ 0.96 × over all
    # steps, the first ones before any V2F row included)
    for spacing, point in data["road"].items():
        rmse = point["rmse"]
        for name in ("icp-da-pf", "icp-da-lc", "icp"):
            assert rmse[name] < rmse["gnss-kf"], (spacing, name, rmse)
    # Figs. 8 and 10: ICP-DA-LC with η_TH = 0.5 below GNSS everywhere, well below from N_f = 10
    # and with moving features (seeds 0–2: ≤ 0.93 × at N_f = 3, ≤ 0.81 × elsewhere)
    points = [(f"N_f = {k}", int(k) >= 10, v["rmse"]) for k, v in data["crossroad_features"].items()]
    points += [(f"v_f = {k}", True, v["rmse"]) for k, v in data["crossroad_speed"].items()]
    for point, significant, rmse in points:
        bound = 0.9 * rmse["gnss-kf"] if significant else rmse["gnss-kf"]
        assert rmse["icp-da-lc"] < bound, (point, rmse)


@pytest.mark.slow
def test_sumo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "sumo"
    data = _quick("sumo", out)
    for name in ("fig16_rmse_over_time.png", "fig17_error_cdf_per_zone.png", "report.md"):
        assert (out / name).stat().st_size > 0
    assert {"gnss-kf", "icp-da-lc", "oracle-kf"} <= set(data["compared"])
    n_bins = math.ceil(data["scenario_params"]["duration"] / data["bin_seconds"])
    for name in data["compared"]:
        for regulation in ("tlr", "vsr"):
            curves = data["fig16"][name][regulation]
            assert len(curves["position"]) == n_bins and all(v is not None for v in curves["position"])
            assert all(v is not None for v in curves["velocity"])
        zones = data["fig17"][name]
        assert set(zones) == {"A", "B", "C"}
        assert sum(z["n"] for z in zones.values()) > 0
    report = (out / "report.md").read_text()
    assert "Fig. 16" in report and "zone C" in report and "Quick mode" in report

    # Fig. 16a: ICP-DA-LC beats GNSS in both regulations (seeds 0–2: 0.61–0.85 ×); the
    # known-association references too
    overall = data["overall"]
    for regulation in ("tlr", "vsr"):
        gnss = overall["gnss-kf"][regulation]["position"]
        for name in ("icp-da-lc", "icp", "oracle-kf"):
            assert overall[name][regulation]["position"] < 0.95 * gnss, (name, regulation, overall)
