"""Time the Gulati factor graphs: per run and per step, and the topology factor before/after.

    python benchmarks/factor_graph.py                 # full: N = 2, 3, 4, 250 steps
    python benchmarks/factor_graph.py --quick         # tiny sizes, to check the script
    python benchmarks/factor_graph.py --out bench.json
    python benchmarks/factor_graph.py --sections old_vs_new jit   # Table II claim: solver alone, JIT

Measured (best of `--repeats`, wall clock and process CPU time; the machine may be
shared, CPU time is the steadier number):

1. `estimators`: each of gnss-kf (Kalman baseline), fg-topology-old, fg-topology-new
   (steps + `smooth()`), fg-isam2 on gulati-Nv: seconds per run, µs per step, and peak
   traced memory (tracemalloc, in a separate pass).
2. `batch_solve` — the topology factor cost in one Levenberg–Marquardt solve of the
   whole graph (graph already built, same initial guess), for each factor kind:
   * `gtsam_naive`  — before: GTSAM LM, topology as a Python `CustomFactor` whose error
     builds NumPy arrays on every call (one GIL-bound call per factor, gtsam #875);
   * `gtsam_scalar` — GTSAM LM with our `CustomFactor` (plain float arithmetic);
   * `gtsam_no_topology` — GTSAM LM on the native GPS/odometry factors only (the floor
     of GTSAM without Python callbacks);
   * `sparse` — after: our vectorised banded LM (`solver="sparse"`), with and without
     the marginal covariances. Costs of `sparse` and `gtsam_*` are recorded to show they
     reach the same minimum.
3. `horizon`: `gtsam_naive` vs `sparse` LM time against the number of steps.
4. `isam2`: ms per step of fg-isam2 before (naive CustomFactor, relinearise every step)
   and after (scalar CustomFactor, GTSAM's default relinearize_skip = 10).
5. `old_vs_new` — Gulati's Table II claim (the new factor ≥ 50 % faster) on the solver
   alone, warm: over `--solve-runs` recordings per N, the LM solve of the old and the new
   graph (same initial guess) with our banded LM and with GTSAM's LM (scalar
   CustomFactor, as the paper's C++ GTSAM), best of `--repeats` each; per run the
   seconds and LM iterations, and the medians of the per-run ratios new / old.
6. `jit`: the one-off compilation of the solver's numba kernel, in a fresh interpreter
   with an empty numba cache (`NUMBA_CACHE_DIR` a new folder), and again with that cache
   filled — excluded from every timing above (`compile_kernels()` runs first).

The JSON also records the environment of `common.environment()` (versions, platform,
CPU count, load average at start and end). Everything runs with one BLAS thread
(`backends.limit_threads(1)`), as the experiment runner's workers do: on a shared
machine OpenBLAS threads spinning for a core slow a banded Cholesky by orders of
magnitude.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # `common` also when loaded from the file
from common import environment, new_estimator, peak_memory, recording, write_json

from cooploc import least_squares
from cooploc.backends import limit_threads
from cooploc.estimators import factor_graph as fg
from cooploc.estimators.factor_graph import gtsam_backend
from cooploc.experiment import estimate

ESTIMATORS = ("gnss-kf", "fg-topology-old", "fg-topology-new", "fg-isam2")
SECTIONS = ("estimators", "batch_solve", "horizon", "isam2", "old_vs_new", "jit")


def timed(fn: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """(best wall s, best CPU s, last result) of `fn` over `repeats` calls."""
    wall, cpu, out = np.inf, np.inf, None
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall, cpu = min(wall, time.perf_counter() - w0), min(cpu, time.process_time() - c0)
    return wall, cpu, out


def run_estimator(name: str, rec, params=None) -> list:
    """A whole run: construct, step through `rec`, smooth where the estimator can."""
    return estimate(new_estimator(name, rec, params), rec)


def naive_topology_factor(kind, keys_t, keys_prev, delta, s, sigma, huber=0.0):
    """The 'before': a CustomFactor that builds NumPy arrays on every call."""
    import gtsam

    keys = list(keys_t) + (list(keys_prev) if kind == fg.NEW else [])

    def error(this, values, jacobians):
        p = np.array([values.atPoint2(k) for k in keys_t])
        if kind == fg.OLD:
            J, _ = fg.topology_jacobians(kind, p[None])
            e = fg.squared_topology(p) - s
            blocks = list(J[0])
        else:
            q = np.array([values.atPoint2(k) for k in keys_prev]) + delta
            J_cur, J_prev = fg.topology_jacobians(kind, p[None], q[None])
            e = fg.bilinear_topology(p, q) - s
            blocks = list(J_cur[0]) + list(J_prev[0])
        if jacobians is not None:
            for i, block in enumerate(blocks):
                jacobians[i] = block[None, :]
        return np.array([e])

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, sigma), keys, error)


@contextmanager
def naive_factor():
    """GTSAM graphs built inside (batch and iSAM2) use the naive topology factor."""
    original = gtsam_backend.topology_custom_factor
    gtsam_backend.topology_custom_factor = naive_topology_factor
    try:
        yield
    finally:
        gtsam_backend.topology_custom_factor = original


def built_graph(name: str, rec):
    est = new_estimator(name, rec)
    for f in rec.frames:
        est.step(f)
    return est


def gtsam_cost(graph, x0: np.ndarray) -> float:
    """GTSAM LM (default parameters, as our solver's) from x0; the final cost."""
    import gtsam

    result = gtsam.LevenbergMarquardtOptimizer(graph, fg.gtsam_values(x0),
                                               gtsam.LevenbergMarquardtParams()).optimize()
    return float(graph.error(result))


def sparse_cost(problem, x0: np.ndarray, covariances: bool = True) -> float:
    """Our banded LM from x0 (`problem` may be the GraphData: arrays built inside)."""
    if isinstance(problem, fg.GraphData):
        problem = fg.GraphProblem.of(problem)
    return fg.solve_lm(problem.linearize, x0, covariances=covariances).cost


def batch_solve(rec, repeats: int) -> dict[str, Any]:
    import gtsam

    out: dict[str, Any] = {}
    for name in ("fg-topology-old", "fg-topology-new"):
        est = built_graph(name, rec)
        data, x0 = est.data, np.concatenate(est.initial)
        row: dict[str, Any] = {"topology_factors": data.n_topology, "variables": data.n_vars}
        with naive_factor():
            graph = fg.gtsam_graph(data)
        row["gtsam_naive"] = _solve_row(partial(gtsam_cost, graph, x0), repeats)
        graph = fg.gtsam_graph(data)
        row["gtsam_scalar"] = _solve_row(partial(gtsam_cost, graph, x0), repeats)
        native = gtsam.NonlinearFactorGraph()
        for i in range(graph.size()):
            if not isinstance(graph.at(i), gtsam.CustomFactor):
                native.add(graph.at(i))
        row["gtsam_no_topology"] = _solve_row(partial(gtsam_cost, native, x0), repeats)
        problem = fg.GraphProblem.of(data)
        row["sparse"] = _solve_row(partial(sparse_cost, problem, x0), repeats)
        row["sparse_without_covariances"] = _solve_row(
            partial(sparse_cost, problem, x0, covariances=False), repeats)
        row["sparse_including_graph_arrays"] = _solve_row(partial(sparse_cost, data, x0), repeats)
        row["speedup_cpu"] = row["gtsam_naive"]["cpu_s"] / row["sparse"]["cpu_s"]
        out[name] = row
    return out


def _solve_row(fn: Callable[[], float], repeats: int) -> dict[str, float]:
    wall, cpu, cost = timed(fn, repeats)
    return {"wall_s": wall, "cpu_s": cpu, "cost": cost}


def isam2(rec, repeats: int) -> dict[str, Any]:
    steps = len(rec.frames)
    out = {}
    with naive_factor():
        wall, cpu, _ = timed(lambda: run_estimator("fg-isam2", rec, fg.ISAM2Params(relinearize_skip=1)),
                             repeats)
    out["before_naive_factor_skip1"] = {"ms_per_step_wall": 1e3 * wall / steps,
                                        "ms_per_step_cpu": 1e3 * cpu / steps}
    wall, cpu, _ = timed(lambda: run_estimator("fg-isam2", rec), repeats)
    out["after"] = {"ms_per_step_wall": 1e3 * wall / steps, "ms_per_step_cpu": 1e3 * cpu / steps}
    return out


def gtsam_solve(graph, x0: np.ndarray) -> tuple[float, int]:
    """GTSAM LM (default parameters) from x0: final cost and iterations."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, fg.gtsam_values(x0), params)
    result = optimizer.optimize()
    return float(graph.error(result)), int(optimizer.iterations())


def old_vs_new(n: int, steps: int, runs: int, repeats: int) -> dict[str, Any]:
    """Section 5 of the module docstring for N = n."""
    per_run: dict[str, dict[str, list[float]]] = {}
    for r in range(runs):
        rec = recording(f"gulati-{n}v", 100 + r, {"n_steps": steps})
        for name in ("fg-topology-old", "fg-topology-new"):
            est = built_graph(name, rec)
            data, x0 = est.data, np.concatenate(est.initial)
            problem = fg.GraphProblem.of(data)
            graph = fg.gtsam_graph(data)
            wall, cpu, result = timed(partial(fg.solve_lm, problem.linearize, x0), repeats)
            g_wall, g_cpu, (_, g_iterations) = timed(partial(gtsam_solve, graph, x0), repeats)
            row = per_run.setdefault(name.removeprefix("fg-topology-"), {})
            values = {"sparse_cpu_s": cpu, "sparse_wall_s": wall, "sparse_iterations": result.iterations,
                      "gtsam_cpu_s": g_cpu, "gtsam_wall_s": g_wall, "gtsam_iterations": g_iterations}
            for key, value in values.items():
                row.setdefault(key, []).append(float(value))
    ratios = {f"median_ratio_new_old_{key}": float(np.median(np.asarray(per_run["new"][key])
                                                           / np.asarray(per_run["old"][key])))
              for key in ("sparse_cpu_s", "gtsam_cpu_s", "sparse_iterations", "gtsam_iterations")}
    return {"runs": runs, **ratios, "per_run": per_run}


def jit_seconds() -> dict[str, float]:
    """Section 6: `compile_kernels()` in a fresh interpreter, empty numba cache, then filled."""
    import os
    import subprocess
    import tempfile

    code = ("import time; t = time.perf_counter(); from cooploc import least_squares; "
            "least_squares.compile_kernels(); print(time.perf_counter() - t)")
    out = {}
    with tempfile.TemporaryDirectory(prefix="cooploc-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for key in ("empty_cache_s", "filled_cache_s"):
            done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                  check=True)
            out[key] = float(done.stdout.strip().splitlines()[-1])
    return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    with limit_threads(1):
        return _main(argv)


def _main(argv: list[str] | None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (checks the script)")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--solve-runs", type=int, default=None, help="recordings per N of section 5")
    parser.add_argument("--sections", nargs="*", default=list(SECTIONS), choices=SECTIONS,
                        help="the sections to run (default: all)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "factor_graph.json")
    args = parser.parse_args(argv)
    counts = (2,) if args.quick else (2, 3, 4)
    steps = 30 if args.quick else 250
    repeats = args.repeats or (1 if args.quick else 3)
    horizons = (20, 40) if args.quick else (125, 250, 500, 1000)

    result: dict[str, Any] = {
        **environment(),
        "steps": steps, "repeats": repeats, "quick": args.quick,
        "estimators": {}, "batch_solve": {}, "isam2": {}, "horizon": {}, "old_vs_new": {},
    }
    result["jit"] = jit_seconds() if "jit" in args.sections else {}
    solve_runs = args.solve_runs or (2 if args.quick else 20)
    least_squares.compile_kernels()  # numba compile outside the timings
    wanted = set(args.sections)
    for n in counts:
        rec = recording(f"gulati-{n}v", 0, {"n_steps": steps})
        if "estimators" in wanted:
            rows = {}
            for name in ESTIMATORS:
                wall, cpu, _ = timed(partial(run_estimator, name, rec), repeats)
                rows[name] = {"s_per_run_wall": wall, "s_per_run_cpu": cpu,
                              "us_per_step_wall": 1e6 * wall / steps, "us_per_step_cpu": 1e6 * cpu / steps,
                              "steps_per_second": steps / wall,
                              "peak_bytes": peak_memory(partial(run_estimator, name, rec))}
            result["estimators"][f"{n}v"] = rows
        if "batch_solve" in wanted:
            result["batch_solve"][f"{n}v"] = batch_solve(rec, repeats)
        if "isam2" in wanted:
            result["isam2"][f"{n}v"] = isam2(rec, repeats)
        if "old_vs_new" in wanted:
            result["old_vs_new"][f"{n}v"] = old_vs_new(n, steps, solve_runs, repeats)
    for T in horizons if "horizon" in wanted else ():
        rec = recording("gulati-2v", 0, {"n_steps": T})
        est = built_graph("fg-topology-new", rec)
        data, x0 = est.data, np.concatenate(est.initial)
        with naive_factor():
            graph = fg.gtsam_graph(data)
        problem = fg.GraphProblem.of(data)
        result["horizon"][str(T)] = {
            "gtsam_naive": _solve_row(partial(gtsam_cost, graph, x0), repeats),
            "sparse": _solve_row(partial(sparse_cost, problem, x0), repeats),
        }
    write_json(result, args.out)
    print(json.dumps({k: result[k] for k in ("batch_solve", "isam2", "jit")}, indent=1)[:3000])
    return result


if __name__ == "__main__":
    main()
