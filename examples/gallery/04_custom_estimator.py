"""An estimator of your own, compared with the built-in ones.

An estimator is a class with a `name`, a one-line `summary`, a frozen `Params`
dataclass, `needs_truth = False`, a `default_preset`, the measurement kinds it cannot do
without (`required_sensors`) and `step(frame) -> Estimate`. Registered with
`cooploc.register_estimator`, it runs under `run_experiment` (and `cooploc run`) on the
same seeds as every other method.

The example is an α-β tracker: a fixed-gain filter that blends each GNSS fix into the
predicted position with gain α and corrects the velocity with gain β / dt — a Kalman
filter whose gain has been frozen. It needs no covariance arithmetic, but it must still
report one: the position variance an α-filter leaves of white fix noise,
α / (2 − α) σ², with σ² from the vehicle's latest fix.
"""

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

import cooploc
from cooploc.params import Params, param
from cooploc.plots import pyplot
from cooploc.types import Estimate, Frame, Setup, StateSet


@dataclass(frozen=True)
class AlphaBetaParams(Params):
    alpha: float = param(0.3, gt=0, le=1)
    beta: float = param(0.05, gt=0, le=1)


@cooploc.register_estimator
class AlphaBeta:
    name: ClassVar[str] = "alpha-beta"
    summary: ClassVar[str] = "fixed-gain α-β tracker per vehicle from its own GNSS (example)"
    Params: ClassVar[type] = AlphaBetaParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "froehle2018"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss",)

    def __init__(self, setup: Setup, params: AlphaBetaParams, rng: np.random.Generator) -> None:
        self.dt = setup.dt
        self.params = params
        prior = setup.vehicle_prior
        self.state = {int(i): m[:4].copy() for i, m in zip(prior.ids, prior.mean, strict=True)}
        self.variance: dict[int, float] = {}                      # σ² of the latest fix

    def step(self, frame: Frame) -> Estimate:
        gnss = frame.batches.get("gnss")
        a, b, dt = self.params.alpha, self.params.beta, self.dt
        for vid in frame.vehicles.tolist():
            x = self.state.setdefault(vid, np.zeros(4))
            x[:2] += dt * x[2:]                                   # predict
            rows = np.flatnonzero(gnss.subject == vid) if gnss is not None else []
            for row in rows:                                      # correct with each fix
                residual = gnss.z[row] - x[:2]
                x[:2] += a * residual
                x[2:] += b / dt * residual
                self.variance[vid] = float(np.trace(gnss.cov[row])) / 2
        mean = np.array([self.state[v] for v in frame.vehicles.tolist()]).reshape(-1, 4)
        shrink = a / (2 - a)
        cov = np.array([np.diag([shrink, shrink, 1.0, 1.0]) * self.variance.get(v, 100.0)
                        for v in frame.vehicles.tolist()]).reshape(-1, 4, 4)
        return Estimate(StateSet(frame.vehicles, mean, cov))


def main() -> None:
    config = cooploc.ExperimentConfig.build(
        "froehle2018", ["gnss-kf", "alpha-beta"], scenario_overrides={"n_steps": 200},
        runs=5, seed=1, backend="serial",
    )
    summary = cooploc.summarize(cooploc.run_experiment(config))

    fig, ax = pyplot().subplots(figsize=(6, 3.2))
    for name, est in summary["estimators"].items():
        per_run = est["per_run_vehicle_rmse"]["1"]
        ax.plot(range(len(per_run)), per_run, "o-", label=name)
        print(f"{name:>10}: vehicle 1 RMSE {est['vehicle_rmse']['1']:.2f} m")
    ax.set_xlabel("run")
    ax.set_ylabel("vehicle 1 position RMSE [m]")
    ax.set_xticks(range(config.runs))
    ax.legend()
    fig.tight_layout()


if __name__ == "__main__":
    main()
