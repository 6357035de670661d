"""`fg-topology-old`, `fg-topology-new`: batch Levenberg–Marquardt on the topology factor graph.

Paper: Gulati et al., "Graph Based Vehicle Infrastructure Cooperative Localization"
(IV 2017), §III: the graph of GPS (eqs. 6–7), odometry (eqs. 4–5) and one topology
factor per step — old (eq. 8) or new (eqs. 9–16) — smoothed as one nonlinear least
squares problem (eq. 17) by Levenberg–Marquardt, as the paper does with GTSAM.
The graph: `graph.py`; the topology factors: `factors.py` (derivation:
docs/factor_graph.md). GNSS rows that hold more than the position (`sumo-*`'s z = [p,
v] + w) enter as their exact position marginal and, through the motion model, as
velocity between factors between consecutive steps (not in the paper; `graph.py`,
`gnss_velocity`).

Per step and at the end
-----------------------
`step` appends the frame's factors and returns the *filtered* estimate of the graph's
linear part (GPS and odometry, `estimates.PositionFilter`), in O(N) per step.
`smooth()` solves the whole graph and returns the smoothed estimate of every step;
`cooploc.experiment.estimate` calls it at the end of a run (the paper scores smoothed
positions) and counts its time as step time. `Estimate.info["topology"]` is the number
of topology factors in the graph so far.

Solvers
-------
`solver="sparse"` (default): `cooploc.least_squares.solve_lm` on `GraphProblem`, our
LM on the sparse whitened Jacobian. Variables are ordered by step, so JᵀJ is banded
(bandwidth < 2N per variable block) and each iteration is one banded Cholesky,
O(T N³) for T steps; marginal covariances come from the banded selected inverse, also
O(T N³). `solver="gtsam"`: GTSAM's LM on the same graph (`gtsam_backend.py`), the
reference the tests check ours against. Damping follows GTSAM's default (λI, λ₀ = 1e-5,
× 10 / ÷ 10), and so do the stopping tolerances. How the two compare in time:
`benchmarks/factor_graph.py`; in accuracy against the paper's Table I:
`cooploc reproduce gulati`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc import least_squares
from cooploc.errors import EstimatorError
from cooploc.estimators.factor_graph.estimates import EstimateLayout, PositionFilter
from cooploc.estimators.factor_graph.factors import NEW, OLD
from cooploc.estimators.factor_graph.graph import GraphData, GraphProblem
from cooploc.estimators.factor_graph.gtsam_backend import first_sentence, solve_gtsam
from cooploc.estimators.road_radars import sees_every_vehicle
from cooploc.least_squares import LMResult
from cooploc.params import Params, param
from cooploc.registry import register_estimator
from cooploc.types import Estimate, FloatArray, Frame, Setup

__all__ = [
    "FactorGraphParams",
    "FgTopologyNew",
    "FgTopologyNewParams",
    "FgTopologyOld",
    "FgTopologyOldParams",
    "odometry_noise",
]


@dataclass(frozen=True)
class FactorGraphParams(Params):
    """Batch factor-graph settings (defaults: GTSAM's LM defaults).

    Attributes
    ----------
    solver : "sparse" (our banded LM, default) or "gtsam" (GTSAM's LM with Python
        CustomFactors: the reference, slower).
    max_iterations, relative_tolerance, absolute_tolerance, lambda_initial : LM settings.
    gap_variance : m², between-factor covariance per axis where odometry is missing.
    huber : Huber threshold (σ units) on topology factors; 0 = plain Gaussian (paper).
    topology_odometry_noise : new factor only — "true": add the odometry noise to σ_s
        (docs/factor_graph.md); "false": radar noise only (paper, eqs. 14–16); "auto"
        (default): "false" in the papers' setup, "true" in traffic, where the few
        vehicles a radar sees and their 1 m odometry make the radar-only σ_s
        overconfident (sumo-grid-tlr, 30 s, 10 runs, seed 1: fg-isam2 3.137 → 3.035 m).
    gnss_velocity : where the GNSS rows hold the velocity (`sumo-*`), add the displacement
        the motion model predicts from two consecutive ones as a between factor
        (`graph.py`); False = positions only (the paper's GPS).
    view_confidence, gate_probability : traffic (per-radar topology factors,
        `graph.py`): least probability that a radar's in-view set is right; χ² gate of
        a radar row against a belief and of the topology against its prediction.
    """

    solver: str = param("sparse", choices=("sparse", "gtsam"))
    max_iterations: int = param(100, ge=1)
    relative_tolerance: float = param(1e-5, gt=0)
    absolute_tolerance: float = param(1e-5, gt=0)
    lambda_initial: float = param(1e-5, gt=0)
    gap_variance: float = param(900.0, gt=0)
    huber: float = param(0.0, ge=0)
    topology_odometry_noise: str = param("auto", choices=("auto", "true", "false"))
    gnss_velocity: bool = True
    view_confidence: float = param(0.9, gt=0, le=1)
    gate_probability: float = param(0.9999, gt=0, lt=1)


def odometry_noise(setup: Setup, params: Params) -> bool:
    """Whether the new factor's σ_s holds the odometry's share (`topology_odometry_noise`)."""
    choice = params.topology_odometry_noise  # type: ignore[attr-defined]
    return choice == "true" or (choice == "auto" and not sees_every_vehicle(setup))


class _BatchGraph:
    """Shared body of the two batch estimators (see the module docstring)."""

    kind: ClassVar[str]
    Params: ClassVar[type[Params]] = FactorGraphParams
    needs_truth: ClassVar[bool] = False
    default_preset: ClassVar[str] = "gulati-2v"
    required_sensors: ClassVar[tuple[str, ...]] = ("gnss", "odometry")
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("gnss-position",), "odometry": ("odometry",), "radar": ("infrastructure-radar",)}

    def __init__(self, setup: Setup, params: FactorGraphParams, rng: np.random.Generator) -> None:
        self.setup, self.params = setup, params
        least_squares.compile_kernels()  # compile (or load from cache) here, not in smooth()
        self.data = GraphData(setup, self.kind, params.gap_variance, odometry_noise(setup, params),
                              self.name, params.gnss_velocity, params.view_confidence,
                              params.gate_probability)
        self.filter = PositionFilter()
        self.estimates = EstimateLayout(setup, self.name)
        self.initial: list[FloatArray] = []   # filtered positions: the smoother's start

    def step(self, frame: Frame) -> Estimate:
        """Add the frame's factors; return the filtered estimate of GPS + odometry."""
        f = self.data.add_frame(frame)
        belief = self.filter.step(f)
        self.data.add_radar_topology(frame, belief.mean, belief.cov)   # traffic: per radar
        self.initial.append(belief.mean)
        vel, vel_cov = self.estimates.filtered_velocity(f.delta)
        return self.estimates.build(f.ids, belief.mean, belief.cov, vel, vel_cov,
                                    {"filtered": True, "topology": self.data.n_topology,
                                     "radar_skipped": dict(self.data.radar_skipped)})

    def solve(self) -> LMResult:
        """Solve the whole graph (positions and marginal covariances of every variable)."""
        x0 = np.concatenate(self.initial) if self.initial else np.zeros((0, 2))
        p = self.params
        if self.data.n_vars == 0:
            return LMResult(x0, np.zeros((0, 2, 2)), 0, 0.0)
        settings = {"max_iterations": p.max_iterations, "relative_tolerance": p.relative_tolerance,
                    "absolute_tolerance": p.absolute_tolerance, "lambda_initial": p.lambda_initial}
        try:
            if p.solver == "gtsam":
                return solve_gtsam(self.data, x0, huber=p.huber, **settings)
            return least_squares.solve_lm(GraphProblem.of(self.data, p.huber).linearize, x0, **settings)
        except np.linalg.LinAlgError as exc:
            raise EstimatorError(self.name, "the information matrix of the graph is not positive definite "
                                 f"in float64 ({exc}): the factor covariances span too many orders of "
                                 "magnitude") from None
        except EstimatorError:
            raise
        except RuntimeError as exc:  # GTSAM's IndeterminateLinearSystemException
            raise EstimatorError(self.name, f"GTSAM: {first_sentence(exc)}") from None

    def smooth(self) -> list[Estimate]:
        """Smoothed estimate of every step so far (one LM solve of the whole graph)."""
        result = self.solve()
        x, cov = result.x, result.cov
        assert cov is not None
        info = {"smoothed": True, "iterations": result.iterations, "cost": result.cost,
                "topology": self.data.n_topology}
        out = []
        dt = self.setup.dt
        for f in self.data.frames:
            vel, vel_cov = self.estimates.filtered_velocity(f.delta)
            cont = f.previous >= 0  # finite difference of smoothed positions
            vel[cont] = (x[f.vars[cont]] - x[f.previous[cont]]) / dt
            vel_cov[cont] = (cov[f.vars[cont]] + cov[f.previous[cont]]) / dt**2
            out.append(self.estimates.build(f.ids, x[f.vars], cov[f.vars], vel, vel_cov, info))
        return out


@dataclass(frozen=True)
class FgTopologyOldParams(FactorGraphParams):
    """`fg-topology-old` settings (see `FactorGraphParams`)."""


@dataclass(frozen=True)
class FgTopologyNewParams(FactorGraphParams):
    """`fg-topology-new` settings (see `FactorGraphParams`)."""


@register_estimator
class FgTopologyOld(_BatchGraph):
    """Batch LM on GPS, odometry and the old topology factor (eq. 8, Gulati 2016).

    Uses: identified GNSS rows, odometry, and the radar rows as topology.
    """

    name: ClassVar[str] = "fg-topology-old"
    bound: ClassVar[str | None] = "oracle-pose-smoother"
    Params: ClassVar[type[Params]] = FgTopologyOldParams
    summary: ClassVar[str] = "factor graph, GPS + odometry + old topology factor (eq. 8), batch LM"
    kind: ClassVar[str] = OLD


@register_estimator
class FgTopologyNew(_BatchGraph):
    """Batch LM on GPS, odometry and the new topology factor (eqs. 9–16).

    Uses: identified GNSS rows, odometry, and the radar rows as topology.
    """

    name: ClassVar[str] = "fg-topology-new"
    bound: ClassVar[str | None] = "oracle-pose-smoother"
    Params: ClassVar[type[Params]] = FgTopologyNewParams
    summary: ClassVar[str] = "factor graph, GPS + odometry + new topology factor (eqs. 9–16), batch LM"
    kind: ClassVar[str] = NEW
