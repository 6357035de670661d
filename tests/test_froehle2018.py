"""The ``froehle2018`` scenario against Fröhle, Lindberg & Wymeersch 2018, §V-A.

Checks the paper's parameters, the feature process (N(0, 0.25 I) at the middle step,
crossing near the origin), the per-step shuffling of V2F rows, parameter overrides
and validation, and that the priors handed to estimators are the exact marginals of
what is simulated (Monte Carlo, 6-sigma bounds: pass for any seed).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.motion import ConstantVelocity, simulate_backward
from cooploc.scenarios import get_preset
from cooploc.scenarios.froehle2018 import FEATURE_ID_OFFSET, FroehleParams, feature_prior
from helpers import assert_covariance_close, froehle_recording

# Matrices computed two ways (recursion vs closed form): round-off over ≤ 250 steps.
EXACT_RTOL = 1e-10


def test_defaults_are_the_papers() -> None:
    params = FroehleParams()
    assert params.n_vehicles == 2                       # S = 2
    assert params.n_features == 3                       # K = 3
    assert params.dt == 0.5                             # ΔT = 0.5 s, eq. (28)
    assert params.noise_density == 0.1                  # r = 0.1, eq. (29)
    assert params.gnss_variances == (0.01, 15.0)        # σ_1² = 1e-2 m², σ_2² = 15 m²
    assert params.v2f_variance == 1.0                   # σ²_V2F = 1 m²
    assert params.feature_init_variance == 0.25         # f ~ N(0, 0.25 I_4) at t = 251
    assert params.n_steps == 501                        # 501 time steps
    assert params.detection_probability == 1.0 and params.clutter_rate == 0.0
    assert params.shuffle
    assert get_preset("froehle2018").params == params


def test_generated_setup_carries_the_papers_models(seed: int) -> None:
    rec = froehle_recording([seed, 10], n_steps=7)
    setup = rec.setup
    assert setup.dt == 0.5 and setup.n_steps == 7 and len(rec.frames) == 7
    for motion in (setup.vehicle_motion, setup.feature_motion):
        assert motion == ConstantVelocity(0.1)
    gnss, v2f = setup.sensors["gnss"], setup.sensors["v2f"]
    np.testing.assert_array_equal(gnss.covariance_of([0, 1]), [0.01 * np.eye(2), 15 * np.eye(2)])
    np.testing.assert_array_equal(v2f.covariance_of([0, 1]), [np.eye(2), np.eye(2)])
    np.testing.assert_array_equal(rec.truth.vehicle_ids, [0, 1])
    np.testing.assert_array_equal(rec.truth.feature_ids, FEATURE_ID_OFFSET + np.arange(3))
    assert setup.detection_probability == 1.0 and setup.clutter_rate == 0.0
    assert setup.clutter_region is None
    for k, frame in enumerate(rec.frames):
        assert frame.t == pytest.approx(0.5 * k)
        np.testing.assert_array_equal(frame.vehicles, [0, 1])
        gnss_batch, v2f_batch = frame.batches["gnss"], frame.batches["v2f"]
        assert len(gnss_batch) == 2 and len(v2f_batch) == 6
        np.testing.assert_array_equal(gnss_batch.subject, [0, 1])
        np.testing.assert_array_equal(v2f_batch.subject, -1)   # association unknown
        np.testing.assert_array_equal(rec.truth.origin[k]["gnss"], [0, 1])
        np.testing.assert_array_equal(np.sort(rec.truth.origin[k]["v2f"]),
                                      np.repeat(FEATURE_ID_OFFSET + np.arange(3), 2))


def test_measurements_follow_eq_30_and_v2f_model(seed: int) -> None:
    rec = froehle_recording([seed, 11], n_steps=200)
    truth = rec.truth
    white_gnss, white_v2f = [], []
    for k, frame in enumerate(rec.frames):
        gnss, v2f = frame.batches["gnss"], frame.batches["v2f"]
        r = gnss.z - truth.vehicles_at(k, gnss.subject)[:, :2]
        white_gnss.append(r / np.sqrt(gnss.cov[:, [0, 1], [0, 1]]))
        f = truth.features_at(k, truth.origin[k]["v2f"])[:, :2]
        x = truth.vehicles_at(k, v2f.sensor)[:, :2]
        white_v2f.append(v2f.z - (f - x))  # σ²_V2F = 1: already white
    assert_covariance_close(np.concatenate(white_gnss), np.eye(2))
    assert_covariance_close(np.concatenate(white_v2f), np.eye(2))


def test_features_at_the_middle_step_are_n_0_025(seed: int) -> None:
    params = FroehleParams(n_vehicles=1, gnss_variances=(0.01,), n_features=4000, n_steps=5)
    rec = get_preset("froehle2018").generate(np.random.default_rng([seed, 12]), params)
    mid = (params.n_steps - 1) // 2
    assert_covariance_close(rec.truth.feature_states[mid], 0.25 * np.eye(4))


def test_features_cross_near_the_origin_mid_run(seed: int) -> None:
    params = FroehleParams(n_vehicles=1, gnss_variances=(0.01,), n_features=30)  # the paper's 501 steps
    rec = get_preset("froehle2018").generate(np.random.default_rng([seed, 13]), params)
    dist = np.linalg.norm(rec.truth.feature_states[:, :, :2], axis=2)  # (T, K)
    mid = (params.n_steps - 1) // 2
    assert mid == 250  # the paper's t = 251 (1-based)
    # at mid-run |p| is Rayleigh(0.5 m): P(|p| > 3.5 m) = exp(−24.5) ≈ 2e-11 per feature
    assert dist[mid].max() < 3.5
    # 125 s away from the middle the features are tens of metres out (σ ≈ 60 m)
    assert dist[0].mean() > 20.0 and dist[-1].mean() > 20.0


def test_v2f_rows_are_shuffled_every_step(seed: int) -> None:
    rec = froehle_recording([seed, 14])
    orders = {0: set(), 1: set()}
    for k, frame in enumerate(rec.frames):
        sensor = frame.batches["v2f"].sensor
        assert np.count_nonzero(np.diff(sensor)) == 1  # rows grouped per vehicle
        origin = rec.truth.origin[k]["v2f"]
        for s in orders:
            orders[s].add(tuple(origin[sensor == s].tolist()))
    # 40 steps with 3! orders each: all the same with probability 6^-39
    assert all(len(o) > 1 for o in orders.values())
    unshuffled = froehle_recording([seed, 14], shuffle=False)
    for k in range(len(unshuffled.frames)):
        np.testing.assert_array_equal(unshuffled.truth.origin[k]["v2f"],
                                      np.tile(FEATURE_ID_OFFSET + np.arange(3), 2))


def test_parameters_are_overridable(seed: int) -> None:
    params = FroehleParams().with_overrides({
        "n_vehicles": "4", "n_features": "5", "n_steps": "6", "gnss_variances": "0.01,15,4",
        "v2f_variance": "3", "dt": "0.1",
    })
    assert params.gnss_variances == (0.01, 15.0, 4.0) and params.dt == 0.1
    rec = get_preset("froehle2018").generate(np.random.default_rng([seed, 15]), params)
    assert len(rec.frames) == 6 and rec.setup.dt == 0.1
    assert rec.frames[3].t == pytest.approx(0.3)
    assert rec.truth.feature_states.shape == (6, 5, 4)
    # vehicle s uses entry min(s, len − 1): the last variance repeats
    np.testing.assert_array_equal(
        rec.setup.sensors["gnss"].covariance_of([0, 1, 2, 3])[:, 0, 0], [0.01, 15.0, 4.0, 4.0])
    np.testing.assert_array_equal(rec.setup.sensors["v2f"].covariance_of([2]), [3 * np.eye(2)])
    assert len(rec.frames[0].batches["v2f"]) == 4 * 5


def test_gnss_variances_longer_than_vehicles_rejected() -> None:
    with pytest.raises(ConfigError, match="gnss_variances"):
        FroehleParams(n_vehicles=2, gnss_variances=(0.01, 15.0, 3.0))
    with pytest.raises(ConfigError, match="gnss_variances"):
        FroehleParams().with_overrides({"n_vehicles": "1"})


@pytest.mark.parametrize(("key", "value"), [
    ("n_steps", "0"), ("dt", "-0.5"), ("gnss_variances", "0.01,-1"),
    ("detection_probability", "1.5"), ("clutter_rate", "-2"), ("n_features", "many"),
])
def test_bad_values_rejected(key: str, value: str) -> None:
    with pytest.raises(ConfigError, match=key):
        FroehleParams().with_overrides({key: value})


def test_unknown_key_rejected() -> None:
    with pytest.raises(ConfigError, match="unknown key 'n_cars'"):
        FroehleParams().with_overrides({"n_cars": "3"})


def test_clutter_and_missed_detections(seed: int) -> None:
    rec = froehle_recording([seed, 16], n_steps=200, detection_probability=0.7, clutter_rate=2.0)
    assert rec.setup.detection_probability == 0.7 and rec.setup.clutter_rate == 2.0
    np.testing.assert_array_equal(rec.setup.clutter_region, [[-50, 50], [-50, 50]])
    origins = np.concatenate([o["v2f"] for o in rec.truth.origin])
    T, S, K = 200, 2, 3
    detected, clutter = np.count_nonzero(origins >= 0), np.count_nonzero(origins == -1)
    # binomial(T S K, 0.7) and Poisson(2 T S): within 6 sigma
    assert abs(detected - 0.7 * T * S * K) < 6 * np.sqrt(T * S * K * 0.21)
    assert abs(clutter - 2.0 * T * S) < 6 * np.sqrt(2.0 * T * S)


# ----------------------------------------------------------------------------
# priors given to estimators are the exact marginals of the simulation
# ----------------------------------------------------------------------------


def test_feature_prior_closed_form() -> None:
    params = FroehleParams()
    motion = ConstantVelocity(params.noise_density)
    mean, cov = feature_prior(params, motion)
    A_inv = np.linalg.inv(motion.transition_matrix(params.dt))
    Q, n = motion.noise_covariance(params.dt), 250
    # A⁻ⁿ (0.25 I) A⁻ⁿᵀ + Σ_{j=1..n} A⁻ʲ Q A⁻ʲᵀ
    want = np.linalg.matrix_power(A_inv, n) @ (0.25 * np.eye(4)) @ np.linalg.matrix_power(A_inv, n).T
    for j in range(1, n + 1):
        Aj = np.linalg.matrix_power(A_inv, j)
        want += Aj @ Q @ Aj.T
    np.testing.assert_array_equal(mean, 0.0)
    np.testing.assert_allclose(cov, want, rtol=EXACT_RTOL)
    # broad: p_0 = p_mid − t v_mid − ∫ (white acceleration) over t = 125 s, so its
    # variance is 0.25 + t² 0.25 + r t³/3 ≈ 263² m² (eq. (29) is the exact discretisation)
    t = 125.0
    np.testing.assert_allclose(cov[0, 0], 0.25 + t**2 * 0.25 + 0.1 * t**3 / 3, rtol=EXACT_RTOL)


def test_feature_prior_is_the_marginal_of_the_backward_simulation(
        rng: np.random.Generator) -> None:
    params = FroehleParams(n_steps=11)  # middle step 5
    motion = ConstantVelocity(params.noise_density)
    f_mid = rng.normal(0.0, 0.5, size=(20000, 4))
    path = simulate_backward(motion, f_mid, 6, params.dt, rng)
    mean, cov = feature_prior(params, motion)
    assert_covariance_close(path[0], cov, mean)


def test_generated_priors_are_the_marginals(seed: int) -> None:
    params = FroehleParams(n_vehicles=1, gnss_variances=(0.01,), n_features=4000, n_steps=11)
    rec = get_preset("froehle2018").generate(np.random.default_rng([seed, 17]), params)
    prior = rec.setup.feature_prior
    np.testing.assert_array_equal(prior.ids, FEATURE_ID_OFFSET + np.arange(4000))
    mean, cov = feature_prior(params, ConstantVelocity(params.noise_density))
    np.testing.assert_array_equal(prior.mean, np.broadcast_to(mean, (4000, 4)))
    np.testing.assert_array_equal(prior.cov, np.broadcast_to(cov, (4000, 4, 4)))
    assert_covariance_close(rec.truth.feature_states[0], cov, mean)


def test_vehicle_prior_is_the_start_distribution(seed: int) -> None:
    params = FroehleParams(n_vehicles=3000, n_features=0, n_steps=2)
    rec = get_preset("froehle2018").generate(np.random.default_rng([seed, 18]), params)
    prior = rec.setup.vehicle_prior
    start = np.diag([100.0, 100.0, 1.0, 1.0])  # σ_p0 = 10 m, σ_v0 = 1 m/s (module doc)
    np.testing.assert_array_equal(prior.ids, np.arange(3000))
    np.testing.assert_array_equal(prior.mean, 0.0)
    np.testing.assert_array_equal(prior.cov, np.broadcast_to(start, (3000, 4, 4)))
    assert_covariance_close(rec.truth.vehicle_states[0], start)


def test_same_seed_same_recording_and_sensor_changes_keep_trajectories(seed: int) -> None:
    a = froehle_recording([seed, 19])
    b = froehle_recording([seed, 19])
    np.testing.assert_array_equal(a.truth.vehicle_states, b.truth.vehicle_states)
    np.testing.assert_array_equal(a.truth.feature_states, b.truth.feature_states)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        for kind in fa.batches:
            for name in ("z", "cov", "sensor", "subject"):
                np.testing.assert_array_equal(getattr(fa.batches[kind], name),
                                              getattr(fb.batches[kind], name))
    # documented: only sensor draws change when a sensor parameter changes
    c = froehle_recording([seed, 19], v2f_variance=4.0)
    np.testing.assert_array_equal(a.truth.vehicle_states, c.truth.vehicle_states)
    np.testing.assert_array_equal(a.truth.feature_states, c.truth.feature_states)
    d = froehle_recording([seed, 20])
    assert not np.array_equal(a.truth.vehicle_states, d.truth.vehicle_states)


def test_params_round_trip_through_dict() -> None:
    params = FroehleParams(n_vehicles=3, gnss_variances=(0.1, 2.0, 3.0), clutter_rate=1.0)
    assert FroehleParams.from_dict(params.to_dict()) == params
    assert dataclasses.replace(params, n_steps=9).n_steps == 9
