"""`cooploc run` on a SUMO preset end to end; `reproduce sumo --quick` is in tests/test_quick_modes.py."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cooploc.cli import app

runner = CliRunner()


@pytest.fixture
def cache_env(tmp_path) -> dict[str, str]:
    return {"COOPLOC_CACHE_DIR": str(tmp_path / "cache")}


def test_run_on_a_sumo_preset(tmp_path, cache_env):
    out = tmp_path / "r"
    result = runner.invoke(app, [
        "run", "sumo-grid-vsr", "-e", "gnss-kf", "--runs", "2", "--seed", "3",
        "--set", "grid_size=2", "--set", "grid_length=80", "--set", "duration=10",
        "--set", "warmup=30", "--set", "zone_radii=45,52", "--out", str(out),
        "--backend", "serial", "--no-progress"], env=cache_env)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["params"]["zone_radii"] == [45.0, 52.0]
    assert summary["params"]["regulation"] == "vsr"
    gnss = summary["estimators"]["gnss-kf"]
    assert gnss["vehicle_rmse_all"] is not None and gnss["vehicle_rmse_all"] > 0
    # two runs, each its own traffic (drawn from the run's generator), both cached
    assert len(list((tmp_path / "cache" / "sumo").glob("grid-vsr-*.npz"))) == 2


def test_bad_sumo_parameter_is_one_line(cache_env):
    result = runner.invoke(app, ["run", "sumo-grid-tlr", "-e", "gnss-kf", "--set",
                                 "regulation=sometimes", "--no-progress"], env=cache_env)
    assert result.exit_code == 2
    assert "regulation" in result.output and "sometimes" in result.output
