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

Numbers depend on the machine and its load; the JSON records the environment of
`common.environment()` (versions, platform, CPU count, load average at start and end).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, recording, time_estimator, write_json

from cooploc.estimators import estimators


def gnss_kf_scaling(n_vehicles: int, n_steps: int, repeats: int) -> dict:
    """gnss-kf with many vehicles against filterpy's KalmanFilter on the same data."""
    rec = recording("froehle2018", 7, {"n_vehicles": n_vehicles, "n_features": 0,
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
        rec = recording(cls.default_preset, 0, overrides)
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
