"""Benchmark `oracle-pose` (filter) and `oracle-pose-smoother` (its batch solve); write JSON.

    python benchmarks/oracle_pose.py                       # the gulati-* and zhang2016-* presets
    python benchmarks/oracle_pose.py --quick --out b.json  # tiny sizes, to check the script

Measured in one process, on the same recordings, per preset:

1. the filter: steps per second inside `step` (best of `--repeats` passes, fresh
   estimator each) and its peak traced memory (a pass of its own);
2. the smoother's `smooth()` alone (one batch LM solve of the whole run and of the
   radar pose, marginals included), best of `--repeats`, with its LM iterations and
   its peak traced memory;
3. the reference in the same process: the per-vehicle Kalman filter the paper compares
   with (`gnss-kf` on gulati, `kf-known-da` on zhang2016), so that the ratio
   filter / reference is comparable across machines and loads.

Every timed pass runs with one BLAS thread (`backends.limit_threads(1)`): on a loaded
machine OpenBLAS threads that spin for a shared core make a banded Cholesky of the
smoother hundreds of times slower, and the experiment runner's workers run with one
thread too. The load average at the start and end is recorded with the versions and
platform (`common.environment()`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, peak_memory, recording, run_steps, time_steps, write_json

from cooploc.backends import limit_threads

PRESETS = ("gulati-2v", "gulati-3v", "gulati-4v", "zhang2016-cv")
REFERENCE = {"gulati": "gnss-kf", "zhang2016": "kf-known-da"}


def time_smoother(rec, repeats: int) -> dict:
    """Best-of-`repeats` seconds of `smooth()` after a full pass of `step`, and its peak memory."""
    best, iterations = np.inf, None
    for r in range(repeats):
        est = new_estimator("oracle-pose-smoother", rec, seed=r)
        run_steps(est, rec.frames)
        start = time.perf_counter()
        out = est.smooth()
        best = min(best, time.perf_counter() - start)
        iterations = out[-1].info["iterations"]
    est = new_estimator("oracle-pose-smoother", rec)
    run_steps(est, rec.frames)
    return {"seconds": best, "lm_iterations": iterations, "peak_memory_bytes": peak_memory(est.smooth)}


def time_preset(name: str, seed: int, repeats: int, overrides: dict | None = None) -> dict:
    rec = recording(name, seed, overrides)
    reference = REFERENCE[name.split("-")[0]]
    run_steps(new_estimator("oracle-pose", rec), rec.frames[:3])      # imports and first calls
    filt, _ = time_steps("oracle-pose", rec, repeats)
    ref, _ = time_steps(reference, rec, repeats)
    out = {"steps": len(rec.frames), "vehicles": int(rec.truth.vehicle_ids.size), "filter": filt,
           "smoother": time_smoother(rec, repeats), "reference": {"name": reference, **ref},
           "filter_time_ratio_to_reference": filt["seconds"] / ref["seconds"]}
    ratio = out["filter_time_ratio_to_reference"]
    print(f"{name}: filter {filt['steps_per_second']:.0f} steps/s (×{ratio:.1f} the time of {reference}), "
          f"smooth() {out['smoother']['seconds'] * 1e3:.1f} ms")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/oracle_pose.json"))
    parser.add_argument("--presets", nargs="*", default=list(PRESETS))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="tiny sizes: check that the script runs")
    args = parser.parse_args(argv)
    presets, repeats, overrides = args.presets, args.repeats, {}
    if args.quick:
        presets, repeats = ["gulati-2v", "zhang2016-cv"], 1
        overrides = {"n_steps": 10}
    results = {"environment": environment(), "repeats": repeats, "presets": {}}
    with limit_threads(1):
        for name in presets:
            results["presets"][name] = time_preset(name, args.seed, repeats, overrides)
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
