"""Dense symmetric positive definite inverses for `oracle-kf`'s component update.

The update of a large component (`components`) inverts two symmetric positive definite
matrices a step (r × r, r up to ~700 on the SUMO presets). LAPACK's way, ``potrf``
(Cholesky A = L Lᵀ) then ``potri`` (= ``trtri``, L⁻¹, then ``lauum``, L⁻ᵀ L⁻¹), was most
of a step: in the OpenBLAS that NumPy and SciPy ship, single-threaded, ``trtri`` runs
several times slower than the triangular product ``trmm``, and ``potrf`` at half its
speed. Here the factor and its inverse come together from one recursion by halves,

    A = [[A11, ·], [A21, A22]]:   L11⁻¹ (recursion),   L21 = A21 L11⁻ᵀ,
    S = A22 − L21 L21ᵀ,   L22⁻¹ of S (recursion),   (L⁻¹)21 = −L22⁻¹ L21 L11⁻¹,

with ``potrf`` and ``trtri`` at the leaves (≤ `LEAF` rows) and ``trmm`` / ``syrk``
between them, all in place in one Fortran-ordered array: the blocks are passed to BLAS
as pointers with the leading dimension of the whole, through the function pointers
SciPy exports for Cython (`scipy.linalg.cython_blas`, `cython_lapack`), so no block is
copied. Then A⁻¹ = L⁻ᵀ L⁻¹ by ``lauum``, as ``potri`` does. The operations are those of
``potrf`` + ``potri`` (n³); L21 comes from a product with L11⁻¹ rather than a triangular
solve, which is as accurate for the condition numbers of a filter's covariances
(≲ 1e6; `tests/test_oracle_kf.py` compares with numpy's inverse and the dense filter).

scipy and ctypes are loaded inside the functions (the registry must not load scipy).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from cooploc.types import FloatArray

__all__ = ["LEAF", "spd_inverse_lower"]

LEAF = 96   # rows below which LAPACK's trtri is called as it is (measured: 48–128 alike)


@cache
def _routines():
    """(dtrmm, dtrtri) of the BLAS / LAPACK SciPy is linked with, as ctypes functions taking
    Fortran arguments (every argument by pointer)."""
    import ctypes

    from scipy.linalg import cython_blas, cython_lapack

    api = ctypes.pythonapi
    api.PyCapsule_GetName.restype, api.PyCapsule_GetName.argtypes = ctypes.c_char_p, [ctypes.py_object]
    api.PyCapsule_GetPointer.restype = ctypes.c_void_p
    api.PyCapsule_GetPointer.argtypes = [ctypes.py_object, ctypes.c_char_p]

    def address(module, name: str) -> int:
        capsule = module.__pyx_capi__[name]
        return api.PyCapsule_GetPointer(capsule, api.PyCapsule_GetName(capsule))

    char, integer, real, pointer = (ctypes.c_char_p, ctypes.POINTER(ctypes.c_int),
                                    ctypes.POINTER(ctypes.c_double), ctypes.c_void_p)
    # dtrmm(side, uplo, transa, diag, m, n, alpha, a, lda, b, ldb): B ← alpha op(A) B or alpha B op(A)
    trmm = ctypes.CFUNCTYPE(None, char, char, char, char, integer, integer, real, pointer, integer,
                            pointer, integer)(address(cython_blas, "dtrmm"))
    # dsyrk(uplo, trans, n, k, alpha, a, lda, beta, c, ldc): C ← alpha A Aᵀ + beta C
    syrk = ctypes.CFUNCTYPE(None, char, char, integer, integer, real, pointer, integer, real,
                            pointer, integer)(address(cython_blas, "dsyrk"))
    # dpotrf(uplo, n, a, lda, info), dtrtri(uplo, diag, n, a, lda, info)
    potrf = ctypes.CFUNCTYPE(None, char, integer, pointer, integer, integer)(
        address(cython_lapack, "dpotrf"))
    trtri = ctypes.CFUNCTYPE(None, char, char, integer, pointer, integer, integer)(
        address(cython_lapack, "dtrtri"))
    return trmm, trtri, syrk, potrf


def _cholesky_inverse_in_place(W: FloatArray) -> bool:
    """Replace the lower triangle of the Fortran-ordered symmetric positive definite W by
    L⁻¹, L its Cholesky factor (W = L Lᵀ), by recursive halving in place:

        W = [[W11, ·], [W21, W22]]:   L11⁻¹ (recursion), L21 = W21 L11⁻ᵀ (trmm),
        S = W22 − L21 L21ᵀ (syrk), L22⁻¹ of S (recursion), (L⁻¹)21 = −L22⁻¹ L21 L11⁻¹ (trmm),

    ``potrf`` then ``trtri`` at the leaves. The operations of ``potrf`` and ``trtri``
    (n³/3 each), all in matrix products. The upper triangle is neither read nor written.
    False if W is not positive definite in float64 (W is then partly overwritten)."""
    import ctypes

    trmm, trtri, syrk, potrf = _routines()
    n = W.shape[0]
    base, lda = W.ctypes.data, ctypes.byref(ctypes.c_int(n))
    one, minus_one = ctypes.byref(ctypes.c_double(1.0)), ctypes.byref(ctypes.c_double(-1.0))

    def at(i: int, j: int) -> int:      # address of W[i, j]
        return base + W.itemsize * (i + j * n)

    def factor_invert(first: int, size: int) -> bool:   # the diagonal block W[first:first+size, same]
        if size <= LEAF:
            info, order = ctypes.c_int(0), ctypes.byref(ctypes.c_int(size))
            potrf(b"L", order, at(first, first), lda, ctypes.byref(info))
            if info.value != 0:
                return False
            trtri(b"L", b"N", order, at(first, first), lda, ctypes.byref(info))
            return info.value == 0
        h = size // 2
        if not factor_invert(first, h):
            return False
        rows, cols = ctypes.byref(ctypes.c_int(size - h)), ctypes.byref(ctypes.c_int(h))
        A_inv, B, C = at(first, first), at(first + h, first), at(first + h, first + h)
        trmm(b"R", b"L", b"T", b"N", rows, cols, one, A_inv, lda, B, lda)          # L21 = W21 L11⁻ᵀ
        syrk(b"L", b"N", rows, cols, minus_one, B, lda, one, C, lda)              # S = W22 − L21 L21ᵀ
        if not factor_invert(first + h, size - h):
            return False
        trmm(b"R", b"L", b"N", b"N", rows, cols, one, A_inv, lda, B, lda)          # L21 L11⁻¹
        trmm(b"L", b"L", b"N", b"N", rows, cols, minus_one, C, lda, B, lda)        # −L22⁻¹ L21 L11⁻¹
        return True

    return factor_invert(0, n)


def spd_inverse_lower(A: FloatArray, overwrite: bool = False) -> FloatArray | None:
    """The lower triangle of A⁻¹ (the upper one is garbage) of a symmetric positive
    definite A (n, n), of which only the lower triangle is read: L⁻¹ of its Cholesky
    factor A = L Lᵀ in place (`_cholesky_inverse_in_place`), then A⁻¹ = L⁻ᵀ L⁻¹ in place
    (``lauum``); a Fortran-ordered array. None if A is not positive definite in float64.
    `overwrite`: A (Fortran-ordered) may be used as the workspace (then it is the result)."""
    from scipy.linalg import lapack

    W = A if overwrite and A.flags.f_contiguous and A.dtype == np.float64 else np.array(A, order="F",
                                                                                          dtype=float)
    if not _cholesky_inverse_in_place(W):
        return None
    inv, info = lapack.dlauum(W, lower=True, overwrite_c=True)   # (L⁻¹)ᵀ L⁻¹
    return inv if info == 0 else None
