"""Time the ICP estimators (Brambilla 2020) and count their V2V traffic; write JSON.

    python benchmarks/icp.py                      # results in benchmarks/results/icp.json
    python benchmarks/icp.py --quick --out icp.json

For `icp`, `icp-da-lc` and `icp-da-pf` on `brambilla-road` and `brambilla-crossroad`
(N_f = 20): steps per second and µs per step (time inside `step`), peak traced memory
(a separate pass), and the V2V messages and bytes per step and vehicle that the
`Network` counted. `icp-da-pf` is also timed against its particle count J (the pair
kernel costs J² per vehicle–feature pair; the paper used J = 5000).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, time_estimator, write_json

from cooploc.estimators import get_estimator

NAMES = ("icp", "icp-da-lc", "icp-da-pf")


def traffic(name: str, rec, params=None) -> dict:
    """Mean V2V messages and bytes per step and per vehicle."""
    est = new_estimator(name, rec, params)
    messages = bytes_ = vehicles = 0
    for frame in rec.frames:
        info = est.step(frame).info
        messages += info["messages"]
        bytes_ += info["bytes"]
        vehicles += frame.vehicles.size
    n = len(rec.frames)
    return {"messages_per_step": messages / n, "bytes_per_step": bytes_ / n,
            "bytes_per_vehicle_step": bytes_ / max(vehicles, 1)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="best of this many passes")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check the script")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "icp.json")
    args = parser.parse_args(argv)
    repeats = 1 if args.quick else args.repeats
    results: dict = {**environment(), "scenarios": {}, "icp-da-pf_vs_particles": {}}
    scenarios = {"brambilla-road": {}, "brambilla-crossroad": {"n_features": 20}}
    if args.quick:
        scenarios["brambilla-crossroad"]["n_steps"] = 8
    for preset, overrides in scenarios.items():
        rec = recording(preset, 1, overrides)
        entry = {}
        for name in NAMES:
            params = None
            if name == "icp-da-pf" and args.quick:
                params = get_estimator(name).Params(n_particles=100)
            timing = time_estimator(name, rec, repeats, params)
            entry[name] = {**timing, **traffic(name, rec, params)}
            print(f"{name:>10} on {preset}: {timing['steps_per_second']:8.1f} steps/s, "
                  f"{entry[name]['bytes_per_vehicle_step']:9.0f} B per vehicle-step")
        results["scenarios"][preset] = entry
    rec = recording("brambilla-road", 1)
    for J in ((50, 100) if args.quick else (200, 500, 1000, 2000, 5000)):
        params = get_estimator("icp-da-pf").Params(n_particles=J)
        timing = time_estimator("icp-da-pf", rec, 1, params)
        results["icp-da-pf_vs_particles"][str(J)] = timing
        print(f"icp-da-pf J = {J:5d}: {timing['steps_per_second']:8.2f} steps/s")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
