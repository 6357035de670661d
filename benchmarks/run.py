"""Time every registered estimator on its default preset and write JSON.

    python benchmarks/run.py                      # all estimators, results in benchmarks/results/
    python benchmarks/run.py -e gnss-kf --steps 200 --out bench.json
    python benchmarks/run.py --quick              # tiny sizes, to check the runner

For each estimator: steps per second and mean µs per step (time inside `step` only,
scenario simulation excluded), and peak traced memory of a separate pass (tracemalloc
slows Python down, so time and memory are measured in different passes).

Extra measurements:
- `gnss-kf-scaling`: `gnss-kf` with 100 vehicles (µs per vehicle-step, target < 5 µs)
  beside filterpy's `KalmanFilter` predict+update of one target (µs per vehicle-step),
  measured in the same run on the same data.

Numbers depend on the machine; the JSON records Python, NumPy and CPU count.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from cooploc import __version__
from cooploc.estimators import estimators, make_estimator
from cooploc.scenarios import get_preset


def _recording(preset_name: str, seed: int, overrides: dict):
    preset = get_preset(preset_name)
    params = preset.params.with_overrides(overrides)
    return preset.generate(np.random.default_rng(seed), params)


def environment() -> dict:
    """What the numbers depend on: cooploc, Python and NumPy versions, machine, CPU count."""
    return {"cooploc_version": __version__, "python": sys.version.split()[0], "numpy": np.__version__,
            "machine": platform.machine(), "cpu_count": os.cpu_count()}


def write_json(results: dict, out: Path) -> None:
    """Write the results (creating the folder) and say where."""
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"written {out}")


def time_estimator(name: str, recording, repeats: int, params=None) -> dict:
    """Best-of-`repeats` time inside `step` over the recording, and peak memory."""
    best = np.inf
    for r in range(repeats):
        est = make_estimator(name, recording.setup, params, np.random.default_rng(r), recording.truth)
        spent = 0.0
        for frame in recording.frames:
            start = time.perf_counter()
            est.step(frame)
            spent += time.perf_counter() - start
        best = min(best, spent)
    est = make_estimator(name, recording.setup, params, np.random.default_rng(0), recording.truth)
    tracemalloc.start()
    for frame in recording.frames:
        est.step(frame)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    n = len(recording.frames)
    return {
        "steps": n,
        "seconds": best,
        "steps_per_second": n / best,
        "us_per_step": best / n * 1e6,
        "peak_memory_bytes": int(peak),
    }


def gnss_kf_scaling(n_vehicles: int, n_steps: int, repeats: int) -> dict:
    """gnss-kf with many vehicles against filterpy's KalmanFilter on the same data."""
    rec = _recording("froehle2018", 7, {"n_vehicles": n_vehicles, "n_features": 0,
                                         "n_steps": n_steps, "gnss_variances": (15.0,)})
    ours = time_estimator("gnss-kf", rec, repeats)
    out = {"n_vehicles": n_vehicles, "n_steps": n_steps,
           "gnss_kf_us_per_vehicle_step": ours["us_per_step"] / n_vehicles,
           "gnss_kf_steps_per_second": ours["steps_per_second"]}
    try:
        from filterpy.kalman import KalmanFilter
    except ImportError:
        out["filterpy"] = "not installed (pip install 'cooploc[dev]')"
        return out
    setup = rec.setup
    F = setup.vehicle_motion.transition_matrix(setup.dt)
    Q = setup.vehicle_motion.noise_covariance(setup.dt)
    H = setup.sensors["gnss"].observation_matrix(4)
    filters = []
    for i in range(n_vehicles):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.F, kf.Q, kf.H = F, Q, H
        kf.x, kf.P = setup.vehicle_prior.mean[i].copy(), setup.vehicle_prior.cov[i].copy()
        filters.append(kf)
    best = np.inf
    for _ in range(repeats):
        spent = 0.0
        for frame in rec.frames:
            gnss = frame.batches["gnss"]
            start = time.perf_counter()
            for i, kf in enumerate(filters):
                kf.predict()
                kf.update(gnss.z[i], R=gnss.cov[i])
            spent += time.perf_counter() - start
        best = min(best, spent)
    out["filterpy_us_per_vehicle_step"] = best / (n_steps * n_vehicles) * 1e6
    out["speedup_vs_filterpy"] = out["filterpy_us_per_vehicle_step"] / out[
        "gnss_kf_us_per_vehicle_step"]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-e", "--estimator", action="append", help="estimator (repeat); default all")
    parser.add_argument("--steps", type=int, default=None, help="steps per recording [preset's]")
    parser.add_argument("--repeats", type=int, default=3, help="best of this many passes")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check the runner")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "estimators.json")
    args = parser.parse_args(argv)

    names = args.estimator or sorted(estimators())
    steps = 20 if args.quick else args.steps
    repeats = 1 if args.quick else args.repeats
    results: dict = {**environment(), "estimators": {}}
    for name in names:
        cls = estimators()[name]
        overrides = {} if steps is None else {"n_steps": steps}
        rec = _recording(cls.default_preset, 0, overrides)
        entry = {"preset": cls.default_preset, **time_estimator(name, rec, repeats)}
        results["estimators"][name] = entry
        print(f"{name:>12} on {cls.default_preset}: {entry['steps_per_second']:9.1f} steps/s, "
              f"{entry['us_per_step']:8.1f} µs/step, peak {entry['peak_memory_bytes'] / 1e6:.2f} MB")
    if "gnss-kf" in names:
        scaling = gnss_kf_scaling(20 if args.quick else 100, 20 if args.quick else 500, repeats)
        results["gnss-kf-scaling"] = scaling
        print(f"gnss-kf, {scaling['n_vehicles']} vehicles: "
              f"{scaling['gnss_kf_us_per_vehicle_step']:.2f} µs per vehicle-step"
              + (f"; filterpy KalmanFilter {scaling['filterpy_us_per_vehicle_step']:.1f} µs"
                 if "filterpy_us_per_vehicle_step" in scaling else ""))
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
