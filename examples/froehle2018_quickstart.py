"""Quick start: GNSS-only filter against the known-association bound on Fröhle 2018.

    python examples/froehle2018_quickstart.py            # 501 steps, 5 runs
    python examples/froehle2018_quickstart.py --small    # what CI runs

Steps:
1. simulate the §V-A scenario (2 vehicles, 3 features; GNSS 0.01 / 15 m², V2F 1 m²),
2. run `gnss-kf` and `oracle-kf` on the same recordings,
3. print the position RMSE per vehicle (m) and write a results folder.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import cooploc


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="40 steps, 2 runs")
    parser.add_argument("--out", type=Path, default=None, help="results folder")
    args = parser.parse_args(argv)

    # 1. one recording, step by step through the Python API
    preset = cooploc.get_preset("froehle2018")
    params = preset.params.with_overrides({"n_steps": 40 if args.small else 501})
    recording = preset.generate(np.random.default_rng(1), params)
    gnss_kf = cooploc.make_estimator("gnss-kf", recording.setup, None, np.random.default_rng(2))
    errors = cooploc.evaluate(recording, cooploc.estimate(gnss_kf, recording))
    print("one run, gnss-kf vehicle 1 RMSE [m]:", round(cooploc.rmse(errors.err_pos[errors.id == 1]), 3))

    # 2. Monte Carlo with both estimators (one seed → every number)
    config = cooploc.ExperimentConfig.build(
        "froehle2018", ["gnss-kf", "oracle-kf"], scenario_overrides={"n_steps": params.n_steps},
        runs=2 if args.small else 5, seed=1, backend="serial",
    )
    result = cooploc.run_experiment(config)
    summary = cooploc.summarize(result)

    # 3. report
    rmse = {name: est["vehicle_rmse"] for name, est in summary["estimators"].items()}
    for name, by_vehicle in rmse.items():
        print(f"{name:>10}: " + ", ".join(f"vehicle {v}: {r:.3f} m" for v, r in by_vehicle.items()))
    out = args.out or Path(tempfile.mkdtemp(prefix="cooploc-"))
    cooploc.write_results(result, out)
    print("results folder:", out)
    return rmse


if __name__ == "__main__":
    main()
