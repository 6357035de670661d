"""`cooploc run` on a SUMO preset and `cooploc reproduce sumo --quick`, end to end."""

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


def test_reproduce_sumo_quick(tmp_path, cache_env):
    out = tmp_path / "sumo"
    result = runner.invoke(app, ["reproduce", "sumo", "--quick", "--out", str(out),
                                 "--backend", "serial", "--no-progress"], env=cache_env)
    assert result.exit_code == 0, result.output
    for name in ("fig16_rmse_over_time.png", "fig17_error_cdf_per_zone.png", "report.md"):
        assert (out / name).stat().st_size > 0
    data = json.loads((out / "data.json").read_text())
    assert {"gnss-kf", "oracle-kf"} <= set(data["compared"])
    n_bins = 3  # 30 s in 10-s intervals
    for name in data["compared"]:
        for regulation in ("tlr", "vsr"):
            curves = data["fig16"][name][regulation]
            assert len(curves["position"]) == n_bins and all(v is not None for v in curves["position"])
            assert all(v is not None for v in curves["velocity"])
        zones = data["fig17"][name]
        assert set(zones) == {"A", "B", "C"}
        assert sum(z["n"] for z in zones.values()) > 0
    # the bound beats GNSS alone overall (known association, V2F σ = 0.1 m)
    overall = data["overall"]
    assert overall["oracle-kf"]["tlr"]["position"] < overall["gnss-kf"]["tlr"]["position"]
    report = (out / "report.md").read_text()
    assert "Fig. 16" in report and "zone C" in report and "Quick mode" in report
