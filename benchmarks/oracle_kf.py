"""Benchmark `oracle-kf`: the component form against the dense joint filter; write JSON.

    python benchmarks/oracle_kf.py                        # paper presets, SUMO presets, city case
    python benchmarks/oracle_kf.py --quick --out b.json   # tiny sizes, to check the script
    python benchmarks/oracle_kf.py --presets sumo-braunschweig-tlr --dense-steps 100
    python benchmarks/oracle_kf.py --presets --tiles 0 --odometry sumo-grid-tlr --duration 60
    python benchmarks/oracle_kf.py --presets sumo-braunschweig-tlr --dense-steps 0 --tiles 0 \
        --odometry --baseline fa406aa                     # against the component form of a commit

Measured in one process, on the same recordings (time inside `step` only):

1. Per preset: steps per second of the component form (the default) over the whole
   run, and of both forms over the first `--dense-steps` steps (the dense form takes
   minutes on a full SUMO run; its state grows over the run, so the prefix ratio is a
   lower bound of the whole-run ratio); the largest difference between the two forms
   over the prefix, absolute and relative to each belief's scale (its largest |entry|);
   the size of the largest component at the end.
2. The city case: `--tiles` independent copies of `brambilla-crossroad` (12 vehicles,
   24 features each: 84 tiles make 1008 vehicles and 2016 features), side by side
   with ids shifted, one recording. Vehicles couple only through the features they
   observe together, so the components stay one crossroad each; the time per step of
   the component form is the `≤ 0.1 s with 1000 vehicles and 2000 features` case. The
   dense form is not run there (D = 12 096 states: a 1.2 GB covariance and ~10¹² flops
   a step).
3. Odometry (`--odometry`, SUMO presets): the same traffic and rows with and without
   ``odometry=true`` (the odometry rows have a random stream of their own, so every other
   row is the same), the component form run on both alternately `--repeats` times:
   steps per second of each (the fastest repeat) and their ratio, which stochastic
   cloning costs; the largest difference between the two forms with odometry over the
   first `--dense-steps` steps.

4. Against a baseline (`--baseline REV`, per preset): the component form of git revision
   REV (its `oracle_kf/components.py`, loaded from `git show` beside the current one;
   every other module is the current one) and the current one, stepped side by side
   on the same recording in one process, frame by frame, `--repeats` times: steps per
   second of each (the fastest repeat), their time ratio (the median over repeats, wall
   clock and CPU time), and the largest difference between the two (relative, as in 1.).

Every pass runs with `--threads` BLAS threads (default 1, `backends.limit_threads`), as
the workers of `cooploc run` run an estimator: on a shared machine OpenBLAS threads that
spin for a busy core slow the many small factorisations of the city case about twofold.

The machine may be shared: the load average at the start and end is recorded with the
versions and platform (`common.environment()`); compare the ratios, which come from the
same process, more than the absolute numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, run_steps, write_json

from cooploc.backends import limit_threads
from cooploc.estimators.oracle_kf import OracleKFParams
from cooploc.types import Batch, Estimate, Frame, Recording, Truth

PAPER_PRESETS = ("froehle2018", "brambilla-crossroad")
SUMO_PRESETS = ("sumo-braunschweig-tlr", "sumo-braunschweig-vsr", "sumo-berlin-tlr",
                "sumo-berlin-vsr", "sumo-grid-tlr", "sumo-grid-vsr")
CITY_TILES = 84              # 84 × (12 vehicles, 24 features) = 1008 vehicles, 2016 features
STEPS_TARGET = {"sumo-braunschweig-tlr": 50.0}   # steps per second (issue 17)
CITY_TARGET_SECONDS = 0.1    # per step with 1000 vehicles and 2000 features (issue 17)


def forms_difference(sparse: list[Estimate], dense: list[Estimate]) -> dict[str, float]:
    """Largest |component − dense| over means and covariances, absolute and relative to
    each belief's scale."""
    absolute = relative = 0.0
    for a, b in zip(sparse, dense, strict=True):
        for part in ("vehicles", "features"):
            x, y = getattr(a, part), getattr(b, part)
            if x is None or not len(y):
                continue
            for u, v in ((x.mean, y.mean), (x.cov, y.cov)):
                d = np.abs(u - v).reshape(len(y), -1).max(axis=1)
                absolute = max(absolute, float(d.max()))
                relative = max(relative, float((d / np.abs(v).reshape(len(y), -1).max(axis=1)).max()))
    return {"max_abs_difference": absolute, "max_rel_difference": relative}


