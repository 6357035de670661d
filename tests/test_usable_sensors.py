"""What an estimator can use (`usable_sensors`): refused where it can use nothing, told where it
leaves a kind aside (`cooploc.registry.construct`, `unused_kinds`; issue 16 item 1)."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.estimators.gnss_kf import GnssKF
from cooploc.registry import estimators, make_estimator, unused_kinds
from cooploc.sensors import _SENSORS
from cooploc.types import Batch, Frame
from helpers import froehle_recording, preset_recording

ZHANG_OFFERS = "gnss (anonymous-position), radar (infrastructure-radar)"


@pytest.fixture(scope="module")
def zhang():
    return preset_recording("zhang2016-cv", 0, {"n_steps": 3})


@pytest.mark.parametrize("name, reads", [
    ("gnss-kf", "gnss (gnss-position), odometry (odometry)"),
    ("oracle-kf", "gnss (gnss-position), v2f (relative-position), odometry (odometry)"),
    ("icp", "gnss (gnss-position), odometry (odometry), v2f (relative-position)"),
    ("icp-da-lc", "gnss (gnss-position), odometry (odometry), v2f (relative-position)"),
    ("icp-da-pf", "gnss (gnss-position), odometry (odometry), v2f (relative-position)"),
    ("rsu-bp", "gnss (gnss-position), v2f (relative-position), odometry (odometry)"),
])
def test_an_estimator_that_can_use_nothing_of_anonymous_gnss_is_refused(zhang, name, reads):
    # before: gnss-kf and oracle-kf ignored the anonymous rows and returned the exact prior (0.000 m)
    message = (f"{name} can use nothing this scenario offers: it reads {reads}; "
               f"the scenario has {ZHANG_OFFERS}")
    with pytest.raises(ConfigError) as info:
        make_estimator(name, zhang.setup, None, np.random.default_rng(0), zhang.truth)
    assert str(info.value) == message


@pytest.mark.parametrize("name, unused", [
    ("kf-known-da", ("radar",)), ("gm-phd", ("radar",)), ("sme-pf", ()), ("sme-ukf", ()),
])
def test_the_anonymous_gnss_methods_are_accepted_and_name_what_they_leave_aside(zhang, name, unused):
    make_estimator(name, zhang.setup, None, np.random.default_rng(0), zhang.truth)
    assert unused_kinds(estimators()[name], zhang.setup) == unused


def test_the_gnss_only_baseline_says_it_leaves_v2f_aside():
    setup = froehle_recording(0, n_steps=3).setup
    assert unused_kinds(GnssKF, setup) == ("v2f",)
    assert unused_kinds(estimators()["oracle-kf"], setup) == ()
    assert unused_kinds(estimators()["rsu-bp"], setup) == ()


def test_every_estimator_declares_known_kinds_and_sensor_models():
    models = {m.name for m in _SENSORS}
    for name, cls in estimators().items():
        usable = cls.usable_sensors
        assert usable, name
        for kind, accepted in usable.items():
            assert isinstance(accepted, tuple) and set(accepted) <= models, (name, kind, accepted)
        assert set(getattr(cls, "required_sensors", ())) <= set(usable), name


def test_a_class_without_the_declaration_is_taken_to_use_everything(zhang):
    legacy = type("Legacy", (), {"name": "legacy"})   # a plug-in written before usable_sensors
    assert unused_kinds(legacy, zhang.setup) is None


def test_gnss_rows_the_baseline_cannot_use_are_counted_not_hidden():
    recording = froehle_recording(0, n_steps=3)
    frames = list(recording.frames)
    gnss = frames[1].batches["gnss"]
    subject = gnss.subject.copy()
    subject[0] = -1                                   # one fix arrives without its vehicle's id
    frames[1] = Frame(1, frames[1].t, frames[1].vehicles,
                      {**frames[1].batches, "gnss": Batch(gnss.z, gnss.cov, subject, subject)})
    est = GnssKF(recording.setup, GnssKF.Params(), np.random.default_rng(0))
    assert [est.step(f).info["gnss_rows_unused"] for f in frames] == [0, 1, 0]


@pytest.mark.parametrize("sensor_model, use_identities, unused", [
    ("anonymous", True, ("odometry", "radar")),      # odometry names a vehicle no PHD component has
    ("identified", True, ("radar",)),                 # one PHD per vehicle: its odometry is fused
    ("identified", False, ("odometry", "radar")),     # one PHD of all rows: nowhere to put it
])
def test_gm_phd_names_odometry_it_cannot_place(zhang, sensor_model, use_identities, unused):
    from dataclasses import replace

    from cooploc.sensors import GnssPosition, Odometry
    gnss = zhang.setup.sensors["gnss"]
    if sensor_model == "identified":
        gnss = GnssPosition(default_cov=gnss.default_cov)
    setup = replace(zhang.setup, sensors={**zhang.setup.sensors, "gnss": gnss,
                                          "odometry": Odometry(default_cov=np.eye(2))})
    cls = estimators()["gm-phd"]
    built = make_estimator("gm-phd", setup, cls.Params(use_identities=use_identities),
                           np.random.default_rng(0), zhang.truth)
    assert unused_kinds(cls, setup, built) == unused
    assert unused_kinds(cls, setup) == ("radar",)      # the class alone cannot tell


@pytest.mark.parametrize("features, unused", [("known", ("odometry",)), ("unknown", ())])
def test_rsu_bp_fuses_odometry_only_in_its_city_mode(features, unused):
    from dataclasses import replace

    from cooploc.sensors import Odometry
    recording = froehle_recording(0, n_steps=3)
    setup = replace(recording.setup, sensors={**recording.setup.sensors,
                                              "odometry": Odometry(default_cov=np.eye(2))})
    cls = estimators()["rsu-bp"]
    built = make_estimator("rsu-bp", setup, cls.Params(features=features), np.random.default_rng(0))
    assert unused_kinds(cls, setup, built) == unused
