"""benchmarks/factor_graph.py runs end to end at quick size (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

from helpers import load_script


def test_factor_graph_benchmark_writes_json(tmp_path: Path) -> None:
    module = load_script("benchmarks/factor_graph.py")
    out = tmp_path / "fg.json"
    module.main(["--quick", "--out", str(out)])
    data = json.loads(out.read_text())
    for name in ("gnss-kf", "fg-topology-old", "fg-topology-new", "fg-isam2"):
        entry = data["estimators"]["2v"][name]
        assert entry["us_per_step_cpu"] > 0 and entry["peak_bytes"] > 0
    for kind, row in data["batch_solve"]["2v"].items():
        # before and after solve the same graph to the same minimum
        costs = [row[k]["cost"] for k in ("gtsam_naive", "gtsam_scalar", "sparse")]
        assert max(costs) - min(costs) <= 1e-6 * max(costs), (kind, costs)
        assert row["gtsam_no_topology"]["cost"] < row["sparse"]["cost"]
    assert data["isam2"]["2v"]["after"]["ms_per_step_cpu"] > 0
    assert set(data["horizon"]) == {"20", "40"}
    row = data["old_vs_new"]["2v"]
    assert row["runs"] == 2 and row["median_ratio_new_old_sparse_cpu_s"] > 0
    assert len(row["per_run"]["new"]["gtsam_iterations"]) == 2
    assert data["jit"]["empty_cache_s"] > 0 and data["jit"]["filled_cache_s"] > 0
