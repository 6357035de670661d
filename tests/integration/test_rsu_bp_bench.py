"""The rsu-bp benchmark and example run end to end at small size (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from helpers import load_script


def test_rsu_bp_benchmark_writes_json(tmp_path: Path) -> None:
    module = load_script("benchmarks/rsu_bp.py")
    out = tmp_path / "rsu_bp.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for entry in data["rsu_bp"].values():
        assert entry["steps_per_second"] > 0 and entry["peak_memory_bytes_20_steps"] > 0
        assert set(entry["vehicle_rmse"]) == {"rsu-bp", "oracle-kf", "gnss-kf"}
    kernel = data["pair_kernel"]
    for key in ("numba_stored_float32_pairs_per_second", "numba_fused_sum_float64_pairs_per_second",
                "numpy_broadcast_float64_pairs_per_second"):
        assert kernel[key] > 0


def test_rsu_bp_clutter_example() -> None:
    module = load_script("examples/rsu_bp_clutter.py")
    rmse = module.main(["--small"])
    assert set(rmse) == {"gnss-kf", "rsu-bp"}
    assert all(np.isfinite(v).all() for v in rmse.values())
