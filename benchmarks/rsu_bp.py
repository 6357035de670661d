"""Benchmark `rsu-bp` (Fröhle 2018) and its pair kernel; write JSON.

    python benchmarks/rsu_bp.py                      # full: 501-step froehle2018, N_p = 600 and 2000
    python benchmarks/rsu_bp.py --quick --out b.json # tiny sizes, to check the script

Measured in one run, on the same machine and data:

1. `rsu-bp` steps per second and µs per step on the `froehle2018` preset (time inside
   `step` only) at N_p = 600 (the paper's; `--runs` runs of `--steps` steps) and 2000
   (one run of at most 201 steps — 72 million pairs a step; `--particles` picks the
   sizes), with vehicle RMSE beside `oracle-kf` (the known-association bound; target:
   vehicle-1 RMSE within 25 %) and `gnss-kf`; `gnss-kf`'s steps per second on the same
   recordings, in the same process, as the reference for a loaded machine (the ratio
   `gnss_kf_steps_per_rsu_bp_step` moves less with the load than either speed); peak
   traced memory in a separate pass (tracemalloc slows Python down).
   The vehicle-1 ratio comes with a bootstrap 90 % interval over runs: one run's RMSE
   is an average of 501 strongly correlated errors, so two runs can put the ratio
   anywhere between 1.1 and 1.4 (default 10 runs).
   ``--features 3 6`` repeats the N_p = 600 timing at each number of features K
   (froehle2018's Fig. 5 sweep goes to K = 6: S K M = 72 blocks of N_p² pairs a step).
2. Pair-kernel throughput, pair evaluations per second, for the shape of one
   `froehle2018` step (S = 2 vehicles with M = 3 rows each against K = 3 features:
   S K M = 18 blocks of N_p × N_p pairs):
   - `separable_step` — what `rsu-bp` does per step with known features
     (`rsu_bp.kernel.SeparableKernel`: the kernel with β's sums, then μ's sums);
   - `direct_step` — the same work in the direct form (rows with different W:
     `pair_kernel`, then its `log_sum_over_second` and `log_sum_over_first`);
   - `pair_kernel` — numba, float32 values with a float64 scale per row, stored;
   - `pair_kernel_log_sum` — numba, fused float64 weighted sum, nothing stored;
   - `pair_kernel_numpy` — a plain NumPy broadcast in float64.
   Each is the best of `repeats` calls after one warm-up call (numba compilation).

With ``--sumo`` (features not known in advance, issues 14 and 17), instead:

3. Every ``sumo-*`` preset at its default duration (one run, seed 1): vehicle RMSE of
   `rsu-bp` (N_p = 600) and `gnss-kf`, and of `oracle-kf` with ``--oracle`` (slow: its
   dense covariance); the ratios rsu-bp / gnss-kf (target: at most 1) and rsu-bp /
   oracle-kf (target: at most 1.3); steps/s inside `step` (target: 10 on
   sumo-braunschweig-tlr) beside gnss-kf's measured in the same process; peak traced
   memory of 20 steps.
4. Time per step against vehicles on ``brambilla-crossroad --set n_vehicles=N`` (32
   steps; ``--vehicles``), with the fitted growth exponent of rsu-bp (1: linear) and the
   time at 200 vehicles (target: 0.1 s).

The machine is shared: the load average at the start and end is recorded with the
versions and platform (`common.environment()`), since numbers from a loaded 2-core
machine are lower bounds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, recording, run_steps, step_memory, write_json

from cooploc.association import padded_groups
from cooploc.estimators.rsu_bp import RsuBPParams
from cooploc.estimators.rsu_bp.kernel import SeparableKernel
from cooploc.metrics import VEHICLE, evaluate, per_entity_rmse
from cooploc.particles import pair_kernel, pair_kernel_log_sum, pair_kernel_numpy
from cooploc.registry import presets as presets_by_name

ORACLE_TARGET = 1.25    # vehicle-1 RMSE of rsu-bp within 25 % of oracle-kf
SPEED_TARGET = 20.0     # steps per second at N_p = 600


def _vehicle_rmse(rec, estimates) -> dict[str, float]:
    table = evaluate(rec, estimates)
    rows = table.kind == VEHICLE
    return {str(k): v for k, v in per_entity_rmse(table.id[rows], table.err_pos[rows]).items()}


def time_rsu_bp(n_particles: int, n_steps: int, seeds: list[int], n_features: int = 3) -> dict:
    """Steps/s, µs/step, RMSE beside the references, peak memory (separate pass)."""
    params = RsuBPParams(n_particles=n_particles)
    seconds = steps = gnss_seconds = 0.0
    rmse: dict[str, list[dict[str, float]]] = {"rsu-bp": [], "oracle-kf": [], "gnss-kf": []}
    for seed in seeds:
        rec = recording("froehle2018", seed, {"n_steps": n_steps, "n_features": n_features})
        spent, estimates = run_steps(new_estimator("rsu-bp", rec, params, seed), rec.frames)
        seconds, steps = seconds + spent, steps + len(rec.frames)
        rmse["rsu-bp"].append(_vehicle_rmse(rec, estimates))
        for ref in ("oracle-kf", "gnss-kf"):
            spent, estimates = run_steps(new_estimator(ref, rec, None, seed), rec.frames)
            gnss_seconds += spent if ref == "gnss-kf" else 0.0
            rmse[ref].append(_vehicle_rmse(rec, estimates))
    mean_rmse = {name: {vid: float(np.sqrt(np.mean([r[vid] ** 2 for r in runs])))
                        for vid in runs[0]} for name, runs in rmse.items()}
    rec = recording("froehle2018", seeds[0], {"n_steps": min(n_steps, 20), "n_features": n_features})
    peak = step_memory(new_estimator("rsu-bp", rec, params), rec.frames)
    ratio = mean_rmse["rsu-bp"]["1"] / mean_rmse["oracle-kf"]["1"]
    low, high = _bootstrap_ratio([r["1"] for r in rmse["rsu-bp"]], [r["1"] for r in rmse["oracle-kf"]])
    return {
        "n_particles": n_particles, "n_features": n_features, "n_steps": n_steps, "runs": len(seeds),
        "steps_per_second": steps / seconds, "us_per_step": seconds / steps * 1e6,
        "gnss_kf_steps_per_second": steps / gnss_seconds,
        "gnss_kf_steps_per_rsu_bp_step": seconds / gnss_seconds,
        "kernel_pairs_per_step": 2 * n_features**2 * n_particles**2,
        "vehicle_rmse": mean_rmse,
        "vehicle1_rmse_over_oracle": ratio,
        "vehicle1_rmse_over_oracle_90pct_interval": [low, high],
        "accuracy_target_met": bool(ratio <= ORACLE_TARGET),
        "peak_memory_bytes_20_steps": peak,
    }


def _bootstrap_ratio(ours: list[float], bound: list[float], draws: int = 2000) -> tuple[float, float]:
    """5 % and 95 % quantiles of RMS(ours)/RMS(bound) over runs drawn with replacement."""
    ours2, bound2 = np.square(ours), np.square(bound)
    pick = np.random.default_rng(0).integers(0, len(ours), size=(draws, len(ours)))
    ratios = np.sqrt(ours2[pick].mean(axis=1) / bound2[pick].mean(axis=1))
    return float(np.quantile(ratios, 0.05)), float(np.quantile(ratios, 0.95))


def kernel_throughput(n_particles: int, repeats: int, numpy_particles: int) -> dict:
    """Pair evaluations per second of the three kernel implementations, same data."""
    rng = np.random.default_rng(0)
    B, d = 18, 2

    def case(n: int):
        return (rng.normal(size=(B, d)), np.repeat(np.eye(d)[None], B, 0),
                rng.normal(size=(B, n, d)), rng.normal(size=(B, n, d)))

    def best(fn, *args) -> float:
        fn(*args)  # warm-up (numba compilation, caches)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            fn(*args)
            times.append(time.perf_counter() - start)
        return min(times)

    z, cov, a, c = case(n_particles)
    w = np.full((B, n_particles), 1.0 / n_particles)
    pairs = B * n_particles**2
    out = {"blocks": B, "n_particles": n_particles, "pairs": pairs}
    # one step of rsu-bp's known-feature BP: S = 2 vehicles × M = 3 rows against K = 3
    # features (blocks b = r K + k), the kernel with β's sums, then μ's sums
    S, K = 2, 3
    feature, vehicle = rng.normal(size=(K, n_particles, d)), rng.normal(size=(S, n_particles, d))
    s_row = np.repeat(np.arange(S), B // (S * K))
    s_b, k_b = np.repeat(s_row, K), np.tile(np.arange(K), s_row.size)
    index, mask = padded_groups(s_row, S)
    groups = (index[:, None, :] * K + np.arange(K)[:, None]).reshape(-1, index.shape[1])
    cov_s = cov[:1].repeat(B, 0)
    buffer = np.empty(pairs, dtype=np.float32)

    def separable_step() -> None:
        kernel, _ = SeparableKernel.build(z, cov_s, feature, vehicle, k_b, s_b, groups,
                                          np.repeat(mask, K, axis=0), w, buffer)
        kernel.log_sum_over_first(w)

    def direct_step() -> None:
        kernel = pair_kernel(z, cov_s, feature[k_b], vehicle[s_b], buffer)
        kernel.log_sum_over_second(w)
        kernel.log_sum_over_first(w)

    out["separable_step_pairs_per_second"] = pairs / best(separable_step)
    out["direct_step_pairs_per_second"] = pairs / best(direct_step)
    out["numba_stored_float32_pairs_per_second"] = pairs / best(pair_kernel, z, cov, a, c)
    out["numba_fused_sum_float64_pairs_per_second"] = pairs / best(pair_kernel_log_sum, z, cov, a, c, w)
    # the broadcast needs B N² d doubles of temporaries: measured at a size that fits
    zn, covn, an, cn = case(numpy_particles)
    pairs_np = B * numpy_particles**2
    out["numpy_broadcast_n_particles"] = numpy_particles
    out["numpy_broadcast_float64_pairs_per_second"] = pairs_np / best(pair_kernel_numpy, zn, covn, an, cn)
    out["numba_over_numpy"] = (out["numba_stored_float32_pairs_per_second"]
                               / out["numpy_broadcast_float64_pairs_per_second"])
    return out


SUMO_ORACLE_TARGET = 1.3     # vehicle RMSE of rsu-bp at most 1.3 × oracle-kf on every sumo-* preset
SUMO_SPEED_TARGET = 10.0     # steps per second on sumo-braunschweig-tlr at N_p = 600
SCALING_TARGET = 0.1         # seconds per step with 200 vehicles


def _rmse_all(rec, estimates) -> float:
    table = evaluate(rec, estimates)
    return float(np.sqrt(np.mean(table.err_pos[table.kind == VEHICLE] ** 2)))


def sumo_preset(name: str, seed: int, oracle: bool, duration: float | None) -> dict:
    """RMSE, ratios, steps/s and peak memory of rsu-bp beside gnss-kf (and oracle-kf) on one run."""
    rec = recording(name, seed, {"duration": duration} if duration else None)
    out: dict = {"steps": len(rec.frames),
                 "vehicles_per_step": float(np.mean([len(f.vehicles) for f in rec.frames])),
                 "v2f_rows_per_step": float(np.mean([len(f.batches["v2f"]) for f in rec.frames]))}
    for est_name in ("gnss-kf", "rsu-bp", *(("oracle-kf",) if oracle else ())):
        spent, estimates = run_steps(new_estimator(est_name, rec, None, seed), rec.frames)
        out[est_name] = {"vehicle_rmse": _rmse_all(rec, estimates),
                         "steps_per_second": len(rec.frames) / spent}
        if est_name == "rsu-bp":
            out[est_name]["discarded_share"] = float(
                sum(e.info["v2f_discarded"] for e in estimates) / max(1, sum(len(e.info["v2f_track"])
                                                                          for e in estimates)))
    bp = out["rsu-bp"]
    out["rsu_over_gnss"] = bp["vehicle_rmse"] / out["gnss-kf"]["vehicle_rmse"]
    out["rsu_over_oracle"] = bp["vehicle_rmse"] / out["oracle-kf"]["vehicle_rmse"] if oracle else None
    out["gnss_steps_per_rsu_step"] = out["gnss-kf"]["steps_per_second"] / bp["steps_per_second"]
    out["peak_memory_bytes_20_steps"] = step_memory(new_estimator("rsu-bp", rec, None, seed), rec.frames[:20])
    return out


def scaling(vehicles: list[int], n_steps: int) -> dict:
    """Seconds per step of rsu-bp and gnss-kf against vehicles, and rsu-bp's growth exponent."""
    rows = []
    for n in vehicles:
        rec = recording("brambilla-crossroad", 0, {"n_vehicles": n, "n_steps": n_steps})
        entry = {"vehicles": n}
        for est_name in ("gnss-kf", "rsu-bp"):
            spent, _ = run_steps(new_estimator(est_name, rec), rec.frames)
            entry[f"{est_name}_seconds_per_step"] = spent / len(rec.frames)
        rows.append(entry)
    t = np.array([r["rsu-bp_seconds_per_step"] for r in rows])
    exponent = float(np.polyfit(np.log(vehicles), np.log(t), 1)[0]) if len(vehicles) > 1 else None
    at_200 = next((r["rsu-bp_seconds_per_step"] for r in rows if r["vehicles"] == 200), None)
    return {"per_vehicles": rows, "rsu_bp_growth_exponent": exponent,
            "rsu_bp_seconds_per_step_at_200": at_200,
            "target_met_at_200": None if at_200 is None else bool(at_200 <= SCALING_TARGET)}


