"""What reporting the NIS (`Estimate.info["nis"]`, issue 16 item 8) costs gnss-kf and oracle-kf.

    python benchmarks/nis_cost.py                 # results in benchmarks/results/nis_cost.json
    python benchmarks/nis_cost.py --quick         # tiny sizes, to check the script

Both filters update through `gaussian.kf_update_nis`. "before" is the same filter with that
function replaced by `kf_update` (no NIS: the update before the NIS was added), "after" the
filter as it is; the two alternate in one process on the same recordings (gnss-kf with 100
vehicles, oracle-kf on its default preset), and each figure is the best of `rounds` × `repeats`
passes (the minimum is the figure least disturbed by other load on the machine). The ratio
after/before is the cost; `kf_update` itself does not compute the NIS, so callers that do not
ask for it pay nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, recording, time_estimator, write_json

import cooploc.estimators.gnss_kf as gnss_kf_module
import cooploc.estimators.oracle_kf as oracle_kf_module
from cooploc.gaussian import kf_update, kf_update_nis

MODULES = (gnss_kf_module, oracle_kf_module)


def _without_nis(prior, z, H, R):
    return kf_update(prior, z, H, R), np.zeros(len(prior))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=10, help="before/after alternations")
    parser.add_argument("--repeats", type=int, default=3, help="passes per round")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check the script")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "nis_cost.json")
    args = parser.parse_args(argv)
    steps = 20 if args.quick else 500
    rounds, repeats = (1, 1) if args.quick else (args.rounds, args.repeats)
    recordings = {
        "gnss-kf": recording("froehle2018", 7, {"n_vehicles": 100, "n_features": 0, "n_steps": steps,
                                                "gnss_variances": (15.0,)}),
        "oracle-kf": recording("froehle2018", 0, {"n_steps": steps}),
    }
    update = {"before": _without_nis, "after": kf_update_nis}
    best = {(name, label): np.inf for name in recordings for label in update}
    for r in range(rounds):
        for label in ("before", "after") if r % 2 == 0 else ("after", "before"):
            for module in MODULES:
                module.kf_update_nis = update[label]
            for name, rec in recordings.items():
                us = time_estimator(name, rec, repeats)["us_per_step"]
                best[name, label] = min(best[name, label], us)
    for module in MODULES:
        module.kf_update_nis = kf_update_nis
    results: dict = {**environment(), "rounds": rounds, "repeats": repeats, "estimators": {}}
    for name in recordings:
        before, after = best[name, "before"], best[name, "after"]
        results["estimators"][name] = {"us_per_step_before": before, "us_per_step_after": after,
                                       "ratio": after / before}
        print(f"{name:>10}: {before:8.1f} µs/step without NIS, {after:8.1f} with, ratio {after / before:.3f}")
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