def largest_component(est) -> dict[str, int]:
    """Entities and states of the largest component of an `oracle-kf` in component form."""
    components = est._filter.components
    if not components:
        return {"entities": 1 if len(est._filter.alone_ids) else 0, "states": 0}
    c = max(components, key=lambda c: c.mean.size)
    return {"entities": int(c.ids.size), "states": int(c.mean.size), "components": len(components),
            "alone_vehicles": int(est._filter.alone_ids.size)}


def warm_up(rec: Recording) -> None:
    """Step both forms through two frames: imports and first calls stay out of the timings."""
    for dense in (False, True):
        run_steps(new_estimator("oracle-kf", rec, OracleKFParams(dense=dense)), rec.frames[:2])


def time_preset(name: str, seed: int, dense_steps: int, overrides: dict | None = None) -> dict:
    rec = recording(name, seed, overrides)
    warm_up(rec)
    est = new_estimator("oracle-kf", rec)
    seconds, _ = run_steps(est, rec.frames)
    n = len(rec.frames)
    out = {"steps": n, "seconds": seconds, "steps_per_second": n / seconds,
           "largest_component_at_end": largest_component(est)}
    prefix = rec.frames[:dense_steps]
    if prefix:
        t_sparse, sparse = run_steps(new_estimator("oracle-kf", rec), prefix)
        t_dense, dense = run_steps(new_estimator("oracle-kf", rec, OracleKFParams(dense=True)), prefix)
        out["prefix"] = {"steps": len(prefix), "components_steps_per_second": len(prefix) / t_sparse,
                         "dense_steps_per_second": len(prefix) / t_dense, "speedup": t_dense / t_sparse,
                         **forms_difference(sparse, dense)}
    if name in STEPS_TARGET:
        out["target_steps_per_second"] = STEPS_TARGET[name]
    print(f"{name}: {out['steps_per_second']:.1f} steps/s over {n} steps"
          + (f"; first {len(prefix)}: ×{out['prefix']['speedup']:.1f} against dense, "
             f"max rel difference {out['prefix']['max_rel_difference']:.2g}" if prefix else ""))
    return out


# -- odometry ------------------------------------------------------------------------


def time_odometry(name: str, seed: int, dense_steps: int, repeats: int,
                  overrides: dict | None = None) -> dict:
    """Steps per second of the component form with and without odometry on the same traffic."""
    from cooploc.scenarios.sumo import SumoNotInstalledError

    try:
        recs = {flag: recording(name, seed, {**(overrides or {}), "odometry": flag})
                for flag in (False, True)}
    except SumoNotInstalledError as exc:
        print(f"{name}: skipped ({exc})")
        return {"skipped": str(exc)}
    warm_up(recs[True])
    seconds: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(repeats):   # alternate, so that a change of load hits both alike
        for flag in (False, True):
            seconds[flag].append(run_steps(new_estimator("oracle-kf", recs[flag]), recs[flag].frames)[0])
    n = len(recs[True].frames)
    out = {"steps": n, "odometry_rows": int(sum(len(f.batches["odometry"]) for f in recs[True].frames)),
           "repeats": repeats, "seconds_without": seconds[False], "seconds_with": seconds[True],
           "steps_per_second_without": n / min(seconds[False]),
           "steps_per_second_with": n / min(seconds[True]),
           "time_ratio_with_to_without": min(seconds[True]) / min(seconds[False])}
    prefix = recs[True].frames[:dense_steps]
    if prefix:
        _, sparse = run_steps(new_estimator("oracle-kf", recs[True]), prefix)
        _, dense = run_steps(new_estimator("oracle-kf", recs[True], OracleKFParams(dense=True)), prefix)
        out["prefix"] = {"steps": len(prefix), **forms_difference(sparse, dense)}
    print(f"{name} odometry: {out['steps_per_second_with']:.1f} steps/s with, "
          f"{out['steps_per_second_without']:.1f} without (time ×{out['time_ratio_with_to_without']:.2f})"
          + (f"; max rel difference to dense {out['prefix']['max_rel_difference']:.2g}" if prefix else ""))
    return out


# -- against a baseline revision ---------------------------------------------------


def baseline_filter(rev: str):
    """The `ComponentFilter` class of `oracle_kf/components.py` at git revision `rev`."""
    import subprocess
    import types

    path = "src/cooploc/estimators/oracle_kf/components.py"
    source = subprocess.run(["git", "show", f"{rev}:{path}"], capture_output=True, text=True, check=True,
                            cwd=Path(__file__).resolve().parent.parent).stdout
    module = types.ModuleType(f"oracle_kf_components_{rev}")
    sys.modules[module.__name__] = module   # dataclasses look their module up
    exec(compile(source, f"{rev}:{path}", "exec"), module.__dict__)
    return module.ComponentFilter


