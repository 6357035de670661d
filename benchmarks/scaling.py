"""Time per step against the number of vehicles, with the growth exponent; JSON and a log–log figure.

    python benchmarks/scaling.py                                  # 100 … 5000 vehicles, four estimators
    python benchmarks/scaling.py --sizes 100 200 400 -e gnss-kf -e oracle-kf --cap 60
    python benchmarks/scaling.py --quick --out s.json             # tiny sizes, to check the script

For each number of vehicles N (`--sizes`) one `brambilla-crossroad` recording with
`n_vehicles = N` (`--set key=value` overrides more fields; 32 steps by default) is
generated, and each estimator (`-e`, default gnss-kf, oracle-kf, icp-da-lc, rsu-bp)
steps through it with cooploc's own timer (`experiment.StepTimer`: time inside `step`
only). Recorded per cell: seconds per step, the steps timed and whether the cell hit
the cap; per N the seconds taken to generate the recording (not part of any
estimator's time).

`--cap` bounds one cell: an estimator is stepped in chunks of a few frames and stops
once its cell has taken `--cap` seconds (its time per step is then the mean over the
steps it took); it is not run at any larger N, since it would only be slower.

The growth exponent of each estimator is the slope of the least-squares line through
(log N, log seconds per step) over the cells it completed or capped: 1 is linear in
the number of vehicles, 3 is cubic. The figure (`--figure`, default the JSON path with
`.png`) shows the cells and the fitted lines on log–log axes.

The machine may be shared: the load average at the start and end of the script and
before each cell is recorded (`common.environment()`); a loaded 2-core machine gives
lower bounds of the speed, and estimators measured at different times saw different
loads.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, write_json

from cooploc.experiment import StepTimer, estimate
from cooploc.types import Recording

PRESET = "brambilla-crossroad"
SIZES = (100, 200, 400, 800, 1000, 2000, 5000)
ESTIMATORS = ("gnss-kf", "oracle-kf", "icp-da-lc", "rsu-bp")
CAP_SECONDS = 120.0
CHUNK_STEPS = 4     # frames stepped between two looks at the cap
TEN_HZ = 0.1        # seconds per step of a 10 Hz real-time estimator (issue 17's target line)


def time_cell(name: str, rec: Recording, cap: float, seed: int = 0) -> dict[str, Any]:
    """Seconds per step of estimator `name` on `rec`, stopping once `cap` seconds are spent."""
    est = new_estimator(name, rec, seed=seed)
    timer = StepTimer()
    frames = rec.frames
    for start in range(0, len(frames), CHUNK_STEPS):
        estimate(est, frames[start:start + CHUNK_STEPS], smooth=False, timer=timer)
        if timer.seconds > cap:
            break
    return {"seconds_per_step": timer.seconds / timer.steps, "steps": timer.steps,
            "capped": timer.steps < len(frames), "load_average": _load()}


def growth_exponent(sizes: list[int], seconds: list[float]) -> float | None:
    """Slope of log(seconds) against log(N), least squares; None with fewer than two sizes."""
    if len(sizes) < 2:
        return None
    slope, _ = np.polyfit(np.log(sizes), np.log(seconds), 1)
    return float(slope)


def _load() -> float | None:
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else None


def warm_up(names: list[str], overrides: dict[str, Any], seed: int) -> None:
    """Step each estimator through two frames of a small run: imports, numba compilation and
    first calls stay out of the cells."""
    rec = recording(PRESET, seed, {**overrides, "n_vehicles": 8, "n_steps": 2})
    for name in names:
        estimate(new_estimator(name, rec, seed=seed), rec, smooth=False)


def run(sizes: list[int], names: list[str], cap: float, overrides: dict[str, Any], seed: int
        ) -> dict[str, Any]:
    """The table {estimator: {N: cell}}, the generation seconds per N, and the exponents."""
    warm_up(names, overrides, seed)
    cells: dict[str, dict[int, dict[str, Any]]] = {name: {} for name in names}
    generation: dict[int, float] = {}
    growing = set(names)
    for n in sorted(sizes):
        if not growing:
            break
        start = time.perf_counter()
        rec = recording(PRESET, seed, {**overrides, "n_vehicles": n})
        generation[n] = time.perf_counter() - start
        print(f"N = {n}: generated in {generation[n]:.1f} s")
        for name in names:
            if name not in growing:
                continue
            cells[name][n] = cell = time_cell(name, rec, cap, seed)
            print(f"  {name}: {cell['seconds_per_step'] * 1e3:.1f} ms/step over {cell['steps']} steps"
                  + (" (capped: not run at larger N)" if cell["capped"] else ""))
            if cell["capped"]:
                growing.discard(name)
    exponents = {}
    for name, by_n in cells.items():
        ns = sorted(by_n)
        exponents[name] = growth_exponent(ns, [by_n[n]["seconds_per_step"] for n in ns])
    return {"cells": {name: {str(n): c for n, c in by_n.items()} for name, by_n in cells.items()},
            "generation_seconds": {str(n): s for n, s in generation.items()},
            "growth_exponent": exponents}


def plot(results: dict[str, Any], path: Path) -> None:
    """Seconds per step against vehicles, log–log, one line per estimator with its fit."""
    from cooploc.plots import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for i, (name, by_n) in enumerate(results["cells"].items()):
        if not by_n:
            continue
        ns = np.array(sorted(int(n) for n in by_n))
        secs = np.array([by_n[str(n)]["seconds_per_step"] for n in ns])
        slope = results["growth_exponent"][name]
        label = name + (f" (slope {slope:.2f})" if slope is not None else "")
        ax.loglog(ns, secs, "o-", color=f"C{i}", label=label)
        capped = np.array([by_n[str(n)]["capped"] for n in ns])
        if capped.any():
            ax.loglog(ns[capped], secs[capped], "x", color=f"C{i}", markersize=10)
        if slope is not None:
            fit = np.polyfit(np.log(ns), np.log(secs), 1)
            ax.loglog(ns, np.exp(np.polyval(fit, np.log(ns))), ":", color=f"C{i}", linewidth=1)
    ax.axhline(TEN_HZ, color="0.5", linestyle="--", linewidth=1)
    ax.text(ax.get_xlim()[0], TEN_HZ, " 0.1 s: real time at 10 Hz", va="bottom", fontsize=8, color="0.4")
    ax.set_xlabel("vehicles (brambilla-crossroad, n_vehicles)")
    ax.set_ylabel("seconds per step (inside step)")
    ax.set_title(f"Time per step against vehicles (load {results['environment']['load_average']:.1f}, "
                 f"{results['environment']['cpu_count']} CPUs; × = capped)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"written {path}")


def _parse_set(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, _, value = item.partition("=")
        for cast in (int, float):
            try:
                out[key] = cast(value)
                break
            except ValueError:
                continue
        else:
            out[key] = value
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "scaling.json")
    parser.add_argument("--figure", type=Path, default=None, help="default: --out with .png")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="numbers of vehicles")
    parser.add_argument("-e", "--estimator", action="append", dest="estimators",
                        help=f"repeatable; default {', '.join(ESTIMATORS)}")
    parser.add_argument("--cap", type=float, default=CAP_SECONDS,
                        help="seconds one cell may take; a capped estimator is not run at larger N")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help=f"override a {PRESET} parameter (n_steps, n_features, ...)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="tiny sizes: check that the script runs")
    args = parser.parse_args(argv)
    names = args.estimators or list(ESTIMATORS)
    sizes, overrides, cap = args.sizes, _parse_set(args.set), args.cap
    if args.quick:
        sizes, cap = [8, 16], min(cap, 20.0)
        overrides.setdefault("n_steps", 6)
    results: dict[str, Any] = {
        "environment": environment(), "preset": PRESET, "overrides": overrides, "sizes": sizes,
        "estimators": names, "cap_seconds": cap, "seed": args.seed,
    }
    results.update(run(sizes, names, cap, overrides, args.seed))
    write_json(results, args.out)
    plot(results, args.figure or args.out.with_suffix(".png"))


if __name__ == "__main__":
    main()
