"""Algorithm 1 of the PLBP paper on one snapshot: linearize every link, then Gaussian BP.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`, Algorithm 1; `papers/plbp_model_notes.md`), after
García-Fernández, Svensson & Särkkä, IEEE TVT 2018 (PLBP).

    beliefs ← priors;  messages ← 0
    for j in 1..J:                                   # linearization iterations
        for every link: SLR w.r.t. the current joint posterior approximation
            (eq. 10; at j = 1 the product of the priors) → (A, c, Ω)   (eqs. 11–22)
        for l in 1..L:                               # BP on the linearized model
            every message (eq. 24), then every belief (eq. 9)

`plbp` relinearizes at every j (`posterior=True`); `prior-lbp` linearizes once, at the
priors, and runs its J·L BP iterations on that one linear model, so the two are
compared at equal message-passing cost. The first BP iteration after a linearization
reuses the cavities the linearization was computed from.

The heading of a belief is kept unwrapped during one solve (messages in information
form refer to one branch); the estimators wrap it to [−π, π) in their output. A vehicle
in no link keeps its prior exactly.

Complexity: O(J (F (2dx)³ + L F dx³)) for F links, all of it batched over the links
(no Python loop over links or vehicles); per vehicle O(J L |N_i| dx³), as the paper
states.
"""

from __future__ import annotations

import numpy as np

from cooploc.errors import ConfigError
from cooploc.estimators.plbp.linearization import linearize_links
from cooploc.estimators.plbp.links import LinkBP, LinkFactors
from cooploc.gaussian import SIGMA_POINT_METHODS, Gaussians
from cooploc.geometry import wrap_angle
from cooploc.sensors import AngleOfArrival
from cooploc.types import Estimate, FloatArray, StateLayout

__all__ = ["iteration_errors", "plbp_solve"]


def plbp_solve(
    prior: Gaussians,
    links: LinkFactors,
    sensor: AngleOfArrival,
    *,
    linearization_iterations: int = 5,
    bp_iterations: int = 3,
    posterior: bool = True,
    method: str = "unscented",
    central_weight: float = 1.0 / 3.0,
) -> tuple[Gaussians, FloatArray]:
    """Algorithm 1 on one snapshot: (posterior beliefs, means after each iteration (J+1, n, dx)).

    posterior : relinearize every iteration w.r.t. the current joint posterior
        approximation (`plbp`); False: linearize once w.r.t. the priors (`prior-lbp`).
    The heading is not wrapped here (see the module docstring).
    """
    n, dx = prior.mean.shape
    iterates = np.empty((linearization_iterations + 1, n, dx))
    iterates[0] = prior.mean
    if len(links) == 0:
        iterates[1:] = prior.mean
        return prior, iterates
    bp = LinkBP(prior, links)
    if method not in SIGMA_POINT_METHODS:
        raise ConfigError(f"sigma point method must be one of {SIGMA_POINT_METHODS}, got {method!r}")
    w0 = 0.0 if method == "cubature" else central_weight   # cubature = unscented with w₀ = 0
    index = np.asarray(sensor.state_indices, dtype=np.int64)
    model = None
    for j in range(linearization_iterations):
        cavities = None
        if j == 0 or posterior:
            cavities = bp.cavities()
            model = linearize_links(cavities, links, model, index, w0)
        for _ in range(bp_iterations):
            bp.iterate(model.A, model.c, model.noise, model.z, cavities)
            cavities = None
        iterates[j + 1] = bp.beliefs().mean
    out = bp.beliefs()
    # a vehicle in no link keeps its prior exactly (not a round trip through Λ, η)
    isolated = ~np.isin(np.arange(n), np.concatenate([links.a, links.b]))
    mean, cov = out.mean.copy(), out.cov.copy()
    mean[isolated], cov[isolated] = prior.mean[isolated], prior.cov[isolated]
    iterates[:, isolated] = prior.mean[isolated]
    return Gaussians(mean, cov), iterates


def iteration_errors(estimate: Estimate, true_states: FloatArray, layout: StateLayout
                     ) -> tuple[FloatArray, FloatArray]:
    """Position and wrapped heading errors (J+1, n) of `info["iterate_means"]`.

    true_states : (n, dx) in the order of `estimate.vehicles.ids`.
    """
    means = np.asarray(estimate.info["iterate_means"])
    pos = list(layout.position)
    err_pos = np.linalg.norm(means[..., pos] - true_states[None, :, pos], axis=-1)
    if layout.heading is None:
        return err_pos, np.full(err_pos.shape, np.nan)
    err_heading = np.abs(wrap_angle(means[..., layout.heading] - true_states[None, :, layout.heading]))
    return err_pos, err_heading
