"""`cooploc run aoa-grid` end to end (no timing asserted); `reproduce plbp --quick` is tested in
tests/test_quick_modes.py."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cooploc.cli import app


def test_run_reports_heading_rmse(tmp_path) -> None:
    result = CliRunner().invoke(app, ["run", "aoa-grid", "-e", "plbp", "-e", "prior-lbp", "--runs", "2",
                                      "--out", str(tmp_path), "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "summary.json").read_text())
    for name in ("plbp", "prior-lbp"):
        assert 0.0 < summary["estimators"][name]["heading_rmse_all"] < 0.35
