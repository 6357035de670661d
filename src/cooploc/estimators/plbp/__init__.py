"""`plbp` and `prior-lbp`: cooperative position and heading estimation from angle of arrival
with posterior-linearization belief propagation.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`; equations restated in `papers/plbp_model_notes.md`),
after García-Fernández, Svensson & Särkkä, IEEE TVT 2018 (PLBP) and IEEE TSP 2015 (PLF).

Vehicle state x_i = [p_x, p_y, α], Gaussian prior (eq. 1); AoA θ_{i←j} =
wrap(atan2(p_j − p_i) − α_i) + w (eqs. 2–5). The AoA rows of a vehicle pair form one
link factor; each link is linearized by statistical linear regression (eqs. 11–22)
w.r.t. the joint posterior approximation (eq. 10), and Gaussian BP in information form
(eqs. 9, 24) runs on the linearized model; Algorithm 1 alternates the two.

Modules, in the order of the algorithm:

- `links` — `LinkFactors`, `link_factors` (rows → links), Gaussian BP on a linearized
  model (`LinkBP`, `gaussian_bp`);
- `linearization` — the SLR of both bearings of a link at the joint posterior
  approximation (`linearize_links`);
- `solve` — Algorithm 1 on one snapshot (`plbp_solve`) and per-iteration errors
  (`iteration_errors`);
- `heading` — the heading of a [p, v] belief from the direction of its velocity
  (`with_velocity_heading`), for scenarios whose state has none (`sumo-*`);
- `estimators` — `PLBP` / `PriorLBP` and their Params: tracking over frames (motion
  prediction, GNSS and anchor fixes) around one solve per frame;
- `_kernels` — the numba kernels, imported on first use (not at package import).

Derivation of the messages and the choices the paper leaves open: docs/plbp.md.
Timings against the number of vehicles: `benchmarks/plbp.py`; accuracy against the
paper: `cooploc reproduce plbp`.
"""

from cooploc.estimators.plbp.estimators import PLBP, PLBPParams, PriorLBP, PriorLBPParams
from cooploc.estimators.plbp.links import LinkFactors, gaussian_bp, link_factors
from cooploc.estimators.plbp.solve import iteration_errors, plbp_solve

__all__ = [
    "PLBP",
    "LinkFactors",
    "PLBPParams",
    "PriorLBP",
    "PriorLBPParams",
    "gaussian_bp",
    "iteration_errors",
    "link_factors",
    "plbp_solve",
]
