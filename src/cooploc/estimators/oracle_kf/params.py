"""The parameters of `oracle-kf` (both forms read them)."""

from __future__ import annotations

from dataclasses import dataclass

from cooploc.params import Params, param

__all__ = ["OracleKFParams"]


@dataclass(frozen=True)
class OracleKFParams(Params):
    """Parameters of `oracle-kf`.

    Attributes
    ----------
    feature_timeout : drop a feature after this many steps without a measurement
        (keeps the joint state bounded in traffic where features come and go).
    dense : run the dense joint filter (one covariance over everything, O(D³) per step)
        instead of the component form; the same numbers up to round-off. A reference
        for tests and benchmarks.
    """

    feature_timeout: int = param(100, ge=1)
    dense: bool = False
