"""Time `plbp` and `prior-lbp` per snapshot against the number of vehicles and write JSON.

    python benchmarks/plbp.py                 # 51 → 1000 vehicles, results in benchmarks/results/plbp.json
    python benchmarks/plbp.py --quick         # 51 and 204 vehicles, one pass

The grid grows with the number of vehicles at the density of the `aoa-grid` default
(51 vehicles on a 50 m × 50 m square with a street every 50 m): grid_size =
50 m · sqrt(n / 51), so the vehicles per metre of lane stay the same and R_c = 30 m
(Table I). For each size and estimator: best-of-`repeats` seconds per snapshot (time
inside `step`, J = 5, L = 3; numba compiled beforehand), µs per link, links, AoA rows,
and peak traced memory of a separate pass (tracemalloc slows Python down). Also the
steps per second of `plbp` on `aoa-grid-tracking`. Target (issue 7): 1000 vehicles in
under 1 s on 2 cores. Numbers depend on the machine and its load; the JSON records the
environment of `common.environment()` (versions, platform, CPU count, load average at
start and end).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, time_steps, write_json

from cooploc.scenarios import get_preset

SIZES = (51, 204, 459, 1000)
QUICK_SIZES = (51, 204)
ESTIMATORS = ("plbp", "prior-lbp")
TARGET_SECONDS = 1.0


def snapshot(n_vehicles: int, seed: int):
    """One `aoa-grid` snapshot with `n_vehicles` at the default density, and its parameters."""
    base = get_preset("aoa-grid").params
    grid = base.grid_size * np.sqrt(n_vehicles / base.n_vehicles)
    overrides = {"n_vehicles": n_vehicles, "grid_size": float(grid)}
    return recording("aoa-grid", seed, overrides), base.with_overrides(overrides)


def time_snapshot(name: str, rec, repeats: int) -> dict:
    """Best-of-`repeats` seconds inside `step` for the recording's frames, the links of
    the last frame, and peak memory."""
    timing, estimates = time_steps(name, rec, repeats)
    return {"seconds_per_step": timing["seconds"] / timing["steps"],
            "steps_per_second": timing["steps_per_second"], "us_per_step": timing["us_per_step"],
            "n_links": int(estimates[-1].info["n_links"]), "peak_memory_bytes": timing["peak_memory_bytes"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="best of this many passes")
    parser.add_argument("--quick", action="store_true", help="small sizes, one pass")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "plbp.json")
    args = parser.parse_args(argv)
    sizes = QUICK_SIZES if args.quick else SIZES
    repeats = 1 if args.quick else args.repeats

    warm, _ = snapshot(51, 0)                          # compile the numba kernels first
    for name in ESTIMATORS:
        new_estimator(name, warm).step(warm.frames[0])

    results: dict = {
        **environment(),
        "target_seconds_1000_vehicles": TARGET_SECONDS, "snapshots": [],
    }
    for n in sizes:
        rec, params = snapshot(n, 1)
        entry = {"n_vehicles": n, "grid_size_m": params.grid_size,
                 "communication_radius_m": params.communication_radius,
                 "aoa_rows": len(rec.frames[0].batches["aoa"])}
        for name in ESTIMATORS:
            timing = time_snapshot(name, rec, repeats)
            timing["us_per_link"] = timing["us_per_step"] / max(timing["n_links"], 1)
            entry[name] = timing
            print(f"{name:>9}, {n:5d} vehicles, {timing['n_links']:6d} links: "
                  f"{timing['seconds_per_step'] * 1e3:8.1f} ms per snapshot, "
                  f"{timing['us_per_link']:5.2f} µs per link, "
                  f"peak {timing['peak_memory_bytes'] / 1e6:.1f} MB")
        results["snapshots"].append(entry)
    rec = recording("aoa-grid-tracking", 2)
    results["tracking"] = {"preset": "aoa-grid-tracking", "n_steps": len(rec.frames),
                           "plbp": time_snapshot("plbp", rec, repeats)}
    print(f"plbp on aoa-grid-tracking: {results['tracking']['plbp']['steps_per_second']:.1f} steps/s")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
