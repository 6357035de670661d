"""Metrics: errors, RMSE definition, CDF, association accuracy, NEES."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from cooploc.geometry import wrap_angle
from cooploc.metrics import (
    FEATURE,
    VEHICLE,
    association_accuracy,
    ecdf,
    evaluate,
    nees,
    per_entity_rmse,
    rmse,
)
from cooploc.scenarios import get_preset
from cooploc.types import Estimate, StateSet


def test_rmse_and_per_entity_rmse():
    assert rmse([3.0, 4.0]) == np.sqrt(12.5)
    assert np.isnan(rmse([]))
    got = per_entity_rmse(np.array([1, 2, 1]), np.array([1.0, 2.0, 3.0]))
    assert got == {1: np.sqrt(5.0), 2: 2.0}


def test_ecdf():
    x, p = ecdf([3.0, 1.0, 2.0])
    np.testing.assert_array_equal(x, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(p, [1 / 3, 2 / 3, 1.0])


@given(st.floats(-1e6, 1e6, allow_nan=False))
def test_wrap_angle_range(a):
    w = wrap_angle(a)
    assert -np.pi <= w < np.pi
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-6)  # same angle (float round-off)


def test_association_accuracy_and_nees():
    assert association_accuracy(np.array([1, 2, -1]), np.array([1, 3, -1])) == 2 / 3
    est = StateSet([0], [[0.0, 0.0]], [np.diag([4.0, 1.0])])
    np.testing.assert_allclose(nees(est, np.array([[2.0, 1.0]])), [2.0])


def test_evaluate_scores_vehicles_and_features_by_id():
    preset = get_preset("froehle2018")
    rec = preset.generate(np.random.default_rng(0), preset.params.with_overrides({"n_steps": 3}))
    truth = rec.truth
    estimates = []
    for k in range(3):
        v = truth.vehicle_states[k] + np.array([3.0, 4.0, 0.0, 1.0])   # 5 m, 1 m/s off
        f = truth.feature_states[k][::-1]                               # reversed order
        estimates.append(Estimate(
            StateSet(truth.vehicle_ids, v, np.repeat(np.eye(4)[None], 2, 0)),
            StateSet(truth.feature_ids[::-1], f, np.repeat(np.eye(4)[None], 3, 0)),
        ))
    table = evaluate(rec, estimates)
    veh = table.kind == VEHICLE
    np.testing.assert_allclose(table.err_pos[veh], 5.0)
    np.testing.assert_allclose(table.err_vel[veh], 1.0)
    np.testing.assert_allclose(table.err_pos[table.kind == FEATURE], 0.0, atol=1e-12)
    assert np.isnan(table.err_heading).all()
    assert len(table) == 3 * (2 + 3)


def test_track_identities_take_the_majority_origin():
    from cooploc.metrics import relabel, track_identities
    from cooploc.types import StateSet

    tracks = [np.array([7, 7, 9, -1]), np.array([7, 9, 9])]
    origins = [np.array([1000, 1001, 1001, 1000]), np.array([1000, 1001, 1000])]
    # track 7: 1000 twice, 1001 once; track 9: 1001 twice, 1000 once; −1 is not a track
    assert track_identities(tracks, origins) == {7: 1000, 9: 1001}
    assert track_identities([np.array([5, 5])], [np.array([3, 2])]) == {5: 2}   # tie: smaller id
    states = StateSet(np.array([9, 7, 8]), np.arange(12.0).reshape(3, 4), np.repeat(np.eye(4)[None], 3, 0))
    named = relabel(states, {7: 1000, 9: 1001})
    assert named.ids.tolist() == [1001, 1000]                 # unmapped track 8 dropped
    np.testing.assert_array_equal(named.mean, states.mean[:2])
    twice = relabel(states, {7: 1000, 9: 1000, 8: 1000})
    assert twice.ids.tolist() == [1000] and twice.mean[0, 0] == 0.0   # first track kept
