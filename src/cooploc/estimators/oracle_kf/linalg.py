"""Dense symmetric positive definite inverses for `oracle-kf`'s component update.

The update of a large component (`components`) inverts two symmetric positive definite
matrices a step (r × r, r up to ~700 on the SUMO presets). LAPACK's ``potri`` (the
inverse from the Cholesky factor) is ``trtri`` (triangular inverse) then ``lauum``
(Lᵀ L); in the OpenBLAS that NumPy and SciPy ship, single-threaded, ``trtri`` runs at
a fraction of the speed of the triangular product ``trmm`` and was the largest single
cost of a step. Here the triangular inverse is done by recursive halving with ``trmm``
alone:

    L = [[A, 0], [B, C]]   ⇒   L⁻¹ = [[A⁻¹, 0], [−C⁻¹ B A⁻¹, C⁻¹]],

A⁻¹ and C⁻¹ by the same recursion, ``trtri`` at the leaves (≤ `LEAF` rows), B ← B A⁻¹
and B ← −C⁻¹ B by ``trmm``, all in place in one Fortran-ordered array: the sub-blocks
are passed to BLAS as pointers with the leading dimension of the whole, through the
function pointers SciPy exports for Cython (`scipy.linalg.cython_blas`,
`cython_lapack`), so no block is copied. Same n³/3 operations as ``trtri``, round-off
of the same order (the recursion is the classical one; LAPACK's ``trtri`` is its
blocked loop).

scipy and ctypes are loaded inside the functions (the registry must not load scipy).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from cooploc.types import FloatArray

__all__ = ["LEAF", "lower_triangular_inverse", "spd_inverse_lower"]

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
    # dtrtri(uplo, diag, n, a, lda, info)
    trtri = ctypes.CFUNCTYPE(None, char, char, integer, pointer, integer, integer)(
        address(cython_lapack, "dtrtri"))
    return trmm, trtri


def _invert_lower_in_place(W: FloatArray) -> bool:
    """Replace the lower triangle of the Fortran-ordered square W by its inverse (the
    module docstring's recursion); the upper triangle is neither read nor written.
    False if a diagonal entry is zero (W is then partly overwritten)."""
    import ctypes

    trmm, trtri = _routines()
    n = W.shape[0]
    base, lda = W.ctypes.data, ctypes.byref(ctypes.c_int(n))
    one, minus_one = ctypes.byref(ctypes.c_double(1.0)), ctypes.byref(ctypes.c_double(-1.0))

    def at(i: int, j: int) -> int:      # address of W[i, j]
        return base + W.itemsize * (i + j * n)

    def invert(first: int, size: int) -> bool:   # the diagonal block W[first:first+size, same]
        if size <= LEAF:
            info = ctypes.c_int(0)
            trtri(b"L", b"N", ctypes.byref(ctypes.c_int(size)), at(first, first), lda, ctypes.byref(info))
            return info.value == 0
        h = size // 2
        if not (invert(first, h) and invert(first + h, size - h)):
            return False
        rows, cols = ctypes.byref(ctypes.c_int(size - h)), ctypes.byref(ctypes.c_int(h))
        B = at(first + h, first)
        A_inv, C_inv = at(first, first), at(first + h, first + h)
        trmm(b"R", b"L", b"N", b"N", rows, cols, one, A_inv, lda, B, lda)          # B ← B A⁻¹
        trmm(b"L", b"L", b"N", b"N", rows, cols, minus_one, C_inv, lda, B, lda)    # B ← −C⁻¹ B A⁻¹
        return True

    return invert(0, n)


def lower_triangular_inverse(L: FloatArray) -> FloatArray | None:
    """L⁻¹ of a lower-triangular L (n, n) whose upper triangle is ignored: a new
    Fortran-ordered array, lower triangular (zeros above the diagonal); None if L is
    singular (a zero on the diagonal)."""
    W = np.tril(L).copy(order="F")
    return W if _invert_lower_in_place(W) else None


def spd_inverse_lower(A: FloatArray, overwrite: bool = False) -> FloatArray | None:
    """The lower triangle of A⁻¹ (the upper one is garbage) of a symmetric positive
    definite A (n, n), of which only the lower triangle is read: Cholesky A = L Lᵀ
    (``potrf``), L⁻¹ in place (the module docstring), A⁻¹ = L⁻ᵀ L⁻¹ in place (``lauum``);
    a Fortran-ordered array. None if A is not positive definite in float64.
    `overwrite`: A (Fortran-ordered) may be used as the workspace (then it is the result)."""
    from scipy.linalg import lapack

    L, info = lapack.dpotrf(A, lower=True, clean=False, overwrite_a=overwrite)
    if info != 0 or not _invert_lower_in_place(L):
        return None
    inv, info = lapack.dlauum(L, lower=True, overwrite_c=True)   # (L⁻¹)ᵀ L⁻¹
    return inv if info == 0 else None
