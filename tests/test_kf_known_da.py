"""`kf-known-da`: exactly `gnss-kf` on the rows relabelled by their true origin, clutter dropped."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.estimators import make_estimator
from cooploc.estimators.gnss_kf import GnssKF, GnssKFParams
from cooploc.estimators.kf_known_da import KFKnownDA, KFKnownDAParams
from cooploc.scenarios import get_preset
from cooploc.types import AssociationTruth, Batch, Frame


@pytest.mark.parametrize("overrides", [{}, {"detection_probability": 0.8, "clutter_rate": 2.0}])
def test_is_gnss_kf_on_identified_rows(seed: int, overrides: dict) -> None:
    preset = get_preset("zhang2016-cv")
    rec = preset.generate(np.random.default_rng([seed, 3]),
                          preset.params.with_overrides({"n_steps": 25, **overrides}))
    ours = KFKnownDA(rec.setup, KFKnownDAParams(), np.random.default_rng(0),
                     truth=AssociationTruth.of(rec.truth))
    reference = GnssKF(rec.setup, GnssKFParams(), np.random.default_rng(0))
    for frame in rec.frames:
        gnss, origin = frame.batches["gnss"], rec.truth.origin[frame.k]["gnss"]
        real = origin >= 0                                   # the rows a vehicle sent
        identified = Batch(gnss.z[real], gnss.cov[real], origin[real], origin[real])
        a = ours.step(frame)
        b = reference.step(Frame(frame.k, frame.t, frame.vehicles, {"gnss": identified}))
        np.testing.assert_array_equal(a.vehicles.ids, b.vehicles.ids)
        np.testing.assert_array_equal(a.vehicles.mean, b.vehicles.mean)
        np.testing.assert_array_equal(a.vehicles.cov, b.vehicles.cov)


def test_without_association_it_only_predicts(seed: int) -> None:
    # the same anonymous rows given to gnss-kf (no origin) leave every vehicle unobserved; the
    # registry refuses gnss-kf here for that reason (tests/test_usable_sensors.py), so it is
    # built directly
    preset = get_preset("zhang2016-cv")
    rec = preset.generate(np.random.default_rng([seed, 4]), preset.params.with_overrides({"n_steps": 10}))
    known = make_estimator("kf-known-da", rec.setup, None, np.random.default_rng(0), rec.truth)
    blind = GnssKF(rec.setup, GnssKF.Params(), np.random.default_rng(0))
    for frame in rec.frames:
        a, b = known.step(frame), blind.step(frame)
    # 10 steps with fixes shrink the position variance far below the prediction-only one
    assert np.trace(a.vehicles.cov[0, :2, :2]) < 0.5 * np.trace(b.vehicles.cov[0, :2, :2])
