"""How `summarize` and the merge of a results folder grow with the number of runs (issue 17 item 5).

    python benchmarks/summarize.py            # 250 … 4000 runs → benchmarks/results/summarize.json
    python benchmarks/summarize.py --quick    # tiny sizes, to check the script

The runs are fabricated: one real run of gnss-kf on froehle2018 (`--steps` steps), copied with
its position errors scaled by a random factor per row, numbered 0 … R − 1 (what `summarize`
costs depends on the rows, not on how they were made). For each R: the seconds of
`summarize`, its peak traced memory (a pass of its own), the seconds of `merge_runs` over R
run parts written beforehand (reading the parts, summary, errors.parquet, figures), the
seconds of the per-vehicle per-run RMSE as `summarize` computes them (rows grouped by
vehicle and run in one sort) and, as the reference measured in the same process, the same
numbers by the masking that `summarize` did before (one boolean mask over every row per
vehicle and run; quadratic in runs). The growth exponent is the slope of a least-squares
line through log(seconds) against log(R): 1 is linear.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, peak_memory, write_json

from cooploc.experiment import ExperimentConfig, ExperimentResult, run_one
from cooploc.metrics import VEHICLE, rmse


def study(runs: int, steps: int) -> ExperimentConfig:
    """The configuration whose runs `fabricated` makes."""
    return ExperimentConfig.build("froehle2018", ["gnss-kf"], scenario_overrides={"n_steps": steps},
                                  runs=runs, seed=1, backend="serial")


def fabricated(config: ExperimentConfig, seed: int = 0) -> ExperimentResult:
    """`config.runs` runs: run 0 of `config` with each row's errors scaled by a random factor."""
    base = run_one(config, 0, keep_estimates=False)
    rng = np.random.default_rng(seed)
    runs = []
    for r in range(config.runs):
        errors = {name: dataclasses.replace(table, err_pos=table.err_pos * rng.uniform(0.5, 1.5, len(table)))
                  for name, table in base.errors.items()}
        runs.append(dataclasses.replace(base, run=r, errors=errors))
    return ExperimentResult(config, tuple(runs))


def masked_per_run(result: ExperimentResult, name: str) -> dict[str, list[float]]:
    """The reference: per-run RMSE by one mask over every row per vehicle and run."""
    run, table = result.errors(name)
    vehicles = table.kind == VEHICLE
    out = {}
    for vid in np.unique(table.id[vehicles]):
        rows = vehicles & (table.id == vid)
        out[str(int(vid))] = [rmse(table.err_pos[rows & (run == r.run)]) for r in result.runs]
    return out


def grouped_per_run(result: ExperimentResult, name: str) -> dict[str, list[float | None]]:
    """What `summarize` does now for the same numbers: rows grouped by (vehicle, run) once."""
    from cooploc.results import _diverged, _per_run_rmse

    run, table = result.errors(name)
    return _per_run_rmse(run, table, _diverged(table.err_pos), table.kind == VEHICLE,
                         [r.run for r in result.runs])


def _seconds(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _merge(config, merge_runs, write_run, write_config, result=None) -> float:
    """Seconds of `merge_runs` over the parts of `result` (default: fabricated) in a new folder."""
    result = result or fabricated(config)
    folder = Path(tempfile.mkdtemp())
    try:
        for run in result.runs:
            write_run(run, config, folder)
        write_config(config, folder)
        start = time.perf_counter()
        merge_runs(folder, config)
        return time.perf_counter() - start
    finally:
        shutil.rmtree(folder)


def _exponent(sizes: list[int], seconds: list[float]) -> float:
    return float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0])


def main(argv: list[str] | None = None) -> int:
    from cooploc.results import _write_config, merge_runs, summarize, write_run

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, nargs="+", default=[250, 500, 1000, 2000, 4000])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--reference-up-to", type=int, default=2000,
                        help="largest R at which the quadratic reference is timed")
    parser.add_argument("--skip-merge", action="store_true",
                        help="time summarize alone (the merge writes and reads R files per size)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, to check the script")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "summarize.json")
    args = parser.parse_args(argv)
    sizes, steps, repeats = ([20, 40], 10, 1) if args.quick else (args.runs, args.steps, args.repeats)
    if not args.skip_merge:
        _merge(study(2, steps), merge_runs, write_run, _write_config)  # imports (matplotlib…) not timed
    rows = []
    for runs in sizes:
        config = study(runs, steps)
        result = fabricated(config)
        row = {"runs": runs, "rows": sum(len(r.errors["gnss-kf"]) for r in result.runs),
               "summarize_seconds": _seconds(lambda: summarize(result), repeats),  # noqa: B023
               "summarize_peak_bytes": peak_memory(lambda: summarize(result))}  # noqa: B023
        row["grouped_per_run_seconds"] = _seconds(lambda: grouped_per_run(result, "gnss-kf"),  # noqa: B023
                                                  repeats)
        if runs <= args.reference_up_to:
            row["masked_per_run_seconds"] = _seconds(lambda: masked_per_run(result, "gnss-kf"),  # noqa: B023
                                                     repeats)
        if not args.skip_merge:
            row["merge_seconds"] = _merge(config, merge_runs, write_run, _write_config, result)
        rows.append(row)
        reference = row.get("masked_per_run_seconds")
        merge = f"merge {row['merge_seconds']:.2f} s, " if "merge_seconds" in row else ""
        print(f"{runs:6d} runs: summarize {row['summarize_seconds']:.3f} s, "
              f"{merge}per-run RMSE {row['grouped_per_run_seconds']:.3f} s"
              + (f", masking reference {reference:.3f} s" if reference is not None else ""))
    results = {**environment(), "steps": steps, "repeats": repeats, "sizes": rows}
    if len(rows) > 1:
        ref = [r for r in rows if "masked_per_run_seconds" in r]
        results["exponent"] = {
            "summarize": _exponent([r["runs"] for r in rows], [r["summarize_seconds"] for r in rows]),
            "merge": None if args.skip_merge else _exponent([r["runs"] for r in rows],
                                                              [r["merge_seconds"] for r in rows]),
            "grouped_per_run": _exponent([r["runs"] for r in rows], [r["grouped_per_run_seconds"]
                                                                     for r in rows]),
            "masked_per_run_reference": _exponent([r["runs"] for r in ref], [r["masked_per_run_seconds"]
                                                                             for r in ref])
            if len(ref) > 1 else None,
        }
        print("growth exponents:", results["exponent"])
    write_json(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
