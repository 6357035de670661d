"""The scaling and oracle-kf benchmark scripts run end to end at quick size (no timing asserted)."""

from __future__ import annotations

import json

import numpy as np

from helpers import load_script


def test_scaling_benchmark_writes_json_and_figure(tmp_path):
    module = load_script("benchmarks/scaling.py")
    out = tmp_path / "scaling.json"
    module.main(["--quick", "--out", str(out), "-e", "gnss-kf", "-e", "oracle-kf"])
    data = json.loads(out.read_text())
    assert set(data["cells"]) == {"gnss-kf", "oracle-kf"} and data["sizes"] == [8, 16]
    for cells in data["cells"].values():
        assert set(cells) == {"8", "16"}
        assert all(c["seconds_per_step"] > 0 and c["steps"] == 6 and not c["capped"] for c in cells.values())
    assert all(np.isfinite(v) for v in data["growth_exponent"].values())
    assert data["environment"]["load_average"] is not None and "load_average_end" in data
    assert (tmp_path / "scaling.png").stat().st_size > 0


def test_a_capped_estimator_stops_growing(tmp_path):
    module = load_script("benchmarks/scaling.py")
    out = tmp_path / "capped.json"
    module.main(["--sizes", "8", "16", "--set", "n_steps=9", "--cap", "0", "-e", "gnss-kf",
                 "--out", str(out)])
    cells = json.loads(out.read_text())["cells"]["gnss-kf"]
    # the first chunk of 4 steps already exceeds a cap of 0 s: one capped cell, no larger size
    assert set(cells) == {"8"} and cells["8"]["capped"] and cells["8"]["steps"] == 4


def test_growth_exponent_is_the_log_log_slope():
    module = load_script("benchmarks/scaling.py")
    sizes = [100, 200, 400, 800]
    assert abs(module.growth_exponent(sizes, [3e-6 * n**1.5 for n in sizes]) - 1.5) < 1e-12
    assert module.growth_exponent([100], [1.0]) is None


def test_oracle_kf_benchmark_writes_json(tmp_path):
    module = load_script("benchmarks/oracle_kf.py")
    out = tmp_path / "oracle.json"
    module.main(["--quick", "--out", str(out)])
    data = json.loads(out.read_text())
    for preset in ("froehle2018", "brambilla-crossroad"):
        entry = data["presets"][preset]
        assert entry["steps_per_second"] > 0 and entry["prefix"]["max_rel_difference"] < 1e-9
    assert data["city"]["vehicles"] == 36 and data["city"]["features"] == 72
