"""`fg-topology-old`, `fg-topology-new`, `fg-isam2`: factor graphs with topology factors.

Paper: Gulati, Zhang, Malovetz, Clarke, Hinz & Knoll, "Graph Based Vehicle
Infrastructure Cooperative Localization" (IV 2017), §III (eqs. 1–19).

Model: one 2-D position variable per vehicle and step; GPS factors (eqs. 6–7),
odometry factors (eqs. 4–5) and one topology factor per step — the squared topology
of the radar's anonymous rows, which needs neither the radar pose nor data
association: the *old* factor (eq. 8) on the current positions, the *new* one
(eqs. 9–16) on the current and previous positions and the odometry. Derivation of the
new factor's residual, its noise and what happens under missed detections and
clutter: docs/factor_graph.md.

In traffic (`sumo-*`), where several road-side radars of unknown pose each see a few
vehicles and vehicles come and go, one topology factor per radar over the vehicles it
sees (found from the estimator's beliefs: `cooploc.estimators.road_radars`, shared with
SME), and the GNSS velocity as a between factor where the rows hold it (`graph.py`).

Kept apart as in GTSAM — the problem, the values, the optimizer:

- `factors`: the topology residuals, Jacobians (eq. 19) and noise (eqs. 14–16);
- `graph`: `GraphData` (the growing graph, one `FrameFactors` per frame) and
  `GraphProblem` (its whitened residuals, eq. 17, and `linearize`);
- `cooploc.least_squares`: the optimizer, banded Levenberg–Marquardt with marginal
  covariances from the selected inverse (`solve_lm`, `LMResult`);
- `gtsam_backend`: the same graph in GTSAM (the reference, and iSAM2's factors);
- `estimates`: the per-step Kalman filter of the linear part, the `Estimate` layout;
- `batch`: `FgTopologyOld`, `FgTopologyNew` (filtered `step`, smoothed `smooth()`);
- `isam2`: `FgIsam2` (incremental, filtered).

Timings: `benchmarks/factor_graph.py`; accuracy against the paper:
`cooploc reproduce gulati`.
"""

from __future__ import annotations

from cooploc.estimators.factor_graph.batch import (
    FactorGraphParams,
    FgTopologyNew,
    FgTopologyNewParams,
    FgTopologyOld,
    FgTopologyOldParams,
)
from cooploc.estimators.factor_graph.factors import (
    NEW,
    OLD,
    bilinear_topology,
    odometry_topology_variance,
    radar_topology,
    squared_topology,
    topology_jacobians,
)
from cooploc.estimators.factor_graph.graph import FrameFactors, GraphData, GraphProblem
from cooploc.estimators.factor_graph.gtsam_backend import (
    gtsam_factors,
    gtsam_graph,
    gtsam_values,
    solve_gtsam,
    topology_custom_factor,
)
from cooploc.estimators.factor_graph.isam2 import FgIsam2, ISAM2Params
from cooploc.least_squares import LMResult, solve_lm

__all__ = [
    "NEW",
    "OLD",
    "FactorGraphParams",
    "FgIsam2",
    "FgTopologyNew",
    "FgTopologyNewParams",
    "FgTopologyOld",
    "FgTopologyOldParams",
    "FrameFactors",
    "GraphData",
    "GraphProblem",
    "ISAM2Params",
    "LMResult",
    "bilinear_topology",
    "gtsam_factors",
    "gtsam_graph",
    "gtsam_values",
    "odometry_topology_variance",
    "radar_topology",
    "solve_gtsam",
    "solve_lm",
    "squared_topology",
    "topology_custom_factor",
    "topology_jacobians",
]
