"""Benchmarks of the Zhang 2016 family: `sme-pf` against its particle count, `gm-phd` against Stone Soup.

    python benchmarks/zhang2016.py                    # full sizes, JSON in benchmarks/results/
    python benchmarks/zhang2016.py --quick            # tiny sizes, to check the script
    python benchmarks/zhang2016.py --only particles   # one section

Sections (all on `zhang2016-cv`, seeds fixed, time inside `step` only):

- ``particles``: `sme-pf` total error (eq. 20, after optimal assignment), ms per step and
  steps per second for n_particles in PARTICLES, over `--runs` runs each (mean and
  standard error), for each proposal (``sme_pf_particles``: the default linearized one;
  ``sme_pf_particles_bootstrap``: drawing from the motion model), beside `kf-known-da` on
  the same recordings (its total error, the paired mean difference sme-pf − kf-known-da
  with its standard error, and its ms per step: the reference the times are relative to).
  These curves are how the default `n_particles` and `proposal` were chosen.
- ``gm_phd``: µs per step of `gm-phd` and of Stone Soup's GM-PHD (its
  `PointProcessUpdater`/`GaussianMixtureReducer` pipeline with the same models) on the
  same recording (5 targets); Stone Soup is optional here (skipped if not installed).
- ``memory``: peak traced memory (tracemalloc, separate pass) of each estimator, and of
  `sme-pf` with the bootstrap proposal.

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

PARTICLES = (500, 1000, 2000, 4000, 8000)
PROPOSALS = ("linearized", "bootstrap")
ESTIMATORS = ("sme-pf", "sme-ukf", "gm-phd", "kf-known-da")


def _recording(seed: int, n_steps: int | None = None):
    return recording("zhang2016-cv", seed, None if n_steps is None else {"n_steps": n_steps})


def _run(name: str, rec, params=None, seed: int = 0) -> tuple[float, float]:
    """(total error of eq. 20, seconds inside step) of one run."""
    spent, estimates = run_steps(new_estimator(name, rec, params, seed), rec.frames)
    true = (rec.truth.vehicle_states[frame.k][:, :2] for frame in rec.frames)
    sq = [np.sum(set_errors(e.vehicles.mean[:, :2], t) ** 2) for e, t in zip(estimates, true, strict=True)]
    return float(np.sqrt(np.mean(sq))), spent


def _se(values: list[float]) -> float | None:
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else None


def particle_curve(runs: int, n_steps: int | None, counts=PARTICLES, proposal: str = "linearized") -> dict:
    cls = get_estimator("sme-pf")
    recordings = [_recording(1000 + r, n_steps) for r in range(runs)]
    reference = [_run("kf-known-da", rec, seed=r) for r, rec in enumerate(recordings)]
    kf_totals = [total for total, _ in reference]
    kf_ms = 1e3 * sum(spent for _, spent in reference) / sum(len(rec.frames) for rec in recordings)
    out = {"proposal": proposal, "n_particles": list(counts), "total_rmse_mean": [], "total_rmse_se": [],
           "minus_kf_mean": [], "minus_kf_se": [], "ms_per_step": [], "steps_per_second": [],
           "ms_per_step_over_kf": [], "runs": runs, "kf_known_da_total_rmse_mean": float(np.mean(kf_totals)),
           "kf_known_da_ms_per_step": kf_ms}
    for count in counts:
        params = cls.Params().with_overrides({"n_particles": count, "proposal": proposal})
        totals, seconds, steps = [], 0.0, 0
        for r, rec in enumerate(recordings):
            total, spent = _run("sme-pf", rec, params, seed=r)
            totals.append(total)
            seconds += spent
            steps += len(rec.frames)
        difference = list(np.asarray(totals) - np.asarray(kf_totals))
        ms = 1e3 * seconds / steps
        out["total_rmse_mean"].append(float(np.mean(totals)))
        out["total_rmse_se"].append(_se(totals))
        out["minus_kf_mean"].append(float(np.mean(difference)))
        out["minus_kf_se"].append(_se(difference))
        out["ms_per_step"].append(ms)
        out["steps_per_second"].append(1e3 / ms)
        out["ms_per_step_over_kf"].append(ms / kf_ms)
        print(f"sme-pf {proposal} n_particles={count}: total error {np.mean(totals):.3f} m "
              f"(kf-known-da {np.mean(kf_totals):.3f} m), {ms:.1f} ms/step", file=sys.stderr)
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
    bootstrap = get_estimator("sme-pf").Params().with_overrides({"proposal": "bootstrap"})
    runs = [*((n, n, None) for n in ESTIMATORS), ("sme-pf bootstrap", "sme-pf", bootstrap)]
    for label, name, params in runs:
        est = new_estimator(name, rec, params)
        est.step(rec.frames[0])  # compile / warm up outside the trace
        out[label] = step_memory(est, rec.frames[1:])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (checks the script)")
    parser.add_argument("--runs", type=int, default=10, help="runs per particle count")
    parser.add_argument("--only", choices=("particles", "gm_phd", "memory"), default=None)
    parser.add_argument("--particles", type=int, nargs="*", default=None,
                        help=f"particle counts of the curve (default {PARTICLES})")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "zhang2016.json")
    args = parser.parse_args(argv)
    n_steps = 12 if args.quick else None
    runs = 2 if args.quick else args.runs
    counts = (100, 200) if args.quick else tuple(args.particles or PARTICLES)
    data: dict = {**environment(), "quick": args.quick}
    if args.only in (None, "particles"):
        data["sme_pf_particles"] = particle_curve(runs, n_steps, counts, "linearized")
        data["sme_pf_particles_bootstrap"] = particle_curve(runs, n_steps, counts, "bootstrap")
    if args.only in (None, "gm_phd"):
        data["gm_phd"] = gm_phd_timing(n_steps, 1 if args.quick else 3)
    if args.only in (None, "memory"):
        data["peak_memory_bytes"] = memory(n_steps)
    write_json(data, args.out)
    print(json.dumps(data, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
