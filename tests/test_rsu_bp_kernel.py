"""`rsu_bp.kernel`: the weighted sums of rsu-bp's pair kernel against the dense definition.

The reference builds log G[b, j, l] = log N(z_b; a_j − c_l, W_b) for every pair in float64
(a linear solve per pair) and sums in the log domain (`scipy.special.logsumexp`). Cases:
several vehicles and features, uneven rows per vehicle, unequal particle counts (so a
transposed index fails), rows far from every feature, log-weights down to −700, zero
weights and an all-zero block (−inf), and beliefs so broad against W that the separable
form's split scaling underflows (those blocks go to the direct float64 sum).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.special import logsumexp

import cooploc.estimators.rsu_bp.kernel as kernel_module
from cooploc.association import padded_groups
from cooploc.estimators.rsu_bp import RsuBPParams
from cooploc.estimators.rsu_bp.kernel import SeparableKernel
from cooploc.particles import pair_kernel
from cooploc.types import Recording
from helpers import froehle_recording, run_estimator

# E is float32 relative to its row's largest value: a log-sum is off by ≲ 6e-8 per
# e-fold of the exponent's range; 2e-6 holds for the ranges here, and a wrong term
# (a missing α, γ or scale, a transposed index) is off by far more
SEPARABLE_LOG_ATOL = 2e-6
# the direct form rounds the exponent −½q itself to float32 (q up to ~10² here)
DIRECT_LOG_ATOL = 2e-5


def case(rng: np.random.Generator, d: int = 2, spread: float = 1.0, noise: float = 1.0):
    """Blocks b = r K + k of rows r (vehicle s_r) against features k, as `_bp_update` forms them."""
    S, K, Nj, Nl = 3, 4, 11, 17
    rows_of = rng.integers(1, 5, size=S)
    s_row = np.repeat(np.arange(S), rows_of)
    rng.shuffle(s_row)
    R = s_row.size
    feature = rng.normal(0, spread, (K, Nj, d)) + rng.normal(0, 5, (K, 1, d))
    vehicle = rng.normal(0, spread, (S, Nl, d)) + rng.normal(0, 5, (S, 1, d))
    A = rng.normal(size=(S, d, d))
    W = noise**2 * (A @ A.transpose(0, 2, 1) / d + 0.3 * np.eye(d))
    truth = rng.integers(0, K, size=R)
    z = (feature[truth].mean(axis=1) - vehicle[s_row].mean(axis=1) + rng.normal(0, noise, (R, d)))
    z[0] += 30 * noise                                         # a row far from every feature
    s_b, k_b = np.repeat(s_row, K), np.tile(np.arange(K), R)
    z_b, cov_b = np.repeat(z, K, axis=0), W[s_b]
    index, mask = padded_groups(s_row, S)
    groups = (index[:, None, :] * K + np.arange(K)[:, None]).reshape(-1, index.shape[1])
    return dict(z=z_b, cov=cov_b, feature=feature, vehicle=vehicle, block_feature=k_b,
                block_vehicle=s_b, blocks=groups, mask=np.repeat(mask, K, axis=0))


def dense_log_kernel(c: dict) -> np.ndarray:
    """log G (B, N_j, N_l) pair by pair in float64."""
    a, x = c["feature"][c["block_feature"]], c["vehicle"][c["block_vehicle"]]
    r = c["z"][:, None, None, :] - a[:, :, None, :] + x[:, None, :, :]       # (B, N_j, N_l, d)
    cov = c["cov"][:, None, None]
    q = (r * np.linalg.solve(cov, r[..., None])[..., 0]).sum(axis=-1)
    _, logdet = np.linalg.slogdet(2 * np.pi * c["cov"])
    return -0.5 * q - 0.5 * logdet[:, None, None]


def extreme_weights(rng: np.random.Generator, B: int, N: int) -> np.ndarray:
    with np.errstate(under="ignore"):
        w = np.exp(rng.uniform(-700, 0, (B, N)))
    w[rng.random((B, N)) < 0.2] = 0.0
    w[1] = 0.0                                                  # a block without weight
    w[2] = rng.random(N)                                        # and an ordinary one
    return w


def reference_sums(log_G: np.ndarray, w_l: np.ndarray, w_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(divide="ignore"):
        return (logsumexp(log_G + np.log(w_l)[:, None, :], axis=2),
                logsumexp(log_G + np.log(w_j)[:, :, None], axis=1))


def assert_log_close(actual: np.ndarray, expected: np.ndarray, atol: float) -> None:
    np.testing.assert_array_equal(np.isneginf(actual), np.isneginf(expected))
    finite = np.isfinite(expected)
    np.testing.assert_allclose(actual[finite], expected[finite], rtol=0, atol=atol)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_separable_sums_match_the_dense_definition(d: int, rng: np.random.Generator) -> None:
    c = case(rng, d=d)
    B, Nj, Nl = c["z"].shape[0], c["feature"].shape[1], c["vehicle"].shape[1]
    w_l, w_j = extreme_weights(rng, B, Nl), extreme_weights(rng, B, Nj)
    ref_l, ref_j = reference_sums(dense_log_kernel(c), w_l, w_j)
    G, first = SeparableKernel.build(**c, weights=w_l)
    assert_log_close(first, ref_l, SEPARABLE_LOG_ATOL)
    assert_log_close(G.log_sum_over_second(w_l), ref_l, SEPARABLE_LOG_ATOL)
    assert_log_close(G.log_sum_over_first(w_j), ref_j, SEPARABLE_LOG_ATOL)
    # a second set of weights on the stored E (the correction iterations)
    w2 = rng.random((B, Nl))
    assert_log_close(G.log_sum_over_second(w2), reference_sums(dense_log_kernel(c), w2, w_j)[0],
                     SEPARABLE_LOG_ATOL)


def test_broad_beliefs_fall_back_to_the_direct_sum(rng: np.random.Generator,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    # particles spread 3 m against W of 1 cm: whitened products of ~10⁵, far beyond what
    # a row-scaled float32 E can hold; the affected blocks are summed directly
    c = case(rng, spread=3.0, noise=0.01)
    B, Nj, Nl = c["z"].shape[0], c["feature"].shape[1], c["vehicle"].shape[1]
    calls: list[int] = []
    direct = kernel_module.pair_kernel_log_sum

    def counted(*args):
        calls.append(len(args[0]))
        return direct(*args)

    monkeypatch.setattr(kernel_module, "pair_kernel_log_sum", counted)
    w_l, w_j = rng.random((B, Nl)), rng.random((B, Nj))
    ref_l, ref_j = reference_sums(dense_log_kernel(c), w_l, w_j)
    G, first = SeparableKernel.build(**c, weights=w_l)
    assert calls, "no block needed the direct sum: the case does not test the fallback"
    assert_log_close(first, ref_l, SEPARABLE_LOG_ATOL)
    assert_log_close(G.log_sum_over_first(w_j), ref_j, SEPARABLE_LOG_ATOL)


def test_direct_form_sums_and_values(rng: np.random.Generator) -> None:
    c = case(rng)
    B, Nj, Nl = c["z"].shape[0], c["feature"].shape[1], c["vehicle"].shape[1]
    a, x = c["feature"][c["block_feature"]], c["vehicle"][c["block_vehicle"]]
    w_l, w_j = rng.random((B, Nl)), rng.random((B, Nj))
    w_l[1], w_j[1] = 0.0, 0.0
    ref_l, ref_j = reference_sums(dense_log_kernel(c), w_l, w_j)
    G = pair_kernel(c["z"], c["cov"], a, x)
    # a row far from every feature: its float32 values hold a relative part of the row only
    near = np.ones(B, dtype=bool)
    near[: c["feature"].shape[0]] = False
    for got, ref in ((G.log_sum_over_second(w_l), ref_l), (G.log_sum_over_first(w_j), ref_j)):
        assert_log_close(got[near], ref[near], DIRECT_LOG_ATOL)


def perturbed_covariance(rec: Recording, step: int) -> Recording:
    """The same run with one V2F row's covariance larger by 1e-9 (relative) at `step`."""
    frames = list(rec.frames)
    batch = frames[step].batches["v2f"]
    cov = batch.cov.copy()
    cov[0] *= 1 + 1e-9
    frames[step] = dataclasses.replace(
        frames[step], batches={**frames[step].batches, "v2f": dataclasses.replace(batch, cov=cov)})
    return dataclasses.replace(rec, frames=frames)


def test_separable_and_direct_forms_agree_in_the_filter(seed: int) -> None:
    rec = froehle_recording([seed, 11], n_steps=3)
    params = RsuBPParams(n_particles=200)
    separable = run_estimator("rsu-bp", rec, seed=1, params=params)
    direct = run_estimator("rsu-bp", perturbed_covariance(rec, 1), seed=1, params=params)
    assert separable[1].info["kernel_form"] == "separable"
    assert direct[1].info["kernel_form"] == "direct"
    # float32 kernels of either form (and a 1e-9 change of one W): 1e-4 m in the means
    np.testing.assert_allclose(separable[1].vehicles.mean, direct[1].vehicles.mean, rtol=0, atol=1e-4)
