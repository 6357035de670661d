"""Examples and the benchmark runner run end to end at small size (no timing asserted)."""

from __future__ import annotations

import json

from helpers import load_script


def test_quickstart_example(tmp_path):
    rmse = load_script("examples/froehle2018_quickstart.py").main(
        ["--small", "--out", str(tmp_path)])
    assert rmse["oracle-kf"]["1"] < rmse["gnss-kf"]["1"]
    assert (tmp_path / "summary.json").is_file()


def test_benchmark_runner_writes_json(tmp_path):
    out = tmp_path / "bench.json"
    assert load_script("benchmarks/run.py").main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for name in ("gnss-kf", "oracle-kf"):
        entry = data["estimators"][name]
        assert entry["steps_per_second"] > 0 and entry["peak_memory_bytes"] > 0
    assert data["gnss-kf-scaling"]["gnss_kf_us_per_vehicle_step"] > 0
