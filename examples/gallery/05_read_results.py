"""Reading a results folder: summary.json, errors.parquet and config.toml.

`cooploc run` (or `write_results`) leaves a folder that other tools can read without
cooploc: `summary.json` (the stable summary contract), `errors.parquet` (one row per
run × step × estimator × entity) and `config.toml` (the resolved configuration, which
`cooploc run --config` reruns exactly). Here a small experiment is written to a
temporary folder and read back with the standard library and pyarrow, and the error
table is drawn as an empirical CDF of the position error per estimator.

From the command line the folder would come from

    cooploc run froehle2018 -e gnss-kf -e oracle-kf --runs 3 --seed 1 --set n_steps=100 --out OUT
"""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq

import cooploc
from cooploc.plots import pyplot

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="cooploc-results-") as tmp:
        read_back(Path(tmp))


def read_back(out: Path) -> None:
    config = cooploc.ExperimentConfig.build(
        "froehle2018", ["gnss-kf", "oracle-kf"], scenario_overrides={"n_steps": 100},
        runs=3, seed=1, backend="serial",
    )
    cooploc.write_results(cooploc.run_experiment(config), out)
    print("files:", ", ".join(sorted(p.name for p in out.iterdir())))

    summary = json.loads((out / "summary.json").read_text())
    print("scenario", summary["scenario"], "runs", summary["runs"], "seed", summary["seed"])
    for name, est in summary["estimators"].items():
        print(f"  {name:>10}: vehicle_rmse_all {est['vehicle_rmse_all']:.3f} m")

    settings = tomllib.loads((out / "config.toml").read_text())
    print("config.toml keys:", ", ".join(settings))

    table = pq.read_table(out / "errors.parquet")
    print("errors.parquet columns:", ", ".join(table.column_names), f"({table.num_rows} rows)")
    vehicles = table.filter(pc.equal(table["kind"], "vehicle"))

    fig, ax = pyplot().subplots(figsize=(6, 3.4))
    for name in summary["estimators"]:
        rows = vehicles.filter(pc.equal(vehicles["estimator"], name))
        err = np.sort(rows["err_pos"].to_numpy())
        ax.step(err, np.arange(1, err.size + 1) / err.size, where="post", label=name)
    ax.set_xscale("log")
    ax.set_xlabel("position error [m] (every vehicle, step and run)")
    ax.set_ylabel("CDF")
    ax.legend()
    fig.tight_layout()


if __name__ == "__main__":
    main()
