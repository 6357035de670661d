"""`kf-known-da`: the Kalman baseline of Zhang et al. 2016 §4.1 — anonymous GPS, association given.

The paper's Kalman filter is "given" the association of the internal (GPS) measurements
and does not use the radar, whose frame is unknown (§4.1). Here that association is the
true origin of every anonymous row (`AssociationTruth.origin`, DESIGN §4): each row is
relabelled with the vehicle it came from, clutter rows (origin −1) are dropped, and the
result is filtered exactly as `gnss-kf` does (one Kalman filter per vehicle, batched,
`Setup.vehicle_motion`; a vehicle whose row was missed is only predicted).

It reads nothing of the truth but the origins, so it is the bound of what a per-vehicle
GPS filter can do once the association problem is removed — the reference the SME
filter is compared with in Fig. 3.

Complexity: that of `gnss-kf`, O(n dx³) per step in a fixed number of NumPy calls.

The model written out: docs/kf_known_da.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from cooploc.estimators.gnss_kf import GnssKF
from cooploc.params import Params
from cooploc.registry import register_estimator
from cooploc.types import AssociationTruth, Batch, Estimate, Frame, Setup

__all__ = ["KFKnownDA", "KFKnownDAParams"]


@dataclass(frozen=True)
class KFKnownDAParams(Params):
    """`kf-known-da` has no tuning parameters: it uses the scenario's models as given."""


@register_estimator
class KFKnownDA:
    """Per-vehicle Kalman filter of anonymous GPS rows given their true association.

    Uses: GNSS rows, anonymous (`AnonymousPosition`, relabelled by their true origin) or
    identified, and odometry; never the radar (Zhang §4.1).
    """

    name: ClassVar[str] = "kf-known-da"
    bound: ClassVar[str | None] = "kf-known-da"
    summary: ClassVar[str] = ("Kalman filter per vehicle of anonymous GPS rows given their true "
                              "association, no radar (Zhang 2016 §4.1 baseline)")
    Params: ClassVar[type[Params]] = KFKnownDAParams
    needs_truth: ClassVar[bool] = True
    default_preset: ClassVar[str] = "zhang2016-cv"
    usable_sensors: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "gnss": ("anonymous-position", "gnss-position"), "odometry": ("odometry",)}

    def __init__(self, setup: Setup, params: KFKnownDAParams, rng: np.random.Generator, *,
                 truth: AssociationTruth) -> None:
        self.params = params
        self._origin = truth.origin
        self._filter = GnssKF(setup, GnssKF.Params(), rng)

    def step(self, frame: Frame) -> Estimate:
        batches = dict(frame.batches)
        gnss = batches.get("gnss")
        if gnss is not None:
            origin = np.asarray(self._origin[frame.k].get("gnss", np.full(len(gnss), -1)))
            rows = origin >= 0                                  # clutter rows have no vehicle
            batches["gnss"] = Batch(gnss.z[rows], gnss.cov[rows], origin[rows], origin[rows])
        return self._filter.step(Frame(frame.k, frame.t, frame.vehicles, batches, frame.links))
