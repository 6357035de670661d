"""Data association by loopy belief propagation (Williams & Lau), vectorised over sensors.

Model (one sensor; Fröhle 2018 §III-A eqs. (4)–(6), generalised as in Williams & Lau,
IEEE TAES 2014, Fröhle's ref. [7]): K features, M measurements. Feature k either generates
one measurement, a_k = m ∈ {1..M}, or is missed, a_k = 0; measurement m either comes
from one feature, b_m = k, or is clutter, b_m = 0; the two descriptions must agree
(the indicator Ψ of eq. (6)). The joint association probability is

    p(a) ∝ Π_k ψ_k(a_k) · Π_{m unused} κ_m,
    ψ_k(0) = 1 − P_D,   ψ_k(m) = P_D · L_{k,m},   κ_m = λ · c(z_m),

where L_{k,m} = ∫ p(z_m | state) belief(state) is the predicted likelihood (the β of
Fröhle eq. (14)), λ the Poisson clutter rate and c the clutter density (uniform over a
region: 1 / area). The paper's one-to-one case is P_D = 1, λ = 0, M = K.

Loopy BP on the a–b graph (Fröhle eqs. (15)–(20), in the simplified ratio form of
Williams & Lau): with ν ≡ 1 initially (δ ≡ 1, eq. (16)), iterate p = 1..P

    μ_{k→m} = ψ_k(m) / (ψ_k(0) + Σ_{m'≠m} ψ_k(m') ν_{m'→k})        (eqs. (17), (19))
    ν_{m→k} = 1 / (κ_m + Σ_{k'≠k} μ_{k'→m})                        (eq. (18))

`ν_{m→k}` is the message η_k(a_k = m) / η_k(a_k = 0) of eq. (20). Marginals:
P(a_k = m) ∝ ψ_k(m) ν_{m→k}, P(a_k = 0) ∝ ψ_k(0); P(b_m = k) ∝ μ_{k→m}, P(b_m = 0) ∝ κ_m.
With κ ≡ 1 this is exactly Williams & Lau's form; a per-measurement κ is the same
model with column m of ψ divided by κ_m. On a tree (K = 1 or M = 1) BP is exact;
with miss and clutter options the iterations converge (Williams & Lau 2010, Fröhle's
ref. [15]).

Numerical safety. Inputs are logs (−inf allowed: an impossible hypothesis). Rows and
columns are rescaled by their maxima (each feature takes exactly one option and each
measurement exactly one, so both rescalings leave p(a) unchanged), then the miss and
clutter weights are floored at `FLOOR` times their row / column maximum, so that
"every feature missed, every measurement clutter" is always admissible and every
denominator is positive; for P_D = 1 and λ = 0 this perturbs the marginals by about
`FLOOR`. The returned messages `log_nu` are in the caller's original scale.

Batches. Many sensors are processed at once: arrays lead with a batch dimension B and
ragged sizes are padded and marked by masks; padded features / measurements take no
part and their marginals come back as 0 (`padded_groups` builds the padding).

Complexity: O(B K M) per iteration, all in NumPy. `exact_marginals` enumerates every
admissible association: O(Σ_{n ≤ min(K,M)} C(K,n) M!/(M−n)!) — tests only.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cooploc.errors import InvalidInputError
from cooploc.particles import log_sum_exp
from cooploc.types import FloatArray, IntArray

__all__ = [
    "FLOOR",
    "AssociationMarginals",
    "association_weights",
    "bp_association",
    "decide",
    "enumerate_associations",
    "exact_marginals",
    "gated_pairs",
    "padded_groups",
    "pair_components",
    "unexplained_rows",
]

#: Smallest relative weight of the miss / clutter options (see module docstring).
FLOOR = 1e-9


@dataclass(frozen=True, slots=True)
class AssociationMarginals:
    """Marginal association probabilities of a batch of B sensors.

    Attributes
    ----------
    feature : (B, K, M) P(a_k = m), feature k generated measurement m.
    missed : (B, K) P(a_k = 0), feature k was not detected.
    measurement : (B, M, K) P(b_m = k), measurement m originated from feature k.
    clutter : (B, M) P(b_m = 0), measurement m is clutter.
    log_nu : (B, K, M) log of the BP message ν_{m→k} = η_k(m) / η_k(0) (eq. (20)) in the
        caller's scale (−inf where ψ_k(m) = 0 or padded).
    iterations : iterations run.
    """

    feature: FloatArray
    missed: FloatArray
    measurement: FloatArray
    clutter: FloatArray
    log_nu: FloatArray
    iterations: int


def association_weights(
    log_likelihood: npt.ArrayLike,
    detection_probability: float,
    clutter_intensity: float | npt.ArrayLike,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Log weights (log ψ (…, K, M), log ψ(0) (…, K), log κ (…, M)) of the model above.

    Parameters
    ----------
    log_likelihood : (…, K, M) log L_{k,m}, predicted likelihood of measurement m under
        feature k (1/m^dz).
    detection_probability : P_D in (0, 1].
    clutter_intensity : λ c(z), clutter rate times clutter density (1/m^dz); scalar or
        (…, M). 0 for no clutter.
    """
    log_likelihood = np.asarray(log_likelihood, dtype=float)
    if not 0.0 < detection_probability <= 1.0:
        raise InvalidInputError(f"detection_probability must lie in (0, 1], got {detection_probability!r}")
    intensity = np.asarray(clutter_intensity, dtype=float)
    if (intensity < 0).any() or not np.isfinite(intensity).all():
        raise InvalidInputError(f"clutter_intensity must be finite and >= 0, got {clutter_intensity!r}")
    with np.errstate(divide="ignore"):
        log_psi = np.log(detection_probability) + log_likelihood
        log_missed = np.full(log_likelihood.shape[:-1], np.log1p(-detection_probability)
                             if detection_probability < 1 else -np.inf)
        log_kappa = np.broadcast_to(np.log(intensity), log_likelihood.shape[:-2]
                                    + log_likelihood.shape[-1:]).copy()
    return log_psi, log_missed, log_kappa


