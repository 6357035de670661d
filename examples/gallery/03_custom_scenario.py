"""A scenario of your own: vehicles on a ring road.

A scenario family is a `Params` dataclass and a function `generate(params, rng) ->
Recording`; `cooploc.register_scenario` gives it named presets, which then run like the
built-in ones (`cooploc run`, `run_experiment`, every estimator that finds the sensors
it needs). Here: `n_vehicles` cars driving around a circle at constant speed, each with
a GNSS fix per step. The truth is exact circular motion; the estimators are told a
constant-velocity model, so the turn shows up as model error.

In a package, the same module registered through the `cooploc.scenarios` entry point
appears in `cooploc list` (see the Plug-ins page).
"""

from dataclasses import dataclass

import numpy as np

import cooploc
from cooploc.motion import ConstantVelocity
from cooploc.params import Params, param
from cooploc.plots import pyplot
from cooploc.sensors import GnssPosition
from cooploc.types import Batch, Frame, Recording, Setup, StateLayout, StateSet, Truth


@dataclass(frozen=True)
class RingParams(Params):
    n_vehicles: int = param(4, ge=1)
    radius: float = param(60.0, gt=0)          # m
    speed: float = param(12.0, gt=0)           # m/s
    n_steps: int = param(150, ge=1)
    dt: float = param(0.2, gt=0)               # s
    gnss_variance: float = param(9.0, gt=0)    # m² per axis


def generate(params: RingParams, rng: np.random.Generator) -> Recording:
    n, T, dt, r = params.n_vehicles, params.n_steps, params.dt, params.radius
    ids = np.arange(n, dtype=np.int64)
    # angle of vehicle i at step k; evenly spaced around the ring
    angle = params.speed / r * dt * np.arange(T)[:, None] + 2 * np.pi * ids / n
    states = np.stack([r * np.cos(angle), r * np.sin(angle),
                       -params.speed * np.sin(angle), params.speed * np.cos(angle)], axis=-1)
    gnss = GnssPosition(default_cov=params.gnss_variance * np.eye(2))
    frames, origins = [], []
    for k in range(T):
        fix = gnss.measure(ids, states[k], rng)
        frames.append(Frame(k, k * dt, ids, {"gnss": Batch(fix.z, fix.cov, fix.sensor, fix.subject)}))
        origins.append({"gnss": ids})
    prior_cov = np.repeat(np.diag([4.0, 4.0, 1.0, 1.0])[None], n, axis=0)
    setup = Setup(
        dt=dt, n_steps=T,
        vehicle_layout=StateLayout.position_velocity(2),
        vehicle_motion=ConstantVelocity(noise_density=2.0),
        vehicle_prior=StateSet(ids, states[0], prior_cov),
        sensors={"gnss": gnss},
        description=f"ring road: {n} vehicles on a {r:.0f} m circle at {params.speed} m/s",
    )
    return Recording(setup, frames, Truth.always_present(ids, states, origins))


cooploc.register_scenario("ring", generate, [
    cooploc.Preset("ring", RingParams(), "4 vehicles on a 60 m ring road, GNSS 9 m²"),
])


def main() -> None:
    recording = cooploc.get_preset("ring").generate(np.random.default_rng(3))
    est = cooploc.make_estimator("gnss-kf", recording.setup, None, np.random.default_rng(4))
    estimates = cooploc.estimate(est, recording)
    path = np.array([e.vehicles.mean[:, :2] for e in estimates])       # (T, n, 2)

    fig, ax = pyplot().subplots(figsize=(5, 5))
    truth = recording.truth.vehicle_states
    for i in range(truth.shape[1]):
        ax.plot(truth[:, i, 0], truth[:, i, 1], "k-", lw=1, label="truth" if i == 0 else None)
        ax.plot(path[:, i, 0], path[:, i, 1], "-", lw=0.8, color=f"C{i}",
                label="gnss-kf" if i == 0 else None)
    fixes = np.concatenate([f.batches["gnss"].z for f in recording.frames])
    ax.plot(fixes[:, 0], fixes[:, 1], ".", ms=1.5, color="0.6", label="GNSS fixes", zorder=0)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="center")
    fig.tight_layout()

    # the registered preset runs like any built-in one
    config = cooploc.ExperimentConfig.build("ring", ["gnss-kf"], runs=3, seed=1, backend="serial")
    summary = cooploc.summarize(cooploc.run_experiment(config))
    rmse = summary["estimators"]["gnss-kf"]["vehicle_rmse"]
    print("gnss-kf RMSE per vehicle:", ", ".join(f"{vid}: {value:.2f} m" for vid, value in rmse.items()))


if __name__ == "__main__":
    main()
