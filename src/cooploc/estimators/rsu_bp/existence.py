"""Existence and birth weights of the unknown-feature `rsu-bp` (Meyer et al. 2018).

Meyer, Kropfreiter, Williams, Lau, Hlawatsch, Braca, Win, "Message passing algorithms for
scalable multitarget tracking", Proc. IEEE 106(2), 2018 (unknown number of objects:
legacy and new potential objects, each with an existence probability). Per sensing
vehicle s (one "sensor" of the paper's multisensor model) and potential feature k with
predicted existence r⁻_k, everything in units of a measurement density (all terms of a
row are multiplied by its clutter intensity λ_c(z), which the association does not
see, so λ_c = 0 stays finite):

- legacy feature k, row m:  ψ_k(m) = r⁻_k P_D β_{k,s}(m);
  missed:                   ψ_k(0) = 1 − r⁻_k P_D p_{k,s},
  with β the predicted likelihood of row m under k and p_{k,s} the probability that k is
  in the vehicle's sensing range (visibility: out of range is not a miss);
- row m not from a legacy feature: κ_m = λ_c(z_m) + λ_b(z_m), clutter or a new feature,
  λ_b(z_m) = μ_b P_D ∫ f_b(f) l(z_m | f) df the birth intensity seen through row m;
- existence after the step: with L_{k,s} = (1 − P_D p_{k,s})
  + P_D Σ_m ν_{m→k} β_{k,s}(m) the likelihood of "k exists" against 1 for "k does not",

      r_k = r⁻_k Π_s L_{k,s} / (r⁻_k Π_s L_{k,s} + 1 − r⁻_k);

- a new potential feature from row m: r_m = λ_b(z_m) / (κ_m + Σ_k μ_{k→m}) =
  P(row m not from a legacy feature) · λ_b(z_m) / κ_m.

ν_{m→k} are the measurement-to-feature messages of the association BP
(`cooploc.association.bp_association`, its ``log_nu``). With one feature and one row BP
is exact; `tests/test_rsu_bp_existence.py` checks these against enumeration.
"""

from __future__ import annotations

import numpy as np

from cooploc.types import FloatArray

__all__ = ["legacy_existence", "legacy_weights", "log_existence_likelihood", "new_existence",
           "row_weights"]


def legacy_weights(log_beta: FloatArray, existence: FloatArray, p_d: float, p_visible: FloatArray
                   ) -> tuple[FloatArray, FloatArray]:
    """log ψ_k(m) (…, K, M) and log ψ_k(0) (…, K) of legacy features (legacy potential object).

    `existence` (…, K) is r⁻, `p_visible` (…, K) the probability that the feature is in range.
    """
    with np.errstate(divide="ignore"):
        log_psi = np.log(existence * p_d)[..., None] + log_beta
        log_missed = np.log1p(-existence * p_d * p_visible)
    return log_psi, log_missed


def row_weights(clutter_intensity: float, log_birth: FloatArray) -> FloatArray:
    """log κ_m = log(λ_c + λ_b(z_m)) per row (new potential object)."""
    with np.errstate(divide="ignore"):
        return np.logaddexp(np.log(clutter_intensity), log_birth)


def log_existence_likelihood(log_nu_beta: FloatArray, p_d: float, p_visible: FloatArray) -> FloatArray:
    """log L_{k,s} = log[(1 − P_D p) + P_D Σ_m ν_{m→k} β_{k,s}(m)] from log Σ_m ν β (−inf: no row)."""
    with np.errstate(divide="ignore"):
        return np.logaddexp(np.log1p(-p_d * np.asarray(p_visible)), np.log(p_d) + log_nu_beta)


def legacy_existence(existence: FloatArray, log_likelihood: FloatArray) -> FloatArray:
    """r = r⁻ Π L / (r⁻ Π L + 1 − r⁻) from Σ_s log L_{k,s} (existence update), computed in logs."""
    with np.errstate(divide="ignore"):
        log_yes = np.log(existence) + log_likelihood
        log_no = np.log1p(-existence)
    return np.exp(log_yes - np.logaddexp(log_yes, log_no))


def new_existence(not_legacy: FloatArray, log_birth: FloatArray, log_kappa: FloatArray) -> FloatArray:
    """r_m = P(row m not from a legacy feature) · λ_b(z_m) / κ_m (new potential object)."""
    with np.errstate(invalid="ignore"):
        share = np.where(np.isfinite(log_kappa), np.exp(log_birth - log_kappa), 0.0)
    return not_legacy * share
