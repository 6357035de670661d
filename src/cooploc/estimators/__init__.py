"""Estimator registry (DESIGN §4): every method by its registered name.

>>> from cooploc.estimators import get_estimator, make_estimator
>>> cls = get_estimator("gnss-kf")
>>> est = make_estimator("gnss-kf", recording.setup, cls.Params(), rng)   # doctest: +SKIP

`make_estimator` hands a known-association reference (`needs_truth`) only the
association part of the truth; every other estimator gets none.
"""

from __future__ import annotations

import numpy as np

from cooploc.errors import ConfigError
from cooploc.estimators.base import AssociationTruth, Estimator
from cooploc.estimators.factor_graph import FgIsam2, FgTopologyNew, FgTopologyOld
from cooploc.estimators.gm_phd import GMPHD
from cooploc.estimators.gnss_kf import GnssKF
from cooploc.estimators.icp import ICP, ICPDALC, ICPDAPF
from cooploc.estimators.kf_known_da import KFKnownDA
from cooploc.estimators.oracle_kf import OracleKF
from cooploc.estimators.plbp import PLBP, PriorLBP
from cooploc.estimators.rsu_bp import RsuBP
from cooploc.estimators.sme import SmePF, SmeUKF
from cooploc.params import Params
from cooploc.types import Setup, Truth

__all__ = ["Estimator", "estimators", "get_estimator", "make_estimator"]

_REGISTRY: dict[str, type] = {cls.name: cls for cls in (
    GnssKF,
    OracleKF,
    RsuBP,
    ICP,
    ICPDALC,
    ICPDAPF,
    KFKnownDA,
    SmePF,
    SmeUKF,
    GMPHD,
    FgTopologyOld,
    FgTopologyNew,
    FgIsam2,
    PLBP,
    PriorLBP,
)}


def estimators() -> dict[str, type]:
    """All registered estimator classes by name."""
    return dict(_REGISTRY)


def get_estimator(name: str) -> type:
    """The estimator class registered as `name`; `ConfigError` listing the known ones."""
    if name not in _REGISTRY:
        raise ConfigError(f"unknown estimator {name!r}; known: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def make_estimator(
    name: str,
    setup: Setup,
    params: Params | None,
    rng: np.random.Generator,
    truth: Truth | None = None,
) -> Estimator:
    """Construct estimator `name`; pass `truth` only to known-association references."""
    cls = get_estimator(name)
    missing = [kind for kind in getattr(cls, "required_sensors", ()) if kind not in setup.sensors]
    if missing:
        raise ConfigError(f"{name} needs the measurement kinds {', '.join(missing)}, which this scenario "
                          f"does not have (it has: {', '.join(sorted(setup.sensors)) or 'none'})")
    params = cls.Params() if params is None else params
    if not isinstance(params, cls.Params):
        raise ConfigError(f"{name}: params must be {cls.Params.__name__}, got {type(params).__name__}")
    if cls.needs_truth:
        if truth is None:
            raise ConfigError(f"{name} is a known-association reference and needs the truth")
        return cls(setup, params, rng, truth=AssociationTruth.of(truth))
    return cls(setup, params, rng)
