"""`cooploc run zhang2016-*` and `cooploc reproduce zhang2016 --quick` end to end."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cooploc.cli import app

runner = CliRunner()


def test_run_writes_total_rmse_and_ospa(tmp_path):
    out = tmp_path / "r"
    result = runner.invoke(app, ["run", "zhang2016-ct2", "-e", "sme-pf", "-e", "gm-phd", "-e", "kf-known-da",
                                 "--runs", "2", "--seed", "3", "--set", "n_steps=8",
                                 "--est-set", "sme-pf.n_particles=200", "--out", str(out),
                                 "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    for name in ("sme-pf", "gm-phd", "kf-known-da"):
        entry = summary["estimators"][name]
        assert entry["total_rmse"] > 0 and entry["ospa"] > 0 and entry["vehicle_rmse_all"] > 0
    assert "total error, eq. (20)" in (out / "report.md").read_text()


def test_reproduce_quick(tmp_path):
    out = tmp_path / "z"
    result = runner.invoke(app, ["reproduce", "zhang2016", "--quick", "--out", str(out),
                                 "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    for name in ("fig2_trajectories.png", "fig3_total_error.png", "fig4_error_per_step.png", "report.md",
                 "data.json", "claims.json"):
        assert (out / name).is_file()
    report = (out / "report.md").read_text()
    assert "SME better than the Kalman filter" in report and "Quick mode" in report
    data = json.loads((out / "data.json").read_text())
    for scenario in ("zhang2016-cv", "zhang2016-ct2", "zhang2016-ct4"):
        totals = data[scenario]["per_run_total"]
        assert set(totals) >= {"sme-pf", "kf-known-da", "gm-phd", "sme-ukf"}
        assert all(len(v) == 2 and min(v) > 0 for v in totals.values() if v)   # variants: CV only
        assert len(totals["MHT, anonymous rows + T (analysis)"]) == 2   # what SME's information allows
        assert set(data[scenario]["per_run_close"]) >= {"sme-pf", "kf-known-da"}
    assert "## Where sme-pf loses against the Kalman filter" in report
