"""The ICP benchmark script runs end to end at quick size (no timing asserted)."""

from __future__ import annotations

import json

from helpers import load_script


def test_icp_benchmark_writes_json(tmp_path):
    module = load_script("benchmarks/icp.py")
    out = tmp_path / "icp.json"
    assert module.main(["--quick", "--out", str(out), "--only", "paper", "--only", "city",
                        "--only", "curve"]) == 0
    data = json.loads(out.read_text())
    for preset in ("brambilla-road", "brambilla-crossroad"):
        for name in ("icp", "icp-da-lc", "icp-da-pf"):
            entry = data["scenarios"][preset][name]
            assert entry["steps_per_second"] > 0 and entry["peak_memory_bytes"] > 0
            assert entry["bytes_per_step"] > 0
    assert set(data["icp-da-pf_vs_particles"]) == {"50", "100"}
    city = data["city_200"]
    assert city["icp-da-lc"]["seconds_per_step"] > 0 and city["icp-da-lc"]["ratio_to_gnss_kf"] > 0
    curve = data["vehicle_curve"]
    assert [p["n_vehicles"] for p in curve["points"]] == [20, 40] and "growth_exponent" in curve
