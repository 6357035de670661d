"""`cooploc._expf.exp_inplace` and the pair kernel that uses it, against their references.

- the vectorized float32 exp against the correctly rounded exponential (float64
  ``np.exp`` rounded to float32) on a sweep of every exponent: within 2 ulp, and
  correctly rounded for most arguments; the special cases exactly;
- `_particle_kernels.kernel_matrix` against its first implementation (a scalar
  ``np.exp`` per pair, the C library's `expf`, kept below): the same row shifts, and
  values within 3 ulp (2 of ours, 1 of the C library's).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from cooploc._expf import exp_inplace
from cooploc._particle_kernels import kernel_matrix, quadratic_row


@numba.njit(cache=False)
def _libm_exp(x: np.ndarray, out: np.ndarray) -> None:
    for i in range(x.size):
        out[i] = np.exp(x[i])


@numba.njit(fastmath=True, cache=False)
def _previous_kernel_matrix(u, vt, out, shift):  # type: ignore[no-untyped-def]
    """kernel_matrix as it was: per row, a running minimum and one scalar exp (the C
    library's expf) per pair, here over whole rows."""
    for b in range(u.shape[0]):
        for j in range(u.shape[1]):
            q = out[b, j]
            quadratic_row(u, vt, b, j, q)
            lowest = q[0]
            for value in q:
                lowest = min(lowest, value)
            shift[b, j] = -0.5 * lowest
            q[:] = np.exp(np.float32(-0.5) * (q - lowest))


def _float32s(bits: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(bits.astype(np.uint32)).view(np.float32)


def test_exp_is_within_two_ulp_of_the_correctly_rounded_value() -> None:
    # every 97th float32 bit pattern of either sign (≈ 44 million values: all exponents,
    # spread mantissas), and every value around the edges of the special cases
    step = np.arange(0, 2**32, 97, dtype=np.uint64)
    edges = [np.float32(v).view(np.uint32)
             for v in (-104.0, -103.97208, -103.27892, 88.72283, -87.33655, 0.0)]
    near = np.concatenate([np.arange(int(e) - 5000, int(e) + 5000, dtype=np.int64) for e in edges])
    x = _float32s(np.concatenate([step, near % 2**32]))
    x = x[~np.isnan(x)]
    ours = x.copy()
    exp_inplace(ours)
    with np.errstate(over="ignore"):
        exact = np.exp(x.astype(np.float64)).astype(np.float32)   # float64 exp: far below float32's ulp
    finite = np.isfinite(exact) & (exact > 0)
    np.testing.assert_array_equal(ours[~finite], exact[~finite])  # 0 and infinity where they belong
    ulps = np.abs(ours[finite].view(np.int32).astype(np.int64) - exact[finite].view(np.int32))
    assert ulps.max() <= 2, x[finite][ulps.argmax()]
    assert (ulps == 0).mean() > 0.9, (ulps == 0).mean()


def test_exp_matches_the_c_library_within_three_ulp() -> None:
    x = np.linspace(-110.0, 90.0, 200_001, dtype=np.float32)
    ours, reference = x.copy(), np.empty_like(x)
    exp_inplace(ours)
    _libm_exp(x, reference)
    np.testing.assert_array_max_ulp(ours, reference, maxulp=3)


def test_exp_special_values() -> None:
    x = np.array([0.0, -0.0, -np.inf, np.inf, -200.0, -103.5, 100.0, np.nan], dtype=np.float32)
    exp_inplace(x)
    assert x[0] == x[1] == 1.0 and x[2] == 0.0 and x[3] == np.inf and x[4] == 0.0
    assert x[5] == np.float32(2.0**-149)            # between log 2⁻¹⁵⁰ and log 2⁻¹⁴⁹: the smallest subnormal
    assert x[6] == np.inf and np.isnan(x[7])


@pytest.mark.parametrize("scale", [0.3, 3.0, 30.0, 300.0])
def test_kernel_matrix_matches_its_first_implementation(scale: float) -> None:
    rng = np.random.default_rng(int(scale * 10))
    B, Nj, Nl = 4, 97, 131               # odd sizes: the vector loops' remainders too
    u = (rng.normal(size=(B, Nj, 2)) * scale).astype(np.float32)
    vt = (rng.normal(size=(B, 2, Nl)) * scale).astype(np.float32)
    ours, reference = np.empty((B, Nj, Nl), np.float32), np.empty((B, Nj, Nl), np.float32)
    shift, shift_ref = np.zeros((B, Nj)), np.zeros((B, Nj))
    kernel_matrix(u, vt, ours, shift)
    _previous_kernel_matrix(u, vt, reference, shift_ref)
    np.testing.assert_array_equal(shift, shift_ref)
    np.testing.assert_array_max_ulp(ours, reference, maxulp=3)
