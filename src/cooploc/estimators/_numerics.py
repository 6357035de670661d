"""Small numerical helpers shared by the Zhang 2016 estimators (`sme`, `gm_phd`)."""

from __future__ import annotations

import numpy as np

from cooploc.types import FloatArray

__all__ = ["logsumexp"]


def logsumexp(a: FloatArray, axis: int | None = None) -> FloatArray | float:
    """log Σ exp(a) over `axis` (all entries for None), −inf where every entry is −inf.

    A lean twin of `scipy.special.logsumexp`, whose array-API dispatch costs ~0.1–0.5 ms
    a call: the tempering bisection of `sme-pf` and the per-step updates of `gm-phd` call
    it dozens of times a step.
    """
    a = np.asarray(a, dtype=float)
    top = np.max(a, axis=axis, keepdims=True)
    safe = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(a - safe), axis=axis, keepdims=True)) + safe
    out = np.squeeze(out, axis=axis) if axis is not None else out.reshape(())
    return float(out) if out.ndim == 0 else out
