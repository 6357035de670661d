"""The estimators (DESIGN §4): one module or package per method, each registering its names.

>>> from cooploc.estimators import get_estimator, make_estimator
>>> cls = get_estimator("gnss-kf")
>>> est = make_estimator("gnss-kf", recording.setup, cls.Params(), rng)   # doctest: +SKIP

The registry itself is `cooploc.registry`; this package re-exports what callers use.
`make_estimator` hands a known-association reference (`needs_truth`) only the
association part of the truth; every other estimator gets none.
"""

from __future__ import annotations

from cooploc.estimators.base import Estimator
from cooploc.registry import estimators, get_estimator, make_estimator, register_estimator

__all__ = ["Estimator", "estimators", "get_estimator", "make_estimator", "register_estimator"]
