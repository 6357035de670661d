"""A first run: GNSS alone against the known-association bound.

Simulate one run of the Fröhle 2018 scenario (two vehicles, three crossing features),
run the GNSS-only Kalman filter (`gnss-kf`) and the joint Kalman filter that is told the
true association (`oracle-kf`, the accuracy bound), and plot each vehicle's position
error over time. This is `cooploc run froehle2018 -e gnss-kf -e oracle-kf --runs 1`
step by step through the Python API.
"""

import numpy as np

import cooploc
from cooploc.metrics import VEHICLE
from cooploc.plots import pyplot


def main() -> None:
    preset = cooploc.get_preset("froehle2018")
    params = preset.params.with_overrides({"n_steps": 200})
    recording = preset.generate(np.random.default_rng(1), params)
    print(recording.setup.description)

    fig, axes = pyplot().subplots(1, 2, figsize=(9, 3.4), sharey=True)
    for i, name in enumerate(["gnss-kf", "oracle-kf"]):
        # every estimator gets its own generator; the known-association bound also
        # receives the true origins of the rows (never the true states)
        truth = recording.truth if cooploc.get_estimator(name).needs_truth else None
        est = cooploc.make_estimator(name, recording.setup, None, np.random.default_rng(2 + i),
                                     truth=truth)
        errors = cooploc.evaluate(recording, cooploc.estimate(est, recording))
        for ax, vid in zip(axes, (0, 1), strict=True):
            rows = (errors.kind == VEHICLE) & (errors.id == vid)
            ax.plot(errors.t[rows], errors.err_pos[rows], label=name,
                    linestyle="--" if name == "oracle-kf" else "-")
            ax.set_title(f"vehicle {vid}")
            ax.set_xlabel("t [s]")
            print(f"{name:>10}: vehicle {vid} RMSE {cooploc.rmse(errors.err_pos[rows]):.3f} m")
    axes[0].set_ylabel("position error [m]")
    axes[0].set_yscale("log")
    axes[1].legend()
    fig.tight_layout()


if __name__ == "__main__":
    main()
