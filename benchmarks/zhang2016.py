"""Benchmarks of the Zhang 2016 family: `sme-pf` against its particle count, `gm-phd` against Stone Soup.

    python benchmarks/zhang2016.py                    # full sizes, JSON in benchmarks/results/
    python benchmarks/zhang2016.py --quick            # tiny sizes, to check the script
    python benchmarks/zhang2016.py --only particles   # one section

Sections (all on `zhang2016-cv`, seeds fixed, time inside `step` only):

- ``particles``: `sme-pf` total error (eq. 20, after optimal assignment) and ms per step
  for n_particles in PARTICLES, over `--runs` runs each (mean and standard error).
  This curve is how the default `n_particles` was chosen.
- ``gm_phd``: µs per step of `gm-phd` and of Stone Soup's GM-PHD (its
  `PointProcessUpdater`/`GaussianMixtureReducer` pipeline with the same models) on the
  same recording (5 targets); Stone Soup is optional here (skipped if not installed).
- ``memory``: peak traced memory (tracemalloc, separate pass) of each estimator.

Numbers depend on the machine and its load; the JSON records the environment of
`common.environment()` (versions, platform, CPU count, load average at start and end).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, run_steps, step_memory, write_json

from cooploc.estimators import get_estimator
from cooploc.metrics import set_errors

PARTICLES = (250, 500, 1000, 2000, 4000)
ESTIMATORS = ("sme-pf", "sme-ukf", "gm-phd", "kf-known-da")


def _recording(seed: int, n_steps: int | None = None):
    return recording("zhang2016-cv", seed, None if n_steps is None else {"n_steps": n_steps})


def _run(name: str, rec, params=None, seed: int = 0) -> tuple[float, float]:
    """(total error of eq. 20, seconds inside step) of one run."""
    spent, estimates = run_steps(new_estimator(name, rec, params, seed), rec.frames)
    true = (rec.truth.vehicle_states[frame.k][:, :2] for frame in rec.frames)
    sq = [np.sum(set_errors(e.vehicles.mean[:, :2], t) ** 2) for e, t in zip(estimates, true, strict=True)]
    return float(np.sqrt(np.mean(sq))), spent


def particle_curve(runs: int, n_steps: int | None, counts=PARTICLES) -> dict:
    cls = get_estimator("sme-pf")
    out = {"n_particles": list(counts), "total_rmse_mean": [], "total_rmse_se": [],
           "ms_per_step": [], "runs": runs}
    for count in counts:
        params = cls.Params().with_overrides({"n_particles": count})
        totals, seconds, steps = [], 0.0, 0
        for r in range(runs):
            rec = _recording(1000 + r, n_steps)
            total, spent = _run("sme-pf", rec, params, seed=r)
            totals.append(total)
            seconds += spent
            steps += len(rec.frames)
        out["total_rmse_mean"].append(float(np.mean(totals)))
        out["total_rmse_se"].append(float(np.std(totals, ddof=1) / np.sqrt(runs)) if runs > 1 else None)
        out["ms_per_step"].append(1e3 * seconds / steps)
        print(f"sme-pf n_particles={count}: total error {np.mean(totals):.3f} m, "
              f"{1e3 * seconds / steps:.1f} ms/step", file=sys.stderr)
    return out


def gm_phd_timing(n_steps: int | None, repeats: int) -> dict:
    rec = _recording(7, n_steps)
    best = min(_run("gm-phd", rec, seed=r)[1] for r in range(repeats))
    out = {"targets": int(rec.truth.vehicle_ids.size), "steps": len(rec.frames),
           "gm_phd_us_per_step": 1e6 * best / len(rec.frames)}
    try:
        import stonesoup  # noqa: F401
    except ImportError:
        return out
    # the reference's one home is the tests folder (Stone Soup is a test dependency)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from stonesoup_reference import stonesoup_reference

    seconds = min(stonesoup_reference(rec)[1] for _ in range(repeats))
    out["stonesoup_us_per_step"] = 1e6 * seconds / len(rec.frames)
    return out


def memory(n_steps: int | None) -> dict:
    rec = _recording(3, n_steps)
    out = {}
    for name in ESTIMATORS:
        est = new_estimator(name, rec)
        est.step(rec.frames[0])  # compile / warm up outside the trace
        out[name] = step_memory(est, rec.frames[1:])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (checks the script)")
    parser.add_argument("--runs", type=int, default=10, help="runs per particle count")
    parser.add_argument("--only", choices=("particles", "gm_phd", "memory"), default=None)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "zhang2016.json")
    args = parser.parse_args(argv)
    n_steps = 12 if args.quick else None
    runs = 2 if args.quick else args.runs
    counts = (100, 200) if args.quick else PARTICLES
    data: dict = {**environment(), "quick": args.quick}
    if args.only in (None, "particles"):
        data["sme_pf_particles"] = particle_curve(runs, n_steps, counts)
    if args.only in (None, "gm_phd"):
        data["gm_phd"] = gm_phd_timing(n_steps, 1 if args.quick else 3)
    if args.only in (None, "memory"):
        data["peak_memory_bytes"] = memory(n_steps)
    write_json(data, args.out)
    print(json.dumps(data, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
