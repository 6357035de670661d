r"""Comparing estimators: a small Monte Carlo study.

Three estimators on the same Fröhle 2018 runs — the GNSS-only filter, the paper's
particle BP with data association at the road-side unit (`rsu-bp`, here with fewer
particles than the paper's 600 to keep the example fast) and the known-association
bound (`oracle-kf`). One seed fixes every number, whatever the backend. The command-line
equivalent is

    cooploc run froehle2018 -e gnss-kf -e rsu-bp -e oracle-kf --runs 4 --seed 1 \
        --set n_steps=60 --est-set rsu-bp.n_particles=200

The bars are the pooled position RMSE of each vehicle (root of the mean over steps and
runs of the squared error), the ticks each run's RMSE.
"""

import numpy as np

import cooploc
from cooploc.plots import pyplot


def main() -> None:
    config = cooploc.ExperimentConfig.build(
        "froehle2018", ["gnss-kf", "rsu-bp", "oracle-kf"],
        scenario_overrides={"n_steps": 60},
        estimator_overrides={"rsu-bp": {"n_particles": 200}},
        runs=4, seed=1, backend="serial",
    )
    result = cooploc.run_experiment(config)
    summary = cooploc.summarize(result)

    fig, ax = pyplot().subplots(figsize=(6.5, 3.4))
    names = list(summary["estimators"])
    width = 0.38
    for j, vid in enumerate(("0", "1")):
        x = np.arange(len(names)) + (j - 0.5) * width
        pooled = [summary["estimators"][n]["vehicle_rmse"][vid] for n in names]
        ax.bar(x, pooled, width, label=f"vehicle {vid}")
        for xi, n in zip(x, names, strict=True):
            runs = summary["estimators"][n]["per_run_vehicle_rmse"][vid]
            ax.plot(np.full(len(runs), xi), runs, "k_", markersize=10)
    ax.set_xticks(np.arange(len(names)), names)
    ax.set_ylabel("position RMSE [m]")
    ax.set_yscale("log")
    ax.legend()
    fig.tight_layout()

    for name, est in summary["estimators"].items():
        print(f"{name:>10}: pooled RMSE {est['vehicle_rmse_all']:.3f} m")


if __name__ == "__main__":
    main()
