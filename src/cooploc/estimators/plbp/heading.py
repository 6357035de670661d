"""The heading of a [p, v] vehicle belief from the direction of its velocity, for the AoA links.

Paper: "Cooperative Localization with Angular Measurements and Posterior Linearization"
(`papers/002_dfdb230c2e4252cd.txt`, `papers/plbp_model_notes.md`): the AoA θ_{i←j} =
wrap(atan2(p_j − p_i) − α_i) + w is relative to the receiver's heading α_i, a state
component of the paper's x_i = [p_x, p_y, α]. Scenarios whose vehicle state is
[p_x, p_y, v_x, v_y] (the `sumo-*` family) carry no heading; their AoA model reads the
heading as the component after the layout (`state_indices` (0, 1, 4)).

Model (our choice; the paper tracks no velocity): a road vehicle moves along its heading,
so α = atan2(v_y, v_x) + s, s ~ N(0, σ_s²) the angle between heading and velocity
(side slip, lane changes; SUMO's velocity is speed · (cos α, sin α), s = 0, and σ_s
only keeps the joint covariance regular). The joint Gaussian of [x; α] is the
statistical linear regression of atan2 w.r.t. the belief N(μ, P) of x (García-Fernández
et al., IEEE TSP 2015, eqs. 17–22, as `gaussian.statistical_linear_regression`):
α ≈ A x + c + e, e ~ N(0, Ω + σ_s²), so

    mean [μ; A μ + c],   cov [[P, P Aᵀ], [A P, A P Aᵀ + Ω + σ_s²]].

The cross-covariance P Aᵀ is what lets an AoA update of α reach the velocity (and,
through the belief's own correlations, the position) once α is marginalised out again.
A vehicle that may stand (`standing`: its velocity belief does not exclude v = 0, the
χ²₂ test at level 0.01) has no heading in this model: a standing vehicle's heading is that
of the road it stopped on, not the direction of a velocity that is noise. The regression
still gives it a spread heading, but not spread enough — on sumo-berlin-tlr the heading
NEES of vehicles slower than 0.1 m/s was 5.5 (error 1.55 rad on average, uniform) against
0.7 for moving ones — so the estimators leave the AoA rows such a vehicle measures out
(`PLBP._moving_receivers`; a bearing relative to a uniform heading is uniform: the exact
marginal), while the rows others take of it still place it. The sigma points' headings are put on the branch
of atan2 at the mean before averaging (eq. 15).

Complexity: O(n d³) for n beliefs of dimension d, batched.
"""

from __future__ import annotations

import numpy as np

from cooploc.gaussian import Gaussians, statistical_linear_regression, symmetrize
from cooploc.types import FloatArray

__all__ = ["STANDING_CHI2", "standing", "with_velocity_heading"]

# the test of v = 0 at level 0.01: the χ²₂ quantile 0.99, −2 ln 0.01 (= scipy.stats.chi2.ppf(0.99, 2))
STANDING_CHI2 = -2.0 * np.log(0.01)


def standing(beliefs: Gaussians, velocity: tuple[int, ...]) -> np.ndarray:
    """(n,) bool: the velocity belief does not exclude v = 0 (v̂ᵀ P_v⁻¹ v̂ < χ²₂,0.99).

    Such a vehicle may stand, and a standing vehicle's heading is not the direction of a
    velocity: it is unknown.
    """
    v = beliefs.mean[:, list(velocity)]
    Pv = beliefs.cov[:, list(velocity)][:, :, list(velocity)]
    return np.einsum("ni,ni->n", v, np.linalg.solve(Pv, v[..., None])[..., 0]) < STANDING_CHI2


def with_velocity_heading(beliefs: Gaussians, velocity: tuple[int, ...], slip_variance: float, *,
                          method: str = "unscented", central_weight: float = 1.0 / 3.0) -> Gaussians:
    """Beliefs of [x; α] (n, d + 1) with α = atan2(v_y, v_x) + s, s ~ N(0, `slip_variance`).

    beliefs : n Gaussians of x (d components); velocity : indices of (v_x, v_y) in x.
    The heading's mean lies on the branch of atan2 at the mean velocity (not wrapped).
    """
    n, d = beliefs.mean.shape
    if n == 0:
        return Gaussians(np.zeros((0, d + 1)), np.zeros((0, d + 1, d + 1)))
    vx, vy = velocity

    def direction(x: FloatArray) -> FloatArray:
        return np.arctan2(x[..., vy], x[..., vx])[..., None]

    A, c, Omega = statistical_linear_regression(beliefs.mean, beliefs.cov, direction, method=method,
                                                angular=(True,), central_weight=central_weight)
    P = beliefs.cov
    PAt = P @ np.swapaxes(A, -1, -2)                                          # (n, d, 1)
    mean = np.concatenate([beliefs.mean, (A @ beliefs.mean[..., None])[..., 0] + c], axis=1)
    cov = np.zeros((n, d + 1, d + 1))
    cov[:, :d, :d] = P
    cov[:, :d, d:] = PAt
    cov[:, d:, :d] = np.swapaxes(PAt, -1, -2)
    cov[:, d:, d:] = A @ PAt + Omega + slip_variance                          # A P Aᵀ + Ω + σ_s²
    return Gaussians(mean, symmetrize(cov))
