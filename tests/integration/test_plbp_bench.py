"""benchmarks/plbp.py runs at quick size and writes its JSON (no timing asserted)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_plbp_benchmark_quick(tmp_path) -> None:
    spec = importlib.util.spec_from_file_location("bench_plbp", ROOT / "benchmarks" / "plbp.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "plbp.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [s["n_vehicles"] for s in data["snapshots"]] == [51, 204]
    for entry in data["snapshots"]:
        for name in ("plbp", "prior-lbp"):
            assert entry[name]["seconds_per_step"] > 0 and entry[name]["n_links"] > 0
    assert data["tracking"]["plbp"]["steps_per_second"] > 0
