"""benchmarks/common.py: the environment record and step timing the benchmark scripts share."""

from __future__ import annotations

import json

from helpers import load_script


def test_environment_has_the_documented_keys():
    env = load_script("benchmarks/common.py").environment()
    assert set(env) == {"cooploc_version", "python", "numpy", "numba", "platform", "machine",
                        "cpu_count", "load_average"}
    assert env["cpu_count"] > 0


def test_time_estimator_on_a_tiny_recording():
    common = load_script("benchmarks/common.py")
    rec = common.recording("froehle2018", 0, {"n_steps": 5})
    timing, estimates = common.time_steps("gnss-kf", rec, 2)
    assert timing["steps"] == len(estimates) == len(rec.frames)
    assert timing["steps_per_second"] > 0 and timing["peak_memory_bytes"] > 0
    assert common.time_estimator("gnss-kf", rec, 1)["us_per_step"] > 0


def test_write_json_records_the_end_load_average(tmp_path):
    out = tmp_path / "sub" / "bench.json"
    load_script("benchmarks/common.py").write_json({"x": 1}, out)
    text = out.read_text()
    assert text.endswith("}\n")
    assert set(json.loads(text)) == {"x", "load_average_end"}
