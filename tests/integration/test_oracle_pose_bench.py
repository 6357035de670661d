"""benchmarks/oracle_pose.py runs end to end at quick size (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

from helpers import load_script


def test_oracle_pose_benchmark_writes_json(tmp_path: Path) -> None:
    out = tmp_path / "op.json"
    assert load_script("benchmarks/oracle_pose.py").main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for name, row in data["presets"].items():
        assert row["filter"]["steps_per_second"] > 0 and row["smoother"]["seconds"] > 0, name
        assert row["smoother"]["peak_memory_bytes"] > 0 and row["reference"]["name"]
    assert data["load_average_end"] is not None
