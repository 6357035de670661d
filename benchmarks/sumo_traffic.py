"""Time the `sumo-*` scenarios: SUMO simulation and Recording build per simulated minute.

    python benchmarks/sumo_traffic.py                       # every sumo-* preset, 300 s each
    python benchmarks/sumo_traffic.py --duration 600 -p sumo-berlin-tlr
    python benchmarks/sumo_traffic.py --quick               # grid presets, 20 s: checks the runner

For each preset, three passes on the same traffic seed:

1. `simulate`: network build (netgenerate/netconvert), demand (randomTrips) and the
   headless SUMO run with state read-out every step — `simulate_traffic`, no cache;
2. `build`: the Recording (GNSS by zone, V2F, links, truth) from the cached traffic
   — what a Monte Carlo run on cached traffic costs;
3. peak traced Python memory of pass 2 (tracemalloc; SUMO's own C++ memory is not
   traced), separately because tracemalloc slows Python down.

Times are reported in seconds per simulated minute (recorded time; the warm-up is
simulated too and included in `simulate`), with the mean number of vehicles and
features present, steps/s and µs per step of the build. The cache goes to a temporary
folder, so the user's cache is not touched. Numbers depend on the machine and its load;
the JSON records the SUMO version and the environment of `common.environment()`
(versions, platform, CPU count, load average at start and end).

Not called sumo.py: run from this folder, that name would shadow Eclipse SUMO's `sumo`
package.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, peak_memory, write_json

from cooploc.scenarios import get_preset, presets


def time_preset(name: str, duration: float, seed: int) -> dict:
    from cooploc.scenarios import sumo

    params = get_preset(name).params.with_overrides({"duration": duration, "traffic_seed": seed})
    start = time.perf_counter()
    traffic = sumo.simulate_traffic(params, seed)
    simulate = time.perf_counter() - start
    traffic.save(sumo.cache_path(params, seed))  # generate() below finds it there
    start = time.perf_counter()
    recording = sumo.generate(params, np.random.default_rng(0))
    build = time.perf_counter() - start
    peak = peak_memory(lambda: sumo.generate(params, np.random.default_rng(0)))
    minutes = params.n_steps * params.dt / 60.0
    steps = len(recording.frames)
    return {
        "duration_s": params.n_steps * params.dt,
        "warmup_s": params.warmup,
        "steps": steps,
        "vehicles_total": int(recording.truth.vehicle_ids.size),
        "vehicles_mean_present": float(recording.truth.vehicle_present.sum(axis=1).mean()),
        "features_mean_present": float(recording.truth.feature_present.sum(axis=1).mean()),
        "simulate_seconds": simulate,
        "simulate_seconds_per_minute": simulate / minutes,
        "build_seconds": build,
        "build_seconds_per_minute": build / minutes,
        "build_steps_per_second": steps / build,
        "build_us_per_step": build / steps * 1e6,
        "build_peak_memory_bytes": peak,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-p", "--preset", action="append", help="preset (repeat); default all sumo-*")
    parser.add_argument("--duration", type=float, default=300.0, help="recorded seconds [300]")
    parser.add_argument("--seed", type=int, default=1, help="traffic seed [1]")
    parser.add_argument("--quick", action="store_true", help="grid presets, 20 s")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "sumo.json")
    args = parser.parse_args(argv)

    import sumo as sumo_package

    names = args.preset or sorted(n for n in presets() if n.startswith("sumo-"))
    if args.quick:
        names = [n for n in names if "-grid-" in n]
    duration = 20.0 if args.quick else args.duration
    results: dict = {**environment(), "sumo": sumo_package.__version__, "presets": {}}
    with tempfile.TemporaryDirectory(prefix="cooploc-bench-") as cache:
        os.environ["COOPLOC_CACHE_DIR"] = cache
        for name in names:
            entry = time_preset(name, duration, args.seed)
            results["presets"][name] = entry
            print(f"{name:>24}: simulate {entry['simulate_seconds_per_minute']:6.2f} s/min, "
                  f"build {entry['build_seconds_per_minute']:6.2f} s/min "
                  f"({entry['build_us_per_step']:8.0f} µs/step), "
                  f"{entry['vehicles_mean_present']:5.1f} vehicles, "
                  f"{entry['features_mean_present']:5.1f} features present, "
                  f"peak {entry['build_peak_memory_bytes'] / 1e6:.1f} MB")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