def _as_batch(log_psi: npt.ArrayLike, log_missed: npt.ArrayLike, log_clutter: npt.ArrayLike
              ) -> tuple[FloatArray, FloatArray, FloatArray, bool]:
    log_psi = np.asarray(log_psi, dtype=float)
    single = log_psi.ndim == 2
    if log_psi.ndim not in (2, 3):
        raise InvalidInputError(f"log_psi must have shape (B, K, M) or (K, M), got {log_psi.shape}")
    log_psi = log_psi[None] if single else log_psi
    B, K, M = log_psi.shape
    log_missed = np.asarray(log_missed, dtype=float)
    log_clutter = np.asarray(log_clutter, dtype=float)
    log_missed = log_missed[None] if single and log_missed.ndim == 1 else log_missed
    log_clutter = log_clutter[None] if single and log_clutter.ndim == 1 else log_clutter
    if log_missed.shape != (B, K):
        raise InvalidInputError(f"log_missed must have shape {(B, K)}, got {log_missed.shape}")
    if log_clutter.shape != (B, M):
        raise InvalidInputError(f"log_clutter must have shape {(B, M)}, got {log_clutter.shape}")
    for name, value in (("log_psi", log_psi), ("log_missed", log_missed), ("log_clutter", log_clutter)):
        if np.isnan(value).any() or np.isposinf(value).any():
            raise InvalidInputError(f"{name} must be finite or -inf, got {value}")
    return log_psi, log_missed, log_clutter, single


