"""exp of float32 values, bit for bit as glibc's `expf`, in a loop that vectorizes (numba).

A numba loop over ``np.exp(x)`` of float32 values calls the C library's scalar `expf`
once per element (numba has no vector maths library unless Intel's SVML is installed):
the pair kernel of `cooploc.particles` spent most of its time in these calls. Here the
same function is written out so that LLVM vectorizes it, and so that it gives the same
float32 result, bit for bit, as glibc's `expf` (2.27 and later, x86-64 with FMA — the
implementation that numba's call reached on the machines where cooploc's reference
numbers were produced); `tests/test_expf.py` compares the two on every float32 ≤ 0.

The method (Tang's table-driven exponential, in double precision): with N = 32,

    k = round(x N / ln 2),  r = x N / ln 2 − k,
    eˣ = 2^(k/N) · 2^(r/N) ≈ s · (c₀ r³ + c₁ r² + c₂ r + 1),  s = 2^(k mod N / N) · 2^⌊k/N⌋,

where 2^(j/N) comes from a table of 32 doubles (correctly rounded, built here), the
integer part of the exponent is added to its bits, and the cubic in r is a minimax
fit (its coefficients are those of glibc's `expf`: a different polynomial would round
some results differently). The rounding of k uses the 1.5·2⁵² shift trick, and the
fused multiply–adds are explicit LLVM `fma` calls, so neither depends on compiler
flags; the module is compiled without fastmath. The result is rounded to float32 once.
Outside the main range: x < −103.97 (below half the smallest subnormal) gives 0,
−103.97 ≤ x < −103.28 the smallest subnormal, x > 88.72 infinity, as glibc does.
"""

from __future__ import annotations

from decimal import Decimal, localcontext

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["exp_inplace"]

_N = 32
_SHIFT = float.fromhex("0x1.8p+52")              # adding it rounds a double to an integer
_INV_LN2_N = float.fromhex("0x1.71547652b82fep+5")  # N / ln 2, correctly rounded
# c₀, c₁, c₂ of the cubic in r (already divided by N³, N², N)
_C0 = float.fromhex("0x1.c6af84b912394p-20")
_C1 = float.fromhex("0x1.ebfce50fac4f3p-13")
_C2 = float.fromhex("0x1.62e42ff0c52d6p-6")
_OVERFLOW = np.float32(float.fromhex("0x1.62e42ep6"))      # log(2¹²⁸)
_UNDERFLOW = np.float32(float.fromhex("-0x1.9fe368p6"))    # log(2⁻¹⁵⁰): rounds to 0 below
_SUBNORMAL = np.float32(float.fromhex("-0x1.9d1d9ep6"))    # log(2⁻¹⁴⁹): the smallest subnormal below
_MIN_SUBNORMAL = np.float32(float.fromhex("0x1p-149"))


def _table() -> np.ndarray:
    """Bits of 2^(j/N), correctly rounded, minus j·2⁴⁷ (where j/N's exponent bits go)."""
    with localcontext() as ctx:
        ctx.prec = 40
        powers = np.array([float(Decimal(2) ** (Decimal(j) / _N)) for j in range(_N)])
    return powers.view(np.int64) - (np.arange(_N, dtype=np.int64) << (52 - 5))


_TABLE = _table()


_ABS_MASK = np.int64(0x7FFFFFFFFFFFFFFF)   # a double's bits without the sign
_INF_BITS = np.int64(0x7FF0000000000000)   # +inf; larger magnitudes are NaNs


@intrinsic
def _fma(typingctx, a, b, c):  # type: ignore[no-untyped-def]
    """a·b + c rounded once (LLVM's fma intrinsic: the vfmadd instruction where there is one)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def _bits(typingctx, x):  # type: ignore[no-untyped-def]
    """The bits of a double as an int64."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _double(typingctx, i):  # type: ignore[no-untyped-def]
    """The double with the bits of an int64."""
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@numba.njit(cache=True)  # no fastmath: the order of operations is part of the result
def exp_inplace(x: np.ndarray) -> None:
    """x[l] ← exp(x[l]) for a 1-D float32 array, as glibc's `expf` (module docstring)."""
    for l in range(x.size):
        xf = x[l]
        xd = np.float64(xf)
        kd = _fma(_INV_LN2_N, xd, _SHIFT)          # k + shift: k = round(x N / ln 2) in the low bits
        ki = _bits(kd)
        kd = kd - _SHIFT
        r = _fma(_INV_LN2_N, xd, -kd)              # r = x N / ln 2 − k
        s = _double(_TABLE[ki & (_N - 1)] + (ki << (52 - 5)))   # 2^(k/N)
        y = _fma(_fma(r, _C0, _C1), r * r, _fma(r, _C2, 1.0))   # 2^(r/N) ≈ c₀r³ + c₁r² + c₂r + 1
        v = np.float32(y * s)
        v = _MIN_SUBNORMAL if xf < _SUBNORMAL else v
        v = np.float32(0.0) if xf < _UNDERFLOW else v
        v = np.float32(np.inf) if xf > _OVERFLOW else v
        # NaN stays NaN, tested on the bits: a float test (xf != xf) was folded away where the
        # compiled loop came out under no-NaN assumptions (a cached build in the test suite)
        x[l] = xf if (_bits(xd) & _ABS_MASK) > _INF_BITS else v
