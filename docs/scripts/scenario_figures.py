"""Draw one run of a preset of every scenario family: `python scenario_figures.py OUT`.

Run by `gen_pages.py` when the site is built; writes `OUT/<preset>.png` for each
preset in `FIGURES` (true vehicle paths, features, infrastructure sensors, and the V2V
links of the first step). SUMO presets need the `sumo` extra; without it their figure
says so, and `OUT/missing.txt` names them.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import cooploc
from cooploc.plots import pyplot

#: preset → the overrides that keep the picture readable and the build fast
FIGURES: dict[str, dict[str, object]] = {
    "froehle2018": {},
    "brambilla-road": {},
    "brambilla-crossroad": {},
    "zhang2016-ct4": {},
    "gulati-4v": {},
    "aoa-grid": {},
    "aoa-manhattan": {},
    "sumo-berlin-tlr": {"duration": 60.0},
}


def draw(name: str, overrides: dict[str, object], out: Path) -> None:
    preset = cooploc.get_preset(name)
    recording = preset.generate(np.random.default_rng(1), preset.params.with_overrides(overrides))
    truth, setup = recording.truth, recording.setup
    pos = setup.vehicle_layout.position
    fig, ax = pyplot().subplots(figsize=(6.4, 4.8))
    many = truth.vehicle_ids.size > 30
    for i in range(truth.vehicle_ids.size):
        where = truth.vehicle_present[:, i]
        xy = truth.vehicle_states[where, i][:, list(pos)]
        if xy.shape[0] == 0:
            continue
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.6 if many else 1.4, color="C0" if many else f"C{i % 10}",
                alpha=0.6 if many else 1.0)
        ax.plot(*xy[0], "o", ms=2 if many else 4, color="C0" if many else f"C{i % 10}")
    if truth.feature_ids.size:
        fpos = setup.feature_layout.position if setup.feature_layout is not None else (0, 1)
        for j in range(truth.feature_ids.size):
            where = truth.feature_present[:, j]
            xy = truth.feature_states[where, j][:, list(fpos)]
            if xy.shape[0] == 0:
                continue
            moving = np.ptp(xy, axis=0).max() > 0.5
            if moving:
                ax.plot(xy[:, 0], xy[:, 1], ":", color="0.35", lw=1.0)
            ax.plot(*xy[0], "s", ms=3, color="0.35")
    if truth.sensor_poses.size:
        ax.plot(truth.sensor_poses[:, 0], truth.sensor_poses[:, 1], "^", ms=9, color="C3")
    first = recording.frames[0]
    if first.links.size and truth.vehicle_ids.size <= 80:
        at0 = {int(v): truth.vehicle_states[0, i][list(pos)]
               for i, v in enumerate(truth.vehicle_ids) if truth.vehicle_present[0, i]}
        for a, b in first.links.tolist():
            if a in at0 and b in at0:
                ax.plot(*np.array([at0[a], at0[b]]).T, "-", color="C2", lw=0.4, alpha=0.3, zorder=0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    span = "a snapshot" if setup.n_steps == 1 else f"{setup.n_steps} steps of {setup.dt:g} s"
    ax.set_title(f"{name}: {truth.vehicle_ids.size} vehicles, {span}", fontsize=10)
    # a legend of what the marks mean, with proxies (one per kind shown)
    handles = [ax.plot([], [], "-", color="C0", label="vehicle paths (dot: start)")[0]]
    if truth.feature_ids.size:
        handles.append(ax.plot([], [], "s", ms=3, color="0.35", label="features (dotted: moving)")[0])
    if truth.sensor_poses.size:
        handles.append(ax.plot([], [], "^", color="C3", label="infrastructure sensor")[0])
    if first.links.size:
        handles.append(ax.plot([], [], "-", color="C2", label="V2V links at step 0")[0])
    ax.legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(out / f"{name}.png", dpi=90)
    pyplot().close(fig)


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    missing = []
    for name, overrides in FIGURES.items():
        try:
            draw(name, overrides, out)
        except ImportError as exc:          # the sumo extra is not installed
            missing.append(f"{name}: {exc}")
            fig, ax = pyplot().subplots(figsize=(6.4, 1.5))
            ax.axis("off")
            ax.text(0.5, 0.5, f"{name}: this site was built without the sumo extra\n"
                    "(pip install -e '.[sumo,docs]' draws this figure)", ha="center", va="center")
            fig.savefig(out / f"{name}.png", dpi=90)
            pyplot().close(fig)
    (out / "missing.txt").write_text("\n".join(missing))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
