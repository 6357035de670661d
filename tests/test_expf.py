"""`cooploc._expf.exp_inplace` and the pair kernel that uses it, against their references.

- the vectorized exp against the C library's `expf`, reached as numba's scalar ``np.exp``
  on float32 (what the pair kernel called before): bit for bit where that is glibc ≥ 2.27
  on x86-64 (whose `expf` this one reproduces; on every float32 ≤ 0 it was checked once
  exhaustively), within 1 ulp on any other C library;
- `_particle_kernels.kernel_matrix` against its previous implementation (a scalar
  ``np.exp`` per pair, kept below): the same float32 values and row shifts, bit for bit
  on glibc, so `rsu-bp` and `icp-da-pf` give the same numbers as before.
"""

from __future__ import annotations

import platform

import numba
import numpy as np
import pytest

from cooploc._expf import exp_inplace
from cooploc._particle_kernels import kernel_matrix, quadratic_row

#: the reference is glibc's expf, which exp_inplace reproduces bit for bit
_LIBC, _LIBC_VERSION = platform.libc_ver()
GLIBC = platform.system() == "Linux" and platform.machine() == "x86_64" and _LIBC == "glibc" and (
    tuple(int(x) for x in _LIBC_VERSION.split(".")[:2]) >= (2, 27))


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


def _assert_same(ours: np.ndarray, reference: np.ndarray) -> None:
    if GLIBC:
        mismatch = np.flatnonzero(ours.view(np.uint32) != reference.view(np.uint32))
        assert mismatch.size == 0, (ours.ravel()[mismatch[:5]], reference.ravel()[mismatch[:5]])
    else:  # another C library's expf: both within 1 ulp of each other
        np.testing.assert_array_max_ulp(ours, reference, maxulp=1)


def _float32s(bits: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(bits.astype(np.uint32)).view(np.float32)


def test_exp_matches_the_c_library_on_a_sweep_of_every_exponent() -> None:
    # every 97th float32 bit pattern of either sign (≈ 44 million values: all exponents,
    # spread mantissas), and every value around the edges of the special cases
    step = np.arange(0, 2**32, 97, dtype=np.uint64)
    edges = [np.float32(v).view(np.uint32) for v in (-103.972084, -103.27892, 88.72283, -87.33655, 0.0)]
    near = np.concatenate([np.arange(int(e) - 5000, int(e) + 5000, dtype=np.int64) for e in edges])
    x = _float32s(np.concatenate([step, near % 2**32]))
    x = x[~np.isnan(x)]
    ours, reference = x.copy(), np.empty_like(x)
    exp_inplace(ours)
    _libm_exp(x, reference)
    _assert_same(ours, reference)


def test_exp_special_values() -> None:
    x = np.array([0.0, -0.0, -np.inf, np.inf, -200.0, -103.5, 100.0, np.nan], dtype=np.float32)
    exp_inplace(x)
    assert x[0] == x[1] == 1.0 and x[2] == 0.0 and x[3] == np.inf and x[4] == 0.0
    assert x[5] == np.float32(2.0**-149)            # between log 2⁻¹⁵⁰ and log 2⁻¹⁴⁹: the smallest subnormal
    assert x[6] == np.inf and np.isnan(x[7])


@pytest.mark.parametrize("scale", [0.3, 3.0, 30.0, 300.0])
def test_kernel_matrix_matches_its_previous_implementation(scale: float) -> None:
    rng = np.random.default_rng(int(scale * 10))
    B, Nj, Nl = 4, 97, 131               # odd sizes: the vector loops' remainders too
    u = (rng.normal(size=(B, Nj, 2)) * scale).astype(np.float32)
    vt = (rng.normal(size=(B, 2, Nl)) * scale).astype(np.float32)
    ours, reference = np.empty((B, Nj, Nl), np.float32), np.empty((B, Nj, Nl), np.float32)
    shift, shift_ref = np.zeros((B, Nj)), np.zeros((B, Nj))
    kernel_matrix(u, vt, ours, shift)
    _previous_kernel_matrix(u, vt, reference, shift_ref)
    np.testing.assert_array_equal(shift, shift_ref)
    _assert_same(ours, reference)
