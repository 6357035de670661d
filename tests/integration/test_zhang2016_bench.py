"""benchmarks/zhang2016.py runs at quick size and writes its JSON (no timing asserted)."""

from __future__ import annotations

import json

from helpers import load_script


def test_benchmark_writes_json(tmp_path):
    module = load_script("benchmarks/zhang2016.py")
    out = tmp_path / "bench.json"
    assert module.main(["--quick", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    for key, proposal in (("sme_pf_particles", "linearized"), ("sme_pf_particles_bootstrap", "bootstrap")):
        curve = data[key]
        assert curve["proposal"] == proposal
        assert len(curve["n_particles"]) == len(curve["total_rmse_mean"]) == len(curve["ms_per_step"]) \
            == len(curve["minus_kf_mean"]) == len(curve["steps_per_second"])
        assert all(v > 0 for v in curve["ms_per_step"]) and curve["kf_known_da_ms_per_step"] > 0
    assert data["gm_phd"]["gm_phd_us_per_step"] > 0 and data["gm_phd"]["stonesoup_us_per_step"] > 0
    memory = data["peak_memory_bytes"]
    assert all(v > 0 for v in memory.values()) and "sme-pf bootstrap" in memory
