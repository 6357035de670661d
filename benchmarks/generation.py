"""Scenario generation against the number of vehicles: `brambilla-crossroad` from 250 to 5000.

    python benchmarks/generation.py                     # 250 … 5000 vehicles, 32 steps
    python benchmarks/generation.py --vehicles 100 200 --out /tmp/gen.json

For each size, the seconds of `generate` (best of `--repeats`; wall and CPU time of
this process, which a loaded machine disturbs less), the V2V links of the last frame,
and — as a reference measured in the same process, so that the ratio
survives a loaded machine — the seconds of the dense n × n distance matrix that built
the links before `cooploc.geometry.links_within` (one frame, times the steps). The
fitted exponent b of time ∝ n^b over the sizes (CPU time; a first small run warms up
the imports) says how generation grows (1: linear).
The links grow with the vehicles that share a communication range: linearly here (more
clusters queue behind the first ones at a fixed spacing), faster than n where the
density grows with n (more traffic in the same streets), and generation with them.

Numbers depend on the machine and its load; the JSON records `common.environment()`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, write_json

from cooploc.scenarios import get_preset


def _dense_links_seconds(positions: np.ndarray, radius: float) -> float:
    """The pre-k-d-tree way: every pair's distance, then the upper triangle."""
    start = time.perf_counter()
    d = np.hypot(*(positions[:, None, :] - positions[None, :, :]).transpose(2, 0, 1))
    np.nonzero(np.triu(d <= radius, k=1))
    return time.perf_counter() - start


def time_size(n: int, repeats: int) -> dict:
    preset = get_preset("brambilla-crossroad")
    params = preset.params.with_overrides({"n_vehicles": n})
    best = best_cpu = float("inf")
    for r in range(repeats):
        start, cpu = time.perf_counter(), time.process_time()
        recording = preset.generate(np.random.default_rng(r), params)
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - cpu)
    last = recording.frames[-1]
    positions = recording.truth.vehicle_states[-1, :, :2]
    dense = _dense_links_seconds(positions, params.communication_range) * params.n_steps
    return {"vehicles": n, "steps": params.n_steps, "generate_seconds": best,
            "generate_cpu_seconds": best_cpu,
            "links_last_frame": int(last.links.shape[0]), "dense_links_seconds": dense,
            "dense_over_generate": dense / best}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, nargs="+", default=[250, 500, 1000, 2000, 5000])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "generation.json")
    args = parser.parse_args(argv)
    results: dict = {**environment(), "scenario": "brambilla-crossroad", "sizes": []}
    time_size(12, 1)  # imports (scipy.spatial) and first calls, not timed
    for n in args.vehicles:
        entry = time_size(n, args.repeats)
        results["sizes"].append(entry)
        print(f"{n:>6} vehicles: generate {entry['generate_seconds']:7.2f} s "
              f"({entry['generate_cpu_seconds']:.2f} s CPU), "
              f"{entry['links_last_frame']:>9} links in the last frame, "
              f"dense link matrices alone {entry['dense_links_seconds']:7.2f} s")
    if len(results["sizes"]) >= 2:
        n = np.log([e["vehicles"] for e in results["sizes"]])
        t = np.log([e["generate_cpu_seconds"] for e in results["sizes"]])
        results["growth_exponent"] = float(np.polyfit(n, t, 1)[0])
        print(f"generate time ∝ n^{results['growth_exponent']:.2f}")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
