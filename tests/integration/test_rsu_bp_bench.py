"""The rsu-bp benchmark and example run end to end at small size (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from helpers import load_script


def test_rsu_bp_benchmark_writes_json(tmp_path: Path) -> None:
    module = load_script("benchmarks/rsu_bp.py")
    out = tmp_path / "rsu_bp.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for entry in data["rsu_bp"].values():
        assert entry["steps_per_second"] > 0 and entry["peak_memory_bytes_20_steps"] > 0
        assert set(entry["vehicle_rmse"]) == {"rsu-bp", "oracle-kf", "gnss-kf"}
        assert entry["gnss_kf_steps_per_second"] > 0 and entry["gnss_kf_steps_per_rsu_bp_step"] > 0
    kernel = data["pair_kernel"]
    for key in ("numba_stored_float32_pairs_per_second", "numba_fused_sum_float64_pairs_per_second",
                "numpy_broadcast_float64_pairs_per_second"):
        assert kernel[key] > 0


@pytest.mark.slow
def test_rsu_bp_sumo_benchmark_writes_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    module = load_script("benchmarks/rsu_bp.py")
    out = tmp_path / "rsu_bp_sumo.json"
    assert module.main(["--sumo", "--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    entry = data["sumo"]["sumo-grid-tlr"]
    assert entry["rsu-bp"]["steps_per_second"] > 0 and entry["peak_memory_bytes_20_steps"] > 0
    assert entry["rsu_over_gnss"] > 0 and entry["rsu_over_oracle"] is None
    assert len(data["scaling"]["per_vehicles"]) == 2


def test_rsu_bp_clutter_example() -> None:
    module = load_script("examples/rsu_bp_clutter.py")
    rmse = module.main(["--small"])
    assert set(rmse) == {"gnss-kf", "rsu-bp"}
    assert all(np.isfinite(v).all() for v in rmse.values())