def time_baseline(name: str, seed: int, rev: str, repeats: int, overrides: dict | None = None) -> dict:
    """Steps per second of the component form at `rev` and now, stepped side by side.

    Each repeat runs both filters over the recording at once, frame by frame, which of
    them steps first alternating: a change of the machine's speed (it moves ±20 % over
    seconds on a shared machine) then meets both alike, where whole runs one after the
    other can land in different phases and show a ratio of the phases, not of the code.
    """
    import time

    rec = recording(name, seed, overrides)
    Baseline = baseline_filter(rev)

    def make(which: str):
        est = new_estimator("oracle-kf", rec)
        if which == "baseline":
            f = est._filter
            est._filter = Baseline(f.setup, f.params, f.truth)
        return est

    for which in ("baseline", "current"):
        run_steps(make(which), rec.frames[:2])
    n = len(rec.frames)
    wall = {"baseline": np.zeros((repeats, n)), "current": np.zeros((repeats, n))}
    cpu = {"baseline": np.zeros((repeats, n)), "current": np.zeros((repeats, n))}
    estimates: dict[str, list[Estimate]] = {}
    for r in range(repeats):
        ests = {which: make(which) for which in wall}
        estimates = {which: [] for which in wall}
        for k, frame in enumerate(rec.frames):
            for which in (("baseline", "current") if (r + k) % 2 == 0 else ("current", "baseline")):
                start, start_cpu = time.perf_counter(), time.process_time()
                estimates[which].append(ests[which].step(frame))
                wall[which][r, k] = time.perf_counter() - start
                cpu[which][r, k] = time.process_time() - start_cpu
    seconds = {which: wall[which].sum(axis=1) for which in wall}
    cpu_seconds = {which: cpu[which].sum(axis=1) for which in cpu}
    out = {"steps": n, "baseline": rev, "repeats": repeats, "interleaved": "step by step",
           "seconds": {w: v.tolist() for w, v in seconds.items()},
           "cpu_seconds": {w: v.tolist() for w, v in cpu_seconds.items()},
           "baseline_steps_per_second": n / seconds["baseline"].min(),
           "current_steps_per_second": n / seconds["current"].min(),
           "speedup": float(np.median(seconds["baseline"] / seconds["current"])),
           "cpu_speedup": float(np.median(cpu_seconds["baseline"] / cpu_seconds["current"])),
           **forms_difference(estimates["current"], estimates["baseline"])}
    print(f"{name} against {rev}: {out['current_steps_per_second']:.1f} steps/s, "
          f"{rev} {out['baseline_steps_per_second']:.1f} (×{out['speedup']:.2f} wall, "
          f"×{out['cpu_speedup']:.2f} CPU, median of {repeats} side-by-side runs); "
          f"max rel difference {out['max_rel_difference']:.2g}")
    return out


# -- the city case ------------------------------------------------------------------

VEHICLE_STRIDE, FEATURE_STRIDE = 100, 10_000   # id shift per tile (crossroad features are 1000 + k)


