"""Where a vehicle is, from its own V2F rows and the tracks it holds: the belief that
`icp-da-lc`'s association likelihood (13) integrates over (Brambilla et al. 2020).

Why. Eq. (13) scores each pairing (row ℓ, track k) of vehicle i on its own,

    η(α_ik = ℓ) = N(z_ℓ; m_k − m_i, R_ℓ + P_i + P_k),

with x_i integrated out separately for every pair, and the BPA-DA (14)–(17) then
treats the rows of one vehicle as independent given the association. They are not:
all of them are relative to the same x_i. While P_i is small against the spacing of
the tracks this does not matter; when it is not, each row picks the track nearest to
z_ℓ + m_i and the set of pairings need not fit any single vehicle position. Two cases
in SUMO traffic (measured on `sumo-grid-tlr`, docs/icp.md):

- a vehicle that enters in GNSS zone C (σ = 15 m) is often 20–36 m off; among poles
  10–30 m apart its rows went to tracks that disagree with each other by tens of
  metres, and the stiff V2F rows (σ = 0.1 m) then pulled whole groups of vehicles
  ~10 m off in the BPA-L;
- a GNSS-only filter that has just turned a corner claims 1 m and is 7 m off (the
  constant-velocity prediction); the right tracks fall outside its η and every row
  starts a duplicate feature.

What. Before (13) each vehicle locates itself against the tracks it holds, from its
own rows only (no message is exchanged). A hypothesis h = (ℓ, k), "row ℓ is track
k's", places the vehicle at y_h = m_k − z_ℓ with covariance C_h = R_ℓ + P_k. Given h,
every other row ℓ' either comes from one of the tracks (probability P_D each,
likelihood N(z_ℓ'; m_k' − y_h, R_ℓ' + P_k' + C_h)) or from a new feature (intensity
λ), and every track that no row fits went undetected (fitted are the pivot's track
and, for each other row, the track with its largest term if that beats a new
feature), which has probability 1 − P_D π_k'(y_h), π_k'(x) = P(‖m_k' − x‖ ≤ R_s) the
chance that the track was in sensing range (Gaussian in the distance, variance half
the summed position traces; 1 without a range). The score of h is the log-ratio of this joint likelihood
to that of "every row new", the vehicle where b_i^(0) says:

    s_h = log η(α_ik = ℓ) + log(P_D/λ)
          + Σ_{ℓ' ≠ ℓ} log(1 + Σ_k' (P_D/λ) N(z_ℓ'; m_k' − y_h, R_ℓ' + P_k' + C_h))
          + Σ_{k' not fitted} log(1 − P_D π_k'(y_h)),
    s_0 = Σ_k' log(1 − P_D π_k'(m_i)).

The last term is the evidence of the tracks that should have been seen: without it, on
one of 24 runs of the tiny test grid (`sumo-grid-tlr` with `TINY_GRID`), rows that
happened to fit two tracks 31 m down the street moved a vehicle (σ = 8 m) there,
although the other tracks in range of that place went unseen. b_i^(0) enters once,
through the pivot's own η (13); the other rows are placed by the pivot alone, i.e. by
the geometry of the rows relative to each other, which does not depend on x_i.
(Conditioning them on b_i^(0) as well — the chain rule for a consistent prior — was
worse where the GNSS-only filter is confidently wrong after a turn: `sumo-grid-vsr`
1.85 against 1.69 m, `icp` 1.63 m.) The exclusion (one row per track) is left to the
BPA-DA that follows, and a hypothesis is scored by each of its pivots, not summed over
them.

If the best score exceeds s_0 the vehicle is registered: the rows that fit the best
hypothesis better than a new feature does, each with its best track, and the pivot row
with its track, are the vehicle's matched rows; its belief is b_i^(0) updated with
them as measurements of its state, y = m_k − z_ℓ with covariance R_ℓ + P_k
(information form). Row ℓ's (13) uses that belief without row ℓ's own term
(leave one out), so that no row is counted in its own likelihood; unmatched rows get
the whole belief. An unregistered vehicle keeps b_i^(0) — eq. (13) as the paper
writes it (b_i^(0) being the GNSS-only filter here; see `icp`).

Two shortcuts, exact up to the stated bound:

- pivots that could not score above s_0 even if every other row matched perfectly are
  skipped: row ℓ' adds at most log(1 + (P_D/λ) N(0; 0, R_ℓ')), since the covariance
  of its term is at least R_ℓ';
- a term (ℓ', k') whose position residual r satisfies |r|² > `TERM_GATE` ·
  tr(S_pos) is dropped: its squared Mahalanobis distance then exceeds `TERM_GATE`, so
  the term is below e^{−TERM_GATE/2} of its peak.

Cost per step and agent: O(H W F) distance tests for H pivots (pairs within the
bound), W rows and F tracks held, and one small Gaussian per surviving term.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cooploc.gaussian import (
    Gaussians,
    from_information,
    gaussian_logpdf,
    spd_inverse_and_product,
    to_information,
)
from cooploc.particles import log_sum_exp
from cooploc.types import FloatArray, IntArray

__all__ = ["TERM_GATE", "Registration", "register_vehicles"]

#: squared Mahalanobis distance beyond which a (row, track) term of a score is dropped:
#: e^{−20} of its peak
TERM_GATE = 40.0
#: pivots × tracks × rows scored at once (bounds the memory of a step, ~100 MB)
_BLOCK = 1 << 21


@dataclass(frozen=True)
class Registration:
    """The vehicle belief each row's association likelihood (13) integrates over.

    Attributes
    ----------
    beliefs : mean (n, W, d) and cov (n, W, d, d): for a registered vehicle, its prior
        updated with its matched rows other than this one; otherwise its prior.
    registered : (n,) whether the vehicle found a hypothesis better than s_0 (every row new).
    matched : (n, W) the track (column) each row fits under the best hypothesis, −1 for
        none or an unregistered vehicle.
    """

    beliefs: Gaussians
    registered: np.ndarray
    matched: IntArray


def register_vehicles(prior: Gaussians, z: FloatArray, R: FloatArray, mask: np.ndarray,
                      tracks: Gaussians, known: np.ndarray, log_eta: FloatArray,
                      detection_probability: float, new_feature_intensity: float,
                      position: Sequence[int], max_range: float = np.inf) -> Registration:
    """Register every vehicle against the tracks it holds (module docstring).

    Parameters
    ----------
    prior : b_i^(0), mean (n, d), cov (n, d, d).
    z, R : (n, W, d), (n, W, d, d) each vehicle's V2F rows, padded (`mask` (n, W) marks
        the real ones; padded covariances must still be positive definite).
    tracks : the vehicles' copies of the tracks, mean (n, F, d), cov (n, F, d, d),
        meaningful where `known` (n, F).
    log_eta : (n, F, W) log η of eq. (13) with the prior, −inf where not a pair.
    detection_probability, new_feature_intensity : P_D and λ of the association model.
    position : indices of the position components in the state.
    max_range : the V2F sensing range R_s (m); a track farther from the vehicle cannot be
        detected, so its not being detected says nothing.
    """
    n, W, d = z.shape
    log_ratio = np.log(detection_probability) - np.log(new_feature_intensity)
    prior_beliefs = Gaussians(np.repeat(prior.mean[:, None], W, 1), np.repeat(prior.cov[:, None], W, 1))
    unregistered = Registration(prior_beliefs, np.zeros(n, dtype=bool), np.full((n, W), -1, dtype=np.int64))
    if n == 0 or W == 0 or not known.any():
        return unregistered
    pos = list(position)
    track_spread = np.trace(tracks.cov[..., pos, :][..., pos], axis1=-2, axis2=-1)      # (n, F)
    # the null hypothesis: the vehicle where b_i^(0) says, every row new, every track missed
    null = np.where(known, np.log1p(-detection_probability * _in_range(
        tracks.mean[..., pos] - prior.mean[:, None, pos],
        track_spread + np.trace(prior.cov[:, pos][:, :, pos], axis1=-2, axis2=-1)[:, None],
        max_range)), 0.0).sum(axis=1)                                                    # (n,)
    # the most a row can add to a score: its term with the smallest covariance, R
    peak = np.where(mask, np.logaddexp(0.0, log_ratio + gaussian_logpdf(np.zeros((n, W, d)), R)), 0.0)
    rest = peak.sum(axis=1, keepdims=True) - peak                          # (n, W) all other rows
    pa, pf, pw = np.nonzero(np.isfinite(log_eta)
                            & (log_eta + log_ratio + rest[:, None, :] > null[:, None, None]))
    if pa.size == 0:
        return unregistered
    score = np.zeros(pa.size)
    fits, fitted = np.zeros((pa.size, W), dtype=bool), np.zeros((pa.size, W), dtype=np.int64)
    block = max(1, _BLOCK // max(known.shape[1] * W, 1))     # bounded memory: pivots in blocks
    for lo in range(0, pa.size, block):
        h = slice(lo, lo + block)
        score[h], fits[h], fitted[h] = _scores(pa[h], pf[h], pw[h], z, R, mask, tracks, known, log_eta,
                                               track_spread, log_ratio, detection_probability, pos,
                                               max_range)
    # the best pivot of each vehicle, if it beats the null hypothesis
    order = np.lexsort((-score, pa))
    first = np.ones(order.size, dtype=bool)
    first[1:] = pa[order[1:]] != pa[order[:-1]]
    star = order[first]
    star = star[score[star] > null[pa[star]]]
    if star.size == 0:
        return unregistered
    agent = pa[star]
    matched = np.full((n, W), -1, dtype=np.int64)
    matched[agent] = np.where(fits[star], fitted[star], -1)
    matched[agent, pw[star]] = pf[star]
    # the registered belief: b_i^(0) and the matched rows as measurements of x_i
    ma, mw = np.nonzero(matched >= 0)
    mf = matched[ma, mw]
    row_Lam = np.zeros((n, W, d, d))
    row_eta = np.zeros((n, W, d))
    row_Lam[ma, mw] = spd_inverse_and_product(R[ma, mw] + tracks.cov[ma, mf], z[ma, mw])[0]  # (R + P_k)⁻¹
    Lam0, eta0 = to_information(prior)
    row_eta[ma, mw] = np.einsum("mij,mj->mi", row_Lam[ma, mw], tracks.mean[ma, mf] - z[ma, mw])
    Lam = Lam0[agent][:, None] + row_Lam[agent].sum(axis=1, keepdims=True) - row_Lam[agent]
    eta = eta0[agent][:, None] + row_eta[agent].sum(axis=1, keepdims=True) - row_eta[agent]
    beliefs = from_information(Lam, eta)                                     # leave-one-out, (S, W)
    mean, cov = prior_beliefs.mean, prior_beliefs.cov
    mean[agent], cov[agent] = beliefs.mean, beliefs.cov
    registered = np.zeros(n, dtype=bool)
    registered[agent] = True
    return Registration(Gaussians(mean, cov), registered, matched)


def _scores(pa: IntArray, pf: IntArray, pw: IntArray, z: FloatArray, R: FloatArray, mask: np.ndarray,
            tracks: Gaussians, known: np.ndarray, log_eta: FloatArray, track_spread: FloatArray,
            log_ratio: float, detection_probability: float, pos: list[int], max_range: float
            ) -> tuple[FloatArray, np.ndarray, IntArray]:
    """s_h of pivots h = (agent pa, track pf, row pw) (module docstring), whether each row
    fits a track under h (H, W) and which (H, W)."""
    H, W = pa.size, mask.shape[1]
    # the vehicle given pivot h, from the pivot alone: N(y_h, C_h), y_h = m_k − z_ℓ, C_h = R_ℓ + P_k
    given = Gaussians(tracks.mean[pa, pf] - z[pa, pw], R[pa, pw] + tracks.cov[pa, pf])
    score = log_eta[pa, pf, pw] + log_ratio
    best_track = np.full((H, W), -1, dtype=np.int64)
    best_term = np.full((H, W), -np.inf)
    held_at = tracks.mean[pa][:, :, pos]                                                 # (H, F, p)
    # tr of the position blocks: |r|² > G tr(S_pos) implies a Mahalanobis distance > G
    spread = track_spread[pa] + np.trace(given.cov[:, pos][:, :, pos], axis1=-2, axis2=-1)[:, None]
    row_spread = np.trace(R[..., pos, :][..., pos], axis1=-2, axis2=-1)                 # (n, W)
    for w in range(W):                           # row slots: at most the rows of one vehicle
        other = mask[pa, w] & (pw != w)
        # where row w's feature would be under pivot h, against every track the vehicle holds
        gap = held_at - (given.mean[:, pos] + z[pa, w][:, pos])[:, None]                 # (H, F, p)
        near = (gap**2).sum(-1) <= TERM_GATE * (spread + row_spread[pa, w][:, None])
        hi, fi = np.nonzero(other[:, None] & known[pa] & near)
        term = np.full((H, known.shape[1]), -np.inf)
        if hi.size:
            a = pa[hi]
            S = R[a, w] + tracks.cov[a, fi] + given.cov[hi]
            term[hi, fi] = gaussian_logpdf(z[a, w] - (tracks.mean[a, fi] - given.mean[hi]), S) + log_ratio
        # log(1 + Σ_k' (P_D/λ) N(…)): the row from one of the tracks, or from a new feature
        score = score + np.where(other, np.logaddexp(0.0, log_sum_exp(term, axis=1)), 0.0)
        best_track[:, w] = term.argmax(axis=1)
        best_term[:, w] = term.max(axis=1, initial=-np.inf)
    # the tracks the hypothesis leaves undetected: each costs log(1 − P_D P(in range))
    fits = best_term > 0
    paired = np.zeros((H, known.shape[1]), dtype=bool)
    paired[np.arange(H), pf] = True
    hh, ww = np.nonzero(fits)
    paired[hh, best_track[hh, ww]] = True
    p_in = _in_range(held_at - given.mean[:, None, pos], spread, max_range)
    score = score + np.where(known[pa] & ~paired, np.log1p(-detection_probability * p_in), 0.0).sum(axis=1)
    return score, fits, best_track


def _in_range(gap: FloatArray, spread: FloatArray, max_range: float) -> FloatArray:
    """P(‖gap‖ ≤ R_s) for position gaps (…, p) whose summed per-axis variances are
    `spread` (…): Gaussian in the distance, with half the trace as its variance."""
    if not np.isfinite(max_range):
        return np.ones(gap.shape[:-1])
    from scipy.special import ndtr  # on use: listing the estimators must not load SciPy

    return ndtr((max_range - np.sqrt((gap**2).sum(-1))) / np.sqrt(spread / 2.0 + 1e-12))
