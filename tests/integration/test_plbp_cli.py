"""`cooploc reproduce plbp --quick` and `cooploc run aoa-grid` end to end (no timing asserted)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cooploc.cli import app


def test_reproduce_plbp_quick(tmp_path) -> None:
    result = CliRunner().invoke(app, ["reproduce", "plbp", "--quick", "--out", str(tmp_path),
                                      "--backend", "serial"])
    assert result.exit_code == 0, result.output
    for name in ("fig4_rmse_vs_iterations.png", "fig5_error_cdf.png", "fig6_rmse_vs_parameters.png",
                 "field_of_view.png"):
        assert (tmp_path / name).stat().st_size > 0
    data = json.loads((tmp_path / "data.json").read_text())
    post, prior = data["fig4"]["plbp/L3"]["pos"], data["fig4"]["prior-lbp/L3"]["pos"]
    assert len(post) == data["j_max"] + 1 and post[-1] < prior[-1] < post[0]
    fov = data["field_of_view"]
    assert len(fov["curves"]["plbp"]["within"]) == len(fov["values"])
    assert all(0.0 <= w <= 1.0 for w in fov["curves"]["plbp"]["within"])
    report = (tmp_path / "report.md").read_text()
    assert "within 4 m and 0.15 rad" in report and "maximum a posteriori" in report
    assert "field of view" in report


def test_run_reports_heading_rmse(tmp_path) -> None:
    result = CliRunner().invoke(app, ["run", "aoa-grid", "-e", "plbp", "-e", "prior-lbp", "--runs", "2",
                                      "--out", str(tmp_path), "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "summary.json").read_text())
    for name in ("plbp", "prior-lbp"):
        assert 0.0 < summary["estimators"][name]["heading_rmse_all"] < 0.35
