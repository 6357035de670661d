"""`cooploc reproduce brambilla2020 --quick` writes every figure, data.json and the report."""

from __future__ import annotations

import json

from cooploc.reproduce import ReproduceOptions, get_experiment


def test_reproduce_brambilla_quick(tmp_path):
    options = ReproduceOptions(tmp_path, runs=1, quick=True, backend="serial")
    out = get_experiment("brambilla2020").run(options)
    for name in ("fig7_road_rmse_over_time", "fig8_rmse_vs_distance_features", "fig9_association_vs_features",
                 "fig10_rmse_vs_distance_speed", "fig11_association_vs_speed"):
        assert (out / f"{name}.png").stat().st_size > 0
    data = json.loads((out / "data.json").read_text())
    assert set(data["fig8"]) == {"N_f = 3", "N_f = 10", "N_f = 20", "N_f = 60"}
    assert "icp-da-lc η=1" in data["fig8"]["N_f = 20"]
    report = (out / "report.md").read_text()
    assert "54%" in report and "92%" in report            # the paper's association figures
