"""The command line: list, run, reproduce, and one-line errors with exit code 2."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cooploc.cli import app

runner = CliRunner()


def test_list_names_everything():
    result = runner.invoke(app, ["list"], env={"COLUMNS": "250"})  # no wrapping
    assert result.exit_code == 0
    for word in ("froehle2018", "gnss-kf", "oracle-kf", "accuracy bound", "KNOWN"):
        assert word in result.output


def test_run_writes_results(tmp_path):
    out = tmp_path / "r"
    result = runner.invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "-e", "oracle-kf",
                                 "--runs", "2", "--seed", "1", "--set", "n_steps=20",
                                 "--est-set", "oracle-kf.feature_timeout=10", "--out", str(out),
                                 "--backend", "serial", "--no-progress"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["params"]["n_steps"] == 20
    assert summary["estimators"]["oracle-kf"]["params"]["feature_timeout"] == 10
    rerun = runner.invoke(app, ["run", "--config", str(out / "config.toml"), "--out",
                                str(tmp_path / "again"), "--no-progress"])
    assert rerun.exit_code == 0, rerun.output
    again = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert again["estimators"]["gnss-kf"]["vehicle_rmse"] == summary["estimators"]["gnss-kf"][
        "vehicle_rmse"]


@pytest.mark.parametrize(("args", "message"), [
    (["--set", "n_vehicle=3"], "unknown key 'n_vehicle'; valid keys: n_vehicles, n_features"),
    (["--set", "n_vehicles=abc"], "n_vehicles must be an integer, got 'abc'"),
    (["--set", "n_vehicles=0"], "n_vehicles must be >= 1, got 0"),
    (["--set", "gnss_variances=1,x"], "gnss_variances must be a comma-separated list"),
    (["--set", "novalue"], "--set takes key=value"),
    (["--est-set", "gnss-kf.x=1"], "gnss-kf: unknown key 'x'"),
    (["--est-set", "oracle-kf.feature_timeout=2"], "not in -e"),
    (["--est-set", "feature_timeout=2"], "--est-set takes EST.key=value"),
    (["-e", "nope"], "unknown estimator 'nope'"),
    (["--runs", "0"], "runs must be a positive integer"),
    (["--backend", "threads"], "backend must be one of"),
])
def test_run_errors_are_one_line_exit_2(args, message):
    result = runner.invoke(app, ["run", "froehle2018", "-e", "gnss-kf", *args])
    assert result.exit_code == 2
    assert message in result.output
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_unknown_scenario_and_paper():
    result = runner.invoke(app, ["run", "nowhere", "-e", "gnss-kf"])
    assert result.exit_code == 2 and "unknown scenario 'nowhere'" in result.output
    result = runner.invoke(app, ["reproduce", "nopaper"])
    assert result.exit_code == 2 and "unknown paper experiment 'nopaper'" in result.output