def tiled(recordings: list[Recording], spacing: float = 5000.0) -> Recording:
    """One recording of independent `recordings` side by side: tile i shifted by
    i × `spacing` m along x (its GNSS rows), its vehicle ids by i × VEHICLE_STRIDE and
    its feature ids by i × FEATURE_STRIDE. Every tile has the same setup (one preset,
    no priors); true states are left zero (only `oracle-kf` runs on it, which reads
    the origins alone)."""
    setup = recordings[0].setup
    frames, origins = [], []
    for k in range(len(recordings[0].frames)):
        vehicles, batches, origin = [], {}, {}
        for i, rec in enumerate(recordings):
            frame, dv, dfeat = rec.frames[k], i * VEHICLE_STRIDE, i * FEATURE_STRIDE
            vehicles.append(frame.vehicles + dv)
            for kind, batch in frame.batches.items():
                z = batch.z.copy()
                if kind == "gnss":
                    z[:, 0] += i * spacing
                batches.setdefault(kind, []).append(Batch(
                    z, batch.cov, np.where(batch.sensor >= 0, batch.sensor + dv, batch.sensor),
                    np.where(batch.subject >= 0, batch.subject + dv, batch.subject)))
                o = rec.truth.origin[k][kind]
                origin.setdefault(kind, []).append(np.where(o >= 0, o + (dfeat if kind == "v2f" else dv), o))
        merged = {kind: Batch(*(np.concatenate([getattr(b, f.name) for b in parts])
                                for f in dataclasses.fields(Batch)))
                  for kind, parts in batches.items()}
        frames.append(Frame(k, recordings[0].frames[k].t, np.concatenate(vehicles), merged))
        origins.append({kind: np.concatenate(parts) for kind, parts in origin.items()})
    T = len(frames)
    dx, df = setup.vehicle_layout.dim, setup.feature_layout.dim
    vehicle_ids = np.concatenate([r.truth.vehicle_ids + i * VEHICLE_STRIDE for i, r in enumerate(recordings)])
    feature_ids = np.concatenate([r.truth.feature_ids + i * FEATURE_STRIDE for i, r in enumerate(recordings)])
    truth = Truth(vehicle_ids, np.zeros((T, vehicle_ids.size, dx)),
                  np.concatenate([r.truth.vehicle_present for r in recordings], axis=1),
                  feature_ids, np.zeros((T, feature_ids.size, df)),
                  np.concatenate([r.truth.feature_present for r in recordings], axis=1), origins)
    return Recording(setup, frames, truth)


def time_city(n_tiles: int, seed: int) -> dict:
    tiles = [recording("brambilla-crossroad", seed + i, {"n_features": 24}) for i in range(n_tiles)]
    rec = tiled(tiles)
    warm_up(tiled(tiles[:1]))
    est = new_estimator("oracle-kf", rec)
    seconds, estimates = run_steps(est, rec.frames)
    n = len(rec.frames)
    out = {"tiles": n_tiles, "vehicles": int(rec.truth.vehicle_ids.size),
           "features": int(rec.truth.feature_ids.size), "steps": n,
           "features_estimated_at_end": len(estimates[-1].features),
           "seconds_per_step": seconds / n, "target_seconds_per_step": CITY_TARGET_SECONDS,
           "largest_component_at_end": largest_component(est)}
    print(f"city: {out['vehicles']} vehicles, {out['features']} features: "
          f"{out['seconds_per_step']:.3f} s per step")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/oracle_kf.json"))
    parser.add_argument("--presets", nargs="*", default=[*PAPER_PRESETS, *SUMO_PRESETS])
    parser.add_argument("--dense-steps", type=int, default=60,
                        help="steps of the dense form compared per preset (0: none)")
    parser.add_argument("--tiles", type=int, default=CITY_TILES, help="crossroads of the city case (0: none)")
    parser.add_argument("--odometry", nargs="*", default=["sumo-grid-tlr", "sumo-braunschweig-tlr"],
                        help="SUMO presets timed with and without odometry")
    parser.add_argument("--duration", type=float, default=None,
                        help="seconds of traffic of the odometry runs (default: the preset's)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="alternate runs of the odometry case and of --baseline")
    parser.add_argument("--baseline", default=None,
                        help="git revision whose component form the presets are also timed against")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--threads", type=int, default=1, help="BLAS threads (1: as a run's worker)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: check that the script runs")
    args = parser.parse_args(argv)
    presets, tiles, dense_steps = args.presets, args.tiles, args.dense_steps
    odometry, repeats = args.odometry, args.repeats
    overrides: dict[str, dict] = {}
    odometry_overrides = {} if args.duration is None else {"duration": args.duration}
    if args.quick:
        from cooploc.scenarios.sumo import TINY_GRID

        presets, tiles, dense_steps = list(PAPER_PRESETS), min(tiles, 3), min(dense_steps, 8)
        overrides = {"froehle2018": {"n_steps": 20}, "brambilla-crossroad": {"n_steps": 8}}
        odometry, repeats, odometry_overrides = ["sumo-grid-tlr"], 1, dict(TINY_GRID)
    results = {"environment": environment(), "threads": args.threads, "presets": {}}
    with limit_threads(args.threads):
        for name in presets:
            results["presets"][name] = time_preset(name, args.seed, dense_steps, overrides.get(name))
            if args.baseline:
                results["presets"][name]["against_baseline"] = time_baseline(
                    name, args.seed, args.baseline, repeats, overrides.get(name))
        if odometry:
            results["odometry"] = {name: time_odometry(name, args.seed, dense_steps, repeats,
                                                       odometry_overrides) for name in odometry}
        if tiles:
            results["city"] = time_city(tiles, args.seed)
    write_json(results, args.out)


if __name__ == "__main__":
    main()
