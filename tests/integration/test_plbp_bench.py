"""benchmarks/plbp.py runs at quick size and writes its JSON (no timing asserted)."""

from __future__ import annotations

import json

from helpers import load_script


def test_plbp_benchmark_quick(tmp_path) -> None:
    module = load_script("benchmarks/plbp.py")
    out = tmp_path / "plbp.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [s["n_vehicles"] for s in data["snapshots"]] == [51, 204]
    for entry in data["snapshots"]:
        for name in ("plbp", "prior-lbp"):
            assert entry[name]["seconds_per_step"] > 0 and entry[name]["n_links"] > 0
    assert data["tracking"]["plbp"]["steps_per_second"] > 0
