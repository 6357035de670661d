"""benchmarks/sumo_traffic.py runs at quick size and writes its JSON (no timing asserted)."""

from __future__ import annotations

import json

from helpers import load_script


def test_sumo_benchmark_writes_json(tmp_path, monkeypatch):
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    module = load_script("benchmarks/sumo_traffic.py")
    out = tmp_path / "bench.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert set(data["presets"]) == {"sumo-grid-tlr", "sumo-grid-vsr"}
    for entry in data["presets"].values():
        assert entry["simulate_seconds_per_minute"] > 0 and entry["build_seconds_per_minute"] > 0
        assert entry["steps"] == round(20 / 0.75) and entry["vehicles_mean_present"] > 0
        assert entry["build_peak_memory_bytes"] > 0
        # the new sensors (issue 19): both builds timed, the cache holds the new arrays
        assert entry["build_ratio"] > 0 and entry["generation_ratio"] > 0
        assert entry["cache_bytes"] > entry["cache_bytes_without_new_arrays"] > 0
        assert entry["radars"] > 0 and entry["rows_per_step"]["aoa"] > 0