def main_sumo(args: argparse.Namespace) -> int:
    presets = (["sumo-grid-tlr"] if args.quick
               else sorted(p for p in presets_by_name() if p.startswith("sumo-")))
    duration = 15.0 if args.quick else None
    vehicles = [20, 40] if args.quick else args.vehicles
    result = {
        **environment(),
        "targets": {"rsu_over_oracle_at_most": SUMO_ORACLE_TARGET, "rsu_over_gnss_at_most": 1.0,
                    "braunschweig_tlr_steps_per_second_at_least": SUMO_SPEED_TARGET,
                    "seconds_per_step_at_200_vehicles_at_most": SCALING_TARGET},
        "sumo": {name: sumo_preset(name, 1, args.oracle, duration) for name in presets},
        "scaling": scaling(vehicles, 8 if args.quick else 32),
    }
    write_json(result, args.out)
    print(json.dumps(result, indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (checks the script)")
    parser.add_argument("--steps", type=int, default=None, help="steps per run (default 501)")
    parser.add_argument("--runs", type=int, default=None, help="runs at N_p = 600 (default 10)")
    parser.add_argument("--particles", type=int, nargs="+", default=None,
                        help="N_p values (default 600 2000; the largest gets one run of ≤ 201 steps)")
    parser.add_argument("--features", type=int, nargs="+", default=[3],
                        help="numbers of features K of the N_p = 600 timing (default 3)")
    parser.add_argument("--out", type=Path, default=None,
                        help="JSON file (default benchmarks/results/rsu_bp.json; "
                             "rsu_bp_sumo.json with --sumo)")
    parser.add_argument("--sumo", action="store_true", help="the sumo-* presets and the scaling curve")
    parser.add_argument("--oracle", action="store_true", help="with --sumo: also oracle-kf (slow)")
    parser.add_argument("--vehicles", type=int, nargs="+", default=[100, 200, 400],
                        help="with --sumo: vehicle counts of the scaling curve")
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = Path("benchmarks/results") / ("rsu_bp_sumo.json" if args.sumo else "rsu_bp.json")
    if args.sumo:
        return main_sumo(args)
    steps = args.steps or (6 if args.quick else 501)
    runs = args.runs or (1 if args.quick else 10)
    particles = tuple(args.particles or ((50, 100) if args.quick else (600, 2000)))
    result = {
        **environment(),
        "targets": {"vehicle1_rmse_over_oracle_at_most": ORACLE_TARGET,
                    "steps_per_second_at_600_at_least": SPEED_TARGET},
        "rsu_bp": {},
        "pair_kernel": kernel_throughput(particles[0], 2 if args.quick else 5,
                                         particles[0] if args.quick else 300),
    }
    for n in particles:
        # the large N_p costs ~S K M N_p² = 72 M pairs a step: one shorter run suffices for speed
        big = len(particles) > 1 and n == particles[-1]
        result["rsu_bp"][str(n)] = time_rsu_bp(n, min(steps, 201) if big else steps,
                                               list(range(1 if big else runs)))
    for k in args.features:
        if k != 3:
            result["rsu_bp"][f"{particles[0]}_K{k}"] = time_rsu_bp(particles[0], steps, list(range(runs)), k)
    if "600" in result["rsu_bp"]:
        result["speed_target_met"] = bool(result["rsu_bp"]["600"]["steps_per_second"] >= SPEED_TARGET)
    result["load_average_end"] = environment()["load_average"]
    write_json(result, args.out)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
