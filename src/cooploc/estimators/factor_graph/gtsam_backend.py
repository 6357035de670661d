"""The same factor graph in GTSAM: native GPS/odometry factors, Python topology `CustomFactor`s.

Paper: Gulati et al., "Graph Based Vehicle Infrastructure Cooperative Localization"
(IV 2017), §III, built on GTSAM as the authors did: eq. 7 as `PriorFactorPoint2`,
eq. 5 as `BetweenFactorPoint2`, eqs. 8 / 11–13 (and their Jacobians, eq. 19) as one
`CustomFactor` per topology factor, eq. 17 solved by GTSAM's Levenberg–Marquardt
(`solve_gtsam`) or incrementally by iSAM2 (`isam2.py`).

This is the reference our own solver (`least_squares.solve_lm` on `GraphProblem`) is
tested against, and the "before" of `benchmarks/factor_graph.py`. A `CustomFactor`
costs one GIL-bound Python call per factor and linearisation (GTSAM issue #875), so the
topology error and Jacobian below are plain float arithmetic on the 2N positions
(no NumPy call per vehicle): O(N) per evaluation. The robust option wraps the
topology noise in `noiseModel.Robust` + `mEstimator.Huber`.

`gtsam` is imported inside the functions (an optional heavy dependency).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.estimators.factor_graph.factors import NEW, OLD
from cooploc.estimators.factor_graph.graph import FrameFactors, GraphData
from cooploc.least_squares import LMResult
from cooploc.types import FloatArray

__all__ = [
    "first_sentence", "gtsam_factors", "gtsam_graph", "gtsam_values", "solve_gtsam", "topology_custom_factor",
]


def first_sentence(exc: BaseException) -> str:
    """The first sentence of an exception's message, on one line (GTSAM's run over a page)."""
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return text.split(". ")[0].rstrip(".") or type(exc).__name__


def topology_custom_factor(kind: str, keys_t: list[int], keys_prev: list[int],
                           delta: FloatArray, s: float, sigma: float, huber: float = 0.0) -> Any:
    """One GTSAM `CustomFactor` of the old or new topology residual (scalar arithmetic).

    keys_t, keys_prev: the N variables at t and t − 1 (the latter used by the new factor);
    delta (N, 2) odometry; s, sigma: the measured squared topology and its σ (eqs. 8, 15).
    """
    import gtsam

    n = len(keys_t)
    dx = [float(v) for v in delta[:, 0]]
    dy = [float(v) for v in delta[:, 1]]
    keys = list(keys_t) + (list(keys_prev) if kind == NEW else [])
    noise = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
    if huber > 0:
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber), noise)

    def error(this, values, jacobians):
        px, py = [], []
        for key in keys_t:
            p = values.atPoint2(key)
            px.append(p[0])
            py.append(p[1])
        mpx, mpy = sum(px) / n, sum(py) / n
        if kind == OLD:  # S(p_t) − s, ∂/∂p^i = 2N(p^i − p̄)                   eq. (8)
            e = n * sum((a - mpx) ** 2 + (b - mpy) ** 2 for a, b in zip(px, py, strict=True)) - s
            if jacobians is not None:
                for i in range(n):
                    jacobians[i] = np.array([[2 * n * (px[i] - mpx), 2 * n * (py[i] - mpy)]])
            return np.array([e])
        qx, qy = [], []  # q = p_{t−1} + δ_t                                   eq. (10)
        for i, key in enumerate(keys_prev):
            p = values.atPoint2(key)
            qx.append(p[0] + dx[i])
            qy.append(p[1] + dy[i])
        mqx, mqy = sum(qx) / n, sum(qy) / n
        # B(p_t, q) − s, ∂/∂p_t^i = N(q^i − q̄), ∂/∂p_{t−1}^i = N(p_t^i − p̄_t)  eqs. (11)–(13)
        e = n * sum((px[i] - mpx) * (qx[i] - mqx) + (py[i] - mpy) * (qy[i] - mqy)
                    for i in range(n)) - s
        if jacobians is not None:
            for i in range(n):
                jacobians[i] = np.array([[n * (qx[i] - mqx), n * (qy[i] - mqy)]])
                jacobians[n + i] = np.array([[n * (px[i] - mpx), n * (py[i] - mpy)]])
        return np.array([e])

    return gtsam.CustomFactor(noise, keys, error)


def gtsam_factors(data: GraphData, frames: list[FrameFactors] | None = None, huber: float = 0.0) -> Any:
    """GTSAM factors of `frames` (default: every frame of `data`) as a NonlinearFactorGraph."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    Gaussian = gtsam.noiseModel.Gaussian.Covariance
    for f in data.frames if frames is None else frames:
        for v, z, cov in zip(f.unary_var.tolist(), f.unary_z, f.unary_cov, strict=True):
            graph.add(gtsam.PriorFactorPoint2(v, z, Gaussian(cov)))
        for a, b, z, cov in zip(f.between_a.tolist(), f.between_b.tolist(), f.between_z,
                                f.between_cov, strict=True):
            graph.add(gtsam.BetweenFactorPoint2(a, b, z, Gaussian(cov)))
        for k in range(f.topology_s.size):
            graph.add(topology_custom_factor(
                data.kind, f.topology_current[k].tolist(), f.topology_previous[k].tolist(),
                f.topology_delta[k], float(f.topology_s[k]), float(f.topology_sigma[k]), huber))
    return graph


def gtsam_graph(data: GraphData, huber: float = 0.0) -> Any:
    """The whole graph of `data` as a GTSAM `NonlinearFactorGraph` (reference solver)."""
    return gtsam_factors(data, None, huber)


def gtsam_values(x: FloatArray) -> Any:
    """GTSAM `Values` holding positions x (n_vars, 2) under keys 0 … n_vars − 1."""
    import gtsam

    values = gtsam.Values()
    for v, p in enumerate(x):
        values.insert(v, np.asarray(p, float))
    return values


def solve_gtsam(data: GraphData, x0: FloatArray, *, huber: float = 0.0, max_iterations: int = 100,
                relative_tolerance: float = 1e-5, absolute_tolerance: float = 1e-5,
                lambda_initial: float = 1e-5, covariances: bool = True) -> LMResult:
    """GTSAM's Levenberg–Marquardt on the same graph from x0, with the LM settings of
    `cooploc.least_squares.solve_lm` (and its Huber threshold on topology factors)."""
    import gtsam

    graph = gtsam_graph(data, huber)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(max_iterations)
    lm.setRelativeErrorTol(relative_tolerance)
    lm.setAbsoluteErrorTol(absolute_tolerance)
    lm.setlambdaInitial(lambda_initial)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, gtsam_values(x0), lm)
    result = optimizer.optimize()
    x = np.array([result.atPoint2(v) for v in range(data.n_vars)])
    cov = None
    if covariances:
        marginals = gtsam.Marginals(graph, result)
        cov = np.array([marginals.marginalCovariance(v) for v in range(data.n_vars)])
    return LMResult(x, cov, int(optimizer.iterations()), float(graph.error(result)))