def _ratio_form(log_psi: FloatArray, log_missed: FloatArray, log_clutter: FloatArray
                ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Rescaled, floored weights (ψ, ψ0, κ) in (0, 1] and the column log-scales."""
    # rows: a feature picks exactly one option, so a common factor per row cancels
    row = np.maximum(log_missed, log_psi.max(axis=2, initial=-np.inf))
    row = np.where(np.isfinite(row), row, 0.0)
    log_psi = log_psi - row[:, :, None]
    log_missed = log_missed - row
    # columns: a measurement has exactly one origin
    col = np.maximum(log_clutter, log_psi.max(axis=1, initial=-np.inf))
    col = np.where(np.isfinite(col), col, 0.0)
    log_psi = log_psi - col[:, None, :]
    log_clutter = log_clutter - col
    # floors: "missed" and "clutter" always admissible, every denominator > 0
    log_floor = np.log(FLOOR)
    row_best = log_psi.max(axis=2, initial=-np.inf)
    log_missed = np.maximum(log_missed, np.where(np.isfinite(row_best), row_best + log_floor, 0.0))
    col_best = log_psi.max(axis=1, initial=-np.inf)
    log_clutter = np.maximum(log_clutter, np.where(np.isfinite(col_best), col_best + log_floor, 0.0))
    return np.exp(log_psi), np.exp(log_missed), np.exp(log_clutter), col


def bp_association(
    log_psi: npt.ArrayLike,
    log_missed: npt.ArrayLike,
    log_clutter: npt.ArrayLike,
    n_iterations: int = 5,
    tol: float | None = None,
    feature_mask: npt.ArrayLike | None = None,
    measurement_mask: npt.ArrayLike | None = None,
) -> AssociationMarginals:
    """Marginal association probabilities by loopy BP, for a batch of sensors.

    Parameters
    ----------
    log_psi : (B, K, M) or (K, M) log ψ_k(m) (see `association_weights`); −inf pads.
    log_missed : (B, K) log ψ_k(0) = log(1 − P_D) (−inf for P_D = 1 or a padded feature).
    log_clutter : (B, M) log κ_m = log(λ c(z_m)) (−inf for no clutter or a padded row).
    n_iterations : P, number of ν-updates (Fröhle default 5); at least 1.
    tol : stop early once no ν changes by more than `tol` relative (None: run all P).
    feature_mask, measurement_mask : (B, K), (B, M) real entries (default: all); padded
        ones take no part and get zero probabilities.

    Returns
    -------
    AssociationMarginals (batch dimension dropped again if the input had none).
    """
    if int(n_iterations) != n_iterations or n_iterations < 1:
        raise InvalidInputError(f"n_iterations must be a positive integer, got {n_iterations!r}")
    lpsi, lmiss, lclut, single = _as_batch(log_psi, log_missed, log_clutter)
    B, K, M = lpsi.shape
    fmask = np.ones((B, K), bool) if feature_mask is None else np.asarray(feature_mask, bool).reshape(B, K)
    mmask = (np.ones((B, M), bool) if measurement_mask is None
             else np.asarray(measurement_mask, bool).reshape(B, M))
    lpsi = np.where(fmask[:, :, None] & mmask[:, None, :], lpsi, -np.inf)
    lmiss = np.where(fmask, lmiss, -np.inf)
    lclut = np.where(mmask, lclut, -np.inf)
    psi, psi0, kappa, col = _ratio_form(lpsi, lmiss, lclut)

    nu = np.ones((B, K, M))                                    # δ ≡ 1, eq. (16)
    done = 0
    for done in range(1, int(n_iterations) + 1):               # noqa: B007 (count kept)
        # μ_{k→m} = ψ_k(m) / (ψ_k(0) + Σ_{m'≠m} ψ_k(m') ν_{m'→k})   eqs. (17), (19)
        pn = psi * nu
        rest = np.maximum(psi0[:, :, None] + pn.sum(axis=2, keepdims=True) - pn, psi0[:, :, None])
        mu = psi / rest
        # ν_{m→k} = 1 / (κ_m + Σ_{k'≠k} μ_{k'→m})                   eq. (18)
        others = np.maximum(kappa[:, None, :] + mu.sum(axis=1, keepdims=True) - mu, kappa[:, None, :])
        new_nu = 1.0 / others
        change = np.abs(new_nu - nu).max(initial=0.0) / max(np.abs(new_nu).max(initial=0.0), 1e-300)
        nu = new_nu
        if tol is not None and change <= tol:
            break

    # μ consistent with the final ν, for the measurement marginals
    pn = psi * nu
    rest = np.maximum(psi0[:, :, None] + pn.sum(axis=2, keepdims=True) - pn, psi0[:, :, None])
    mu = psi / rest
    feat_norm = psi0 + pn.sum(axis=2)
    feature = pn / feat_norm[:, :, None]
    missed = psi0 / feat_norm
    meas_norm = kappa + mu.sum(axis=1)
    measurement = (mu / meas_norm[:, None, :]).transpose(0, 2, 1)
    clutter = kappa / meas_norm
    # padded entries: no probability
    missed = np.where(fmask, missed, 0.0)
    clutter = np.where(mmask, clutter, 0.0)
    with np.errstate(divide="ignore"):
        # back to the caller's scale: column m was divided by exp(col_m), so ν was multiplied
        log_nu = np.where(psi > 0, np.log(nu) - col[:, None, :], -np.inf)
    out = AssociationMarginals(feature, missed, measurement, clutter, log_nu, done)
    if single:
        out = AssociationMarginals(feature[0], missed[0], measurement[0], clutter[0], log_nu[0], done)
    return out


def decide(marginals: AssociationMarginals, threshold: float = 0.5,
           one_to_one: bool = False) -> IntArray:
    """Decided origin of every measurement: feature index, or -1 (clutter / undecided).

    MAP per measurement over {clutter, features}; a feature whose probability is below
    `threshold` is not trusted (-1). With `one_to_one`, the decisions of one sensor form
    the most probable consistent assignment (no feature takes two measurements):
    `scipy.optimize.linear_sum_assignment` on −log of the marginals, each measurement
    allowed to be clutter; the threshold then applies to the assigned pairs.

    Returns (B, M) (or (M,) for an unbatched input).
    """
    P, clutter = marginals.measurement, marginals.clutter
    single = P.ndim == 2
    P, clutter = (P[None], clutter[None]) if single else (P, clutter)
    B, M, K = P.shape
    if not K:
        out = np.full((B, M), -1, dtype=np.int64)
    elif not one_to_one:
        best = P.argmax(axis=2)
        p_best = np.take_along_axis(P, best[:, :, None], axis=2)[:, :, 0]
        out = np.where((p_best > clutter) & (p_best >= threshold), best, -1).astype(np.int64)
    else:
        from scipy.optimize import linear_sum_assignment

        out = np.full((B, M), -1, dtype=np.int64)
        with np.errstate(divide="ignore"):
            cost_f, cost_c = -np.log(P), -np.log(clutter)
        big = 1e12
        for b in range(B):  # one small assignment problem per sensor
            cost = np.full((M, K + M), big)
            cost[:, :K] = np.minimum(cost_f[b], big)
            cost[np.arange(M), K + np.arange(M)] = np.minimum(cost_c[b], big)
            rows, cols = linear_sum_assignment(cost)
            take = (cols < K) & (P[b, rows, np.minimum(cols, K - 1)] >= threshold)
            out[b, rows[take]] = cols[take]
    return out[0] if single else out


def enumerate_associations(n_features: int, n_measurements: int) -> IntArray:
    """Every admissible association a (n_hyp, K): a[k] = measurement index or -1 (missed).

    No two features share a measurement. For tests of small cases only.
    """
    if n_features == 0:
        return np.zeros((1, 0), dtype=np.int64)  # one association: nothing to assign
    rows = []
    for n in range(min(n_features, n_measurements) + 1):
        for feats in itertools.combinations(range(n_features), n):
            for meas in itertools.permutations(range(n_measurements), n):
                a = np.full(n_features, -1, dtype=np.int64)
                a[list(feats)] = meas
                rows.append(a)
    return np.array(rows, dtype=np.int64).reshape(-1, n_features)


def exact_marginals(log_psi: npt.ArrayLike, log_missed: npt.ArrayLike,
                    log_clutter: npt.ArrayLike) -> AssociationMarginals:
    """Exact marginals of one sensor (K, M) by enumerating every association (no floors)."""
    log_psi = np.asarray(log_psi, dtype=float)
    log_missed = np.asarray(log_missed, dtype=float)
    log_clutter = np.asarray(log_clutter, dtype=float)
    K, M = log_psi.shape
    hyp = enumerate_associations(K, M)                                  # (H, K)
    k_idx = np.arange(K)
    term = np.where(hyp >= 0, log_psi[k_idx, np.maximum(hyp, 0)], log_missed[k_idx])
    used = np.zeros((hyp.shape[0], M), dtype=bool)
    h_idx, f_idx = np.nonzero(hyp >= 0)
    used[h_idx, hyp[h_idx, f_idx]] = True
    with np.errstate(invalid="ignore"):
        log_w = term.sum(axis=1) + np.where(used, 0.0, log_clutter[None, :]).sum(axis=1)
    log_w = log_w - log_sum_exp(log_w, axis=None)
    w = np.exp(log_w)
    feature = np.zeros((K, M))
    for m in range(M):
        feature[:, m] = (w[:, None] * (hyp == m)).sum(axis=0)
    missed = (w[:, None] * (hyp < 0)).sum(axis=0)
    clutter = (w[:, None] * ~used).sum(axis=0)
    return AssociationMarginals(feature, missed, feature.T.copy(), clutter,
                                np.full((K, M), np.nan), 0)


def padded_groups(group: npt.ArrayLike, n_groups: int) -> tuple[IntArray, npt.NDArray[np.bool_]]:
    """Pad a ragged grouping of rows: index (n_groups, width) of the rows of each group.

    `group (n,)` gives the group (e.g. sensing vehicle position) of each row, in
    [0, n_groups). Returns `index` (n_groups, width) with the rows of group g in their
    original order, padded with 0, and `mask` marking the real entries.
    """
    group = np.asarray(group, dtype=np.int64)
    if group.size and (group.min() < 0 or group.max() >= n_groups):
        raise InvalidInputError(f"group must lie in [0, {n_groups}), got {group}")
    counts = np.bincount(group, minlength=n_groups)
    width = int(counts.max(initial=0))
    order = np.argsort(group, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    slot = np.arange(group.size) - np.repeat(starts, counts)
    index = np.zeros((n_groups, width), dtype=np.int64)
    mask = np.zeros((n_groups, width), dtype=bool)
    index[group[order], slot] = order
    mask[group[order], slot] = True
    return index, mask


def unexplained_rows(cost: FloatArray, n: int) -> IntArray:
    """The `n` rows that the tracks explain least, for births: cost (M, J) of row m on track j
    (e.g. squared Mahalanobis distances). The rows an optimal one-to-one assignment
    (`scipy.optimize.linear_sum_assignment`) leaves over are the unexplained ones; of those
    (of all rows where fewer are left), the `n` with the largest cost to their nearest track.
    """
    from scipy.optimize import linear_sum_assignment

    M = cost.shape[0]
    free = np.ones(M, dtype=bool)
    nearest = np.zeros(M)
    if cost.shape[1]:
        assigned, _ = linear_sum_assignment(cost)
        free[assigned] = False
        nearest = cost.min(axis=1)
    candidates = np.flatnonzero(free) if free.sum() >= n else np.arange(M)
    return candidates[np.argsort(-nearest[candidates], kind="stable")[:n]]


def gated_pairs(means: FloatArray, covs: FloatArray, owners: IntArray, gate: float,
                position: tuple[int, ...] = (0, 1), *, inclusive: bool = False
                ) -> tuple[IntArray, IntArray, FloatArray]:
    """(i, j, d²), sorted by (i, j), i < j, of the pairs of Gaussian points (means (n, d),
    covs (n, d, d)) from different `owners` within the gate: d² = Δᵀ (C_i + C_j)⁻¹ Δ < gate
    (≤ with `inclusive`).

    Found with a k-d tree over the `position` components, not among all n² pairs: the
    Mahalanobis distance of a part is at most that of the whole, so d² ≥ ‖Δp‖² /
    λ_max((C_i + C_j)_pp), and λ_max of a sum is at most 2 max λ_max(C_pp); only pairs
    within √(gate · 2 max λ_max(C_pp)) can pass, the same pairs as the full triangle gives.
    """
    from cooploc.geometry import links_within

    empty = np.zeros(0, dtype=np.int64)
    if owners.size < 2:
        return empty, empty, np.zeros(0)
    p = list(position)
    spread = np.linalg.eigvalsh(covs[:, p][:, :, p])[:, -1].max()
    i, j = links_within(np.arange(owners.size), means[:, p], np.sqrt(gate * 2.0 * spread) * (1.0 + 1e-9)).T
    ok = owners[i] != owners[j]
    i, j = i[ok], j[ok]
    diff = means[i] - means[j]
    d2 = np.einsum("pi,pi->p", diff, np.linalg.solve(covs[i] + covs[j], diff[..., None])[..., 0])
    keep = d2 <= gate if inclusive else d2 < gate
    return i[keep], j[keep], d2[keep]


def pair_components(n: int, i: IntArray, j: IntArray) -> IntArray:
    """(n,) label of the connected component of each of n nodes joined by the pairs (i, j)."""
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)
