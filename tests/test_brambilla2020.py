"""Scenarios `brambilla-road` and `brambilla-crossroad` (Brambilla 2020 §V): the paper's
settings, sensing and communication ranges, and the feature motion model."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.motion import CVVelocityNoise
from cooploc.scenarios import get_preset
from cooploc.scenarios.brambilla2020 import KMH
from helpers import preset_recording

N_SIGMA = 6.0


def test_presets_carry_the_papers_settings() -> None:
    road = get_preset("brambilla-road").params
    assert (road.n_vehicles, road.n_features, road.dt, road.headway) == (2, 2, 1.0, 5.0)
    assert road.speed == pytest.approx(25 * KMH)
    assert (road.sigma_accel_along, road.sigma_accel_cross) == (0.2, 0.001)
    assert (road.gnss_position_std, road.gnss_velocity_std) == (8.0, 0.1)
    assert (road.v2f_position_std, road.v2f_velocity_std) == (0.2, 0.1)
    cross = get_preset("brambilla-crossroad").params
    assert (cross.n_vehicles, cross.cluster_size, cross.speed) == (12, 3, pytest.approx(50 * KMH))
    assert (cross.sigma_accel_along, cross.gnss_position_std, cross.gnss_velocity_std) == (0.35, 9.0, 0.25)
    assert (cross.communication_range, cross.sensing_range, cross.feature_radius) == (250.0, 75.0, 150.0)
    assert (cross.v2f_position_std, cross.v2f_velocity_std) == (0.1, 0.1)


def test_ranges_are_respected() -> None:
    rec = preset_recording("brambilla-crossroad", [1, 0], {"n_features": 30})
    truth = rec.truth
    for frame, origin in zip(rec.frames, truth.origin, strict=True):
        v2f = frame.batches["v2f"]
        vi = np.searchsorted(truth.vehicle_ids, v2f.sensor)
        fi = np.searchsorted(truth.feature_ids, origin["v2f"])
        gap = truth.vehicle_states[frame.k, vi, :2] - truth.feature_states[frame.k, fi, :2]
        dist = np.linalg.norm(gap, axis=1)
        assert (dist <= 75.0).all()
        pos = truth.vehicle_states[frame.k, :, :2]
        # every pair within R_c, in the order of the upper triangle of the distance matrix
        i, j = np.nonzero(np.triu(np.linalg.norm(pos[:, None] - pos[None], axis=2) <= 250.0, k=1))
        expected = np.stack([truth.vehicle_ids[i], truth.vehicle_ids[j]], axis=1)
        np.testing.assert_array_equal(frame.links, expected)
        # every pair within R_s is sensed (P_D = 1)
        d_all = np.linalg.norm(pos[:, None] - truth.feature_states[frame.k][None, :, :2], axis=2)
        assert len(v2f) == int((d_all <= 75.0).sum())


def test_clusters_approach_the_junction() -> None:
    rec = preset_recording("brambilla-crossroad", [2, 0])
    start = rec.truth.vehicle_states[0]
    dist = np.linalg.norm(start[:, :2], axis=1)
    assert ((dist > 200) & (dist < 260)).all()
    # velocity points at the centre, 50 km/h ± start spread
    towards = -np.einsum("ni,ni->n", start[:, :2], start[:, 2:]) / dist
    assert (np.abs(towards - 50 * KMH) < N_SIGMA * 0.5).all()
    assert len({tuple(np.sign(np.round(v, 6))) for v in start[:, 2:]}) == 4   # four approaches


def test_features_on_sidewalks_and_their_speed() -> None:
    rec = preset_recording("brambilla-crossroad", [3, 0], {"n_features": 60, "feature_speed": 2.0})
    f0 = rec.truth.feature_states[0]
    on_sidewalk = np.isclose(np.abs(f0[:, 0]), 8.0) | np.isclose(np.abs(f0[:, 1]), 8.0)
    assert on_sidewalk.all()
    assert (np.linalg.norm(f0[:, :2], axis=1) <= 150.0 * np.sqrt(2)).all()
    np.testing.assert_allclose(np.linalg.norm(f0[:, 2:], axis=1), 2.0)


def test_static_features_do_not_move() -> None:
    rec = preset_recording("brambilla-road", [4, 0], {"feature_spacing": 6.0})
    f = rec.truth.feature_states
    np.testing.assert_array_equal(f[0], f[-1])
    assert f[0, 1, 0] - f[0, 0, 0] == pytest.approx(6.0)


def test_velocity_noise_model() -> None:
    model = CVVelocityNoise(0.02, 0.01)
    Q = model.noise_covariance(1.0, np.array([[0.0, 0.0, 0.0, 2.0]]))[0]   # walking north
    G = np.kron([[1.0], [1.0]], np.eye(2))
    expected = G @ np.diag([0.01**2, 0.02**2]) @ G.T                       # along = y
    np.testing.assert_allclose(Q, expected, atol=1e-15)
    np.testing.assert_allclose(model.transition_matrix(1.0) @ [0, 0, 1.0, 2.0], [1.0, 2.0, 1.0, 2.0])


def test_gnss_noise_level() -> None:
    rec = preset_recording("brambilla-crossroad", [5, 0])
    z = np.concatenate([f.batches["gnss"].z for f in rec.frames])
    x = rec.truth.vehicle_states.reshape(-1, 4)
    err = z - x
    n = err.shape[0]
    np.testing.assert_allclose(err.std(axis=0), [9.0, 9.0, 0.25, 0.25], rtol=N_SIGMA / np.sqrt(2 * n))


def test_bad_geometry() -> None:
    with pytest.raises(ConfigError, match="geometry"):
        get_preset("brambilla-road").params.with_overrides({"geometry": "roundabout"})
