"""Time the `sumo-*` scenarios: SUMO simulation and Recording build per simulated minute.

    python benchmarks/sumo_traffic.py                       # every sumo-* preset, 300 s each
    python benchmarks/sumo_traffic.py --duration 600 -p sumo-berlin-tlr
    python benchmarks/sumo_traffic.py --quick               # grid presets, 20 s: checks the runner

For each preset, these passes on the same traffic seed:

1. `simulate`: network build (netgenerate/netconvert), demand (randomTrips) and the
   headless SUMO run with state read-out every step — `simulate_traffic`, no cache;
2. `build`: the Recording (GNSS by zone, V2F, links, truth, and every sensor family
   of issue 19: radars, odometry, AoA, anonymous GNSS) from the cached traffic — what
   a Monte Carlo run on cached traffic costs; and `build_without_new_sensors`, the
   same with those families off (the recording of before issue 19), alternating,
   best of `--repeats` each;
3. peak traced Python memory of the build with every family (tracemalloc; SUMO's own
   C++ memory is not traced), separately because tracemalloc slows Python down;
4. the cache file: its size, and the size of the same traffic without the arrays that
   the new sensors added to it (the heading and the junctions: cache format 3).

Times are reported in seconds per simulated minute (recorded time; the warm-up is
simulated too and included in `simulate`), with the mean number of vehicles and
features present, steps/s and µs per step of the build. The ratios with / without the
new sensors — `build_ratio` (wall clock) and `build_cpu_ratio` (this process's CPU time,
steadier on a shared machine), `generation_ratio` (simulate + build) and `cache_ratio` —
come from the same run, so the machine's load affects both sides alike. The cache goes to a temporary
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

#: every sensor family of issue 19 on, and off (the recording of before)
NEW_SENSORS_ON = {"radar": True, "odometry": True, "aoa": True, "anonymous_gnss": True}
NEW_SENSORS_OFF = {"radar": False, "odometry": False, "aoa": False, "anonymous_gnss": False}
#: the arrays the new sensors added to the cached traffic (cache format 4)
NEW_TRAFFIC_ARRAYS = ("vehicle_heading", "junction_ids", "junctions", "junction_roads")


def _old_format_bytes(traffic: object, folder: Path) -> int:
    """Size of the cache file of `traffic` without `NEW_TRAFFIC_ARRAYS` (cache format 3)."""
    import dataclasses

    path = folder / "format-3.npz.tmp"  # not a cache entry: measured, then deleted
    with path.open("wb") as file:
        np.savez_compressed(file, **{f.name: getattr(traffic, f.name) for f in dataclasses.fields(traffic)
                                     if f.name not in NEW_TRAFFIC_ARRAYS})
    size = path.stat().st_size
    path.unlink()
    return size


def time_preset(name: str, duration: float, seed: int, repeats: int = 3) -> dict:
    from cooploc.scenarios import sumo

    params = get_preset(name).params.with_overrides({"duration": duration, "traffic_seed": seed})
    on, off = params.with_overrides(NEW_SENSORS_ON), params.with_overrides(NEW_SENSORS_OFF)
    start = time.perf_counter()
    traffic = sumo.simulate_traffic(params, seed)
    simulate = time.perf_counter() - start
    path = sumo.cache_path(params, seed)
    traffic.save(path)  # generate() below finds it there
    cache_bytes, old_bytes = path.stat().st_size, _old_format_bytes(traffic, path.parent)
    times: dict[str, list[float]] = {"on": [], "off": []}
    cpu: dict[str, list[float]] = {"on": [], "off": []}
    for _ in range(repeats):  # alternating, so that a change of load hits both
        for key, variant in (("off", off), ("on", on)):
            start, start_cpu = time.perf_counter(), time.process_time()
            recording = sumo.generate(variant, np.random.default_rng(0))
            times[key].append(time.perf_counter() - start)
            cpu[key].append(time.process_time() - start_cpu)
    build, build_off = min(times["on"]), min(times["off"])
    peak = peak_memory(lambda: sumo.generate(on, np.random.default_rng(0)))
    minutes = params.n_steps * params.dt / 60.0
    steps = len(recording.frames)
    rows = {kind: sum(len(f.batches[kind]) for f in recording.frames if kind in f.batches)
            for kind in ("gnss", "v2f", "radar", "odometry", "aoa")}
    return {
        "duration_s": params.n_steps * params.dt,
        "warmup_s": params.warmup,
        "steps": steps,
        "vehicles_total": int(recording.truth.vehicle_ids.size),
        "vehicles_mean_present": float(recording.truth.vehicle_present.sum(axis=1).mean()),
        "features_mean_present": float(recording.truth.feature_present.sum(axis=1).mean()),
        "radars": len(recording.setup.infrastructure_ids),
        "rows_per_step": {kind: n / steps for kind, n in rows.items()},
        "simulate_seconds": simulate,
        "simulate_seconds_per_minute": simulate / minutes,
        "build_seconds": build,
        "build_seconds_per_minute": build / minutes,
        "build_steps_per_second": steps / build,
        "build_us_per_step": build / steps * 1e6,
        "build_peak_memory_bytes": peak,
        "build_without_new_sensors_seconds": build_off,
        "build_ratio": build / build_off,
        # CPU time of this process: less disturbed by other jobs on a shared machine
        "build_cpu_ratio": min(cpu["on"]) / min(cpu["off"]),
        "generation_ratio": (simulate + build) / (simulate + build_off),
        "cache_bytes": cache_bytes,
        "cache_bytes_without_new_arrays": old_bytes,
        "cache_ratio": cache_bytes / old_bytes,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-p", "--preset", action="append", help="preset (repeat); default all sumo-*")
    parser.add_argument("--duration", type=float, default=300.0, help="recorded seconds [300]")
    parser.add_argument("--seed", type=int, default=1, help="traffic seed [1]")
    parser.add_argument("--quick", action="store_true", help="grid presets, 20 s")
    parser.add_argument("--repeats", type=int, default=3, help="builds per variant, best kept [3]")
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
            entry = time_preset(name, duration, args.seed, 1 if args.quick else args.repeats)
            results["presets"][name] = entry
            print(f"{name:>24}: simulate {entry['simulate_seconds_per_minute']:6.2f} s/min, "
                  f"build {entry['build_seconds_per_minute']:6.2f} s/min "
                  f"({entry['build_us_per_step']:8.0f} µs/step), "
                  f"{entry['vehicles_mean_present']:5.1f} vehicles, "
                  f"{entry['features_mean_present']:5.1f} features present, "
                  f"peak {entry['build_peak_memory_bytes'] / 1e6:.1f} MB; with / without the new "
                  f"sensors: build ×{entry['build_ratio']:.2f} (CPU ×{entry['build_cpu_ratio']:.2f}), "
                  f"generation ×{entry['generation_ratio']:.2f}, "
                  f"cache ×{entry['cache_ratio']:.2f} ({entry['cache_bytes'] / 1e6:.2f} MB)")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
