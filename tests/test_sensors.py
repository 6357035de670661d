"""`cooploc.sensors`: measurement simulation (shapes, noise, association bookkeeping,
detection and clutter statistics) and likelihoods against scipy.

Statistical checks use 6-sigma bounds (binomial / Poisson / sample covariance), so a
correct simulator fails them with probability below ~1e-8 for any seed.
"""

from __future__ import annotations

import json
from itertools import permutations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from cooploc.errors import InvalidInputError
from cooploc.geometry import fit_pose, rotation, to_local
from cooploc.sensors import (
    AnonymousPosition,
    GnssPosition,
    InfrastructureRadar,
    Odometry,
    RelativePosition,
    selection_matrix,
    sensor_from_dict,
)
from cooploc.types import Batch
from helpers import assert_covariance_close

N_SIGMA = 6.0
# Likelihoods: Cholesky (ours) vs eigendecomposition (scipy), values of order 10.
LOGPDF_ATOL = 1e-9


def test_selection_matrix() -> None:
    np.testing.assert_array_equal(selection_matrix((0, 1), 4), [[1, 0, 0, 0], [0, 1, 0, 0]])
    # Fröhle eq. (30): H = [1 0]ᵀ ⊗ I_2 ... as a row selector, [1, 0] ⊗ I_2
    np.testing.assert_array_equal(selection_matrix((0, 1), 4), np.kron([[1, 0]], np.eye(2)))
    np.testing.assert_array_equal(selection_matrix((2, 0), 3), [[0, 0, 1], [1, 0, 0]])


# ----------------------------------------------------------------------------
# GNSS
# ----------------------------------------------------------------------------


def paper_gnss(default: float | None = None) -> GnssPosition:
    return GnssPosition({0: 0.01 * np.eye(2), 1: 15.0 * np.eye(2)},
                        None if default is None else default * np.eye(2))


def test_gnss_covariance_lookup_per_entity() -> None:
    gnss = paper_gnss(default=2.0)
    cov = gnss.covariance_of([1, 0, 7, 1])
    np.testing.assert_array_equal(cov, np.array([15.0, 0.01, 2.0, 15.0])[:, None, None] * np.eye(2))
    with pytest.raises(InvalidInputError, match="entity 7"):
        paper_gnss().covariance_of([0, 7])


def test_gnss_rejects_bad_covariance() -> None:
    with pytest.raises(InvalidInputError, match="positive definite"):
        GnssPosition({0: np.diag([1.0, -1.0])})
    with pytest.raises(InvalidInputError, match="shape"):
        GnssPosition({0: np.eye(3)})


def test_gnss_measure_shapes_and_ids(rng: np.random.Generator) -> None:
    gnss = paper_gnss()
    ids = np.array([1, 0])
    states = rng.standard_normal((2, 4))
    batch = gnss.measure(ids, states, rng)
    assert isinstance(batch, Batch)
    assert batch.z.shape == (2, 2) and batch.cov.shape == (2, 2, 2)
    np.testing.assert_array_equal(batch.sensor, ids)
    np.testing.assert_array_equal(batch.subject, ids)
    np.testing.assert_array_equal(batch.cov, gnss.covariance_of(ids))
    empty = gnss.measure(np.zeros(0, int), np.zeros((0, 4)), rng)
    assert len(empty) == 0 and empty.dim == 2


@pytest.mark.parametrize("vehicle", [0, 1])
def test_gnss_noise_statistics(rng: np.random.Generator, vehicle: int) -> None:
    gnss = paper_gnss()
    n = 20000
    states = rng.standard_normal((n, 4)) * 50
    batch = gnss.measure(np.full(n, vehicle), states, rng)
    assert_covariance_close(batch.z - states[:, :2], gnss.covariances[vehicle])


def test_gnss_position_and_velocity(rng: np.random.Generator) -> None:
    # Brambilla 2020 eq. (3): GNSS gives position and velocity
    gnss = GnssPosition(default_cov=np.diag([4.0, 4.0, 0.1, 0.1]), state_indices=(0, 1, 2, 3))
    states = rng.standard_normal((20000, 4))
    batch = gnss.measure(np.arange(20000), states, rng)
    assert batch.dim == 4
    assert_covariance_close(batch.z - states, np.diag([4.0, 4.0, 0.1, 0.1]))


def test_gnss_log_likelihood_equals_scipy(rng: np.random.Generator) -> None:
    gnss = paper_gnss()
    ids = np.array([0, 1, 1])
    states = rng.standard_normal((3, 4))
    batch = gnss.measure(ids, states, rng)
    guess = states + rng.standard_normal((3, 4))
    got = gnss.log_likelihood(batch, guess)
    want = [multivariate_normal(guess[i, :2], batch.cov[i]).logpdf(batch.z[i]) for i in range(3)]
    np.testing.assert_allclose(got, want, rtol=0, atol=LOGPDF_ATOL)


# ----------------------------------------------------------------------------
# V2F relative position
# ----------------------------------------------------------------------------


def scene(rng: np.random.Generator, n: int = 3, K: int = 4):
    vehicle_ids = np.array([5, 2, 9, 4, 7][:n])
    feature_ids = 1000 + np.arange(K)
    vehicles = 20 * rng.standard_normal((n, 4))
    features = 20 * rng.standard_normal((K, 4))
    v2f = RelativePosition({5: 0.5 * np.eye(2), 2: np.diag([2.0, 0.3])}, default_cov=np.eye(2))
    return v2f, vehicle_ids, vehicles, feature_ids, features


def assert_grouped(sensor: np.ndarray) -> None:
    """Rows of each sensing vehicle are contiguous."""
    changes = np.count_nonzero(np.diff(sensor)) if sensor.size else 0
    assert changes == max(np.unique(sensor).size - 1, 0), f"rows not grouped: {sensor}"


def test_v2f_shapes_association_and_grouping(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng)
    batch, origin = v2f.measure(vids, vehicles, fids, features, rng)
    assert batch.z.shape == (12, 2) and batch.cov.shape == (12, 2, 2) and origin.shape == (12,)
    np.testing.assert_array_equal(batch.subject, -1)  # association unknown to the receiver
    assert_grouped(batch.sensor)
    for s in vids:  # P_D = 1: every vehicle sees every feature exactly once
        assert sorted(origin[batch.sensor == s].tolist()) == fids.tolist()
    # per-vehicle noise covariance on every row
    np.testing.assert_array_equal(batch.cov, v2f.covariance_of(batch.sensor))


def test_v2f_rows_match_their_origin(rng: np.random.Generator) -> None:
    # z = H f − H x_s + w with w ~ N(0, W_s): whitened residuals are standard normal
    v2f, vids, vehicles, fids, features = scene(rng, n=3, K=5)
    white = []
    for _ in range(1500):
        batch, origin = v2f.measure(vids, vehicles, fids, features, rng)
        f = features[np.searchsorted(fids, origin), :2]
        x = vehicles[[int(np.flatnonzero(vids == s)[0]) for s in batch.sensor], :2]
        residual = batch.z - (f - x)
        L = np.linalg.cholesky(batch.cov)
        white.append(np.linalg.solve(L, residual[..., None])[..., 0])
    assert_covariance_close(np.concatenate(white), np.eye(2))


def test_v2f_shuffles_rows_within_each_vehicle(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng, n=2, K=3)
    n_draws = 600
    seen = {s: [] for s in vids.tolist()}
    for _ in range(n_draws):
        batch, origin = v2f.measure(vids, vehicles, fids, features, rng)
        assert_grouped(batch.sensor)
        for s in seen:
            seen[s].append(tuple(origin[batch.sensor == s].tolist()))
    for orders in seen.values():
        # every one of the 3! orders occurs; P(one missing) ≤ 6 (5/6)^600 ≈ 1e-46
        assert set(orders) == set(permutations(fids.tolist()))
        # the first row is uniform over features: binomial(600, 1/3) within 6 sigma
        first = np.array([o[0] for o in orders])
        counts = np.array([(first == f).sum() for f in fids])
        sd = np.sqrt(n_draws * (1 / 3) * (2 / 3))
        assert (np.abs(counts - n_draws / 3) < N_SIGMA * sd).all(), counts


def test_v2f_without_shuffle_keeps_order(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng, n=3, K=4)
    batch, origin = v2f.measure(vids, vehicles, fids, features, rng, shuffle=False)
    np.testing.assert_array_equal(batch.sensor, np.repeat(vids, 4))
    np.testing.assert_array_equal(origin, np.tile(fids, 3))


def test_v2f_detection_probability(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng, n=2, K=5)
    p_d, n_draws = 0.7, 2000
    total = 0
    for _ in range(n_draws):
        batch, origin = v2f.measure(vids, vehicles, fids, features, rng,
                                    detection_probability=p_d)
        for s in vids:  # at most one detection per (vehicle, feature) pair
            o = origin[batch.sensor == s]
            assert np.unique(o).size == o.size
        total += len(batch)
    trials = n_draws * vids.size * fids.size
    sd = np.sqrt(trials * p_d * (1 - p_d))
    assert abs(total - p_d * trials) < N_SIGMA * sd, (total, p_d * trials)


def test_v2f_clutter_counts_and_region(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng, n=3, K=2)
    rate, n_draws = 2.0, 2000
    region = np.array([[-30.0, 30.0], [-10.0, 50.0]])
    clutter_z, clutter_count = [], np.zeros(3)
    for _ in range(n_draws):
        batch, origin = v2f.measure(vids, vehicles, fids, features, rng,
                                    clutter_rate=rate, clutter_region=region)
        assert_grouped(batch.sensor)
        clutter = origin == -1
        assert (origin[~clutter] >= 1000).all()
        assert (~clutter).sum() == vids.size * fids.size  # P_D = 1: all detections kept
        clutter_z.append(batch.z[clutter])
        clutter_count += [np.count_nonzero(clutter & (batch.sensor == s)) for s in vids]
        # a clutter row carries the noise covariance of the vehicle that reported it
        np.testing.assert_array_equal(batch.cov[clutter], v2f.covariance_of(batch.sensor[clutter]))
    # Poisson(rate) per vehicle and draw: the totals within 6 sigma
    mean = rate * n_draws
    assert (np.abs(clutter_count - mean) < N_SIGMA * np.sqrt(mean)).all(), clutter_count
    z = np.concatenate(clutter_z)
    assert ((z >= region[:, 0]) & (z <= region[:, 1])).all()
    width = region[:, 1] - region[:, 0]
    # uniform over the box: mean at its centre (sd width/√(12 N)), variance width²/12
    # (relative sd √((1/80 − 1/144) · 144 / N) ≈ √(0.8/N))
    mean_sd = width / np.sqrt(12 * len(z))
    assert (np.abs(z.mean(0) - region.mean(1)) < N_SIGMA * mean_sd).all()
    np.testing.assert_allclose(z.var(0), width**2 / 12, rtol=N_SIGMA * np.sqrt(0.8 / len(z)))


def test_v2f_visibility_mask(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng, n=3, K=4)
    visible = rng.random((3, 4)) < 0.5
    batch, origin = v2f.measure(vids, vehicles, fids, features, rng, visible=visible)
    got = {(int(s), int(f)) for s, f in zip(batch.sensor, origin, strict=True)}
    want = {(int(vids[i]), int(fids[j])) for i, j in zip(*np.nonzero(visible), strict=True)}
    assert got == want


def test_v2f_empty_inputs(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng)
    batch, origin = v2f.measure(np.zeros(0, int), np.zeros((0, 4)), fids, features, rng,
                                clutter_rate=1.0, clutter_region=np.array([[0, 1], [0, 1.0]]))
    assert len(batch) == 0 and origin.size == 0 and batch.dim == 2
    batch, origin = v2f.measure(vids, vehicles, np.zeros(0, int), np.zeros((0, 4)), rng)
    assert len(batch) == 0 and origin.size == 0


def test_v2f_bad_arguments(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng)
    with pytest.raises(InvalidInputError, match="detection_probability"):
        v2f.measure(vids, vehicles, fids, features, rng, detection_probability=0.0)
    with pytest.raises(InvalidInputError, match="clutter_rate"):
        v2f.measure(vids, vehicles, fids, features, rng, clutter_rate=-1.0)
    with pytest.raises(InvalidInputError, match="clutter_region"):
        v2f.measure(vids, vehicles, fids, features, rng, clutter_rate=1.0)
    with pytest.raises(InvalidInputError, match="visible"):
        v2f.measure(vids, vehicles, fids, features, rng, visible=np.ones((2, 2), bool))


def test_v2f_log_likelihood_equals_scipy(rng: np.random.Generator) -> None:
    v2f, vids, vehicles, fids, features = scene(rng)
    batch, origin = v2f.measure(vids, vehicles, fids, features, rng)
    f = features[np.searchsorted(fids, origin)] + rng.standard_normal((len(batch), 4))
    x = vehicles[[int(np.flatnonzero(vids == s)[0]) for s in batch.sensor]]
    got = v2f.log_likelihood(batch.z, batch.cov, f, x)
    want = [multivariate_normal(f[i, :2] - x[i, :2], batch.cov[i]).logpdf(batch.z[i])
            for i in range(len(batch))]
    np.testing.assert_allclose(got, want, rtol=0, atol=LOGPDF_ATOL)


# ----------------------------------------------------------------------------
# anonymous GNSS, infrastructure radar, odometry
# ----------------------------------------------------------------------------

# Noise-free simulations are compared with closed forms up to float rounding.
EXACT_ATOL = 1e-12


def _tiny_cov(dim: int = 2) -> np.ndarray:
    return 1e-30 * np.eye(dim)


def test_anonymous_rows_hide_identity_and_keep_origin(rng: np.random.Generator) -> None:
    sensor = AnonymousPosition(default_cov=_tiny_cov())
    ids = np.array([4, 9, 2, 7])
    states = rng.normal(size=(4, 4)) * 50
    batch, origin = sensor.measure(ids, states, rng)
    assert (batch.sensor == -1).all() and (batch.subject == -1).all()
    assert sorted(origin.tolist()) == sorted(ids.tolist())
    rows = {int(i): s for i, s in zip(ids, states, strict=True)}
    for z, entity in zip(batch.z, origin, strict=True):
        np.testing.assert_allclose(z, rows[int(entity)][:2], atol=EXACT_ATOL)


def test_anonymous_rows_are_shuffled(rng: np.random.Generator) -> None:
    sensor = AnonymousPosition(default_cov=np.eye(2))
    ids = np.arange(6)
    orders = {tuple(sensor.measure(ids, np.zeros((6, 4)), rng)[1]) for _ in range(50)}
    assert len(orders) > 1


def test_anonymous_detection_and_clutter(rng: np.random.Generator) -> None:
    sensor = AnonymousPosition(default_cov=np.eye(2))
    region = np.array([[-10.0, 10.0], [0.0, 5.0]])
    n_trials, n_ids, p_d, lam = 400, 5, 0.7, 2.0
    detected, clutter = 0, 0
    for _ in range(n_trials):
        batch, origin = sensor.measure(np.arange(n_ids), np.zeros((n_ids, 4)), rng,
                                       detection_probability=p_d, clutter_rate=lam, clutter_region=region)
        detected += int((origin >= 0).sum())
        clutter += int((origin < 0).sum())
        z_clutter = batch.z[origin < 0]
        assert ((z_clutter >= region[:, 0]) & (z_clutter <= region[:, 1])).all()
    n = n_trials * n_ids
    assert abs(detected - n * p_d) < N_SIGMA * np.sqrt(n * p_d * (1 - p_d))
    assert abs(clutter - n_trials * lam) < N_SIGMA * np.sqrt(n_trials * lam)


def test_anonymous_empty(rng: np.random.Generator) -> None:
    batch, origin = AnonymousPosition(default_cov=np.eye(2)).measure(np.zeros(0, int), np.zeros((0, 4)), rng)
    assert len(batch) == 0 and origin.shape == (0,)


def test_rotation_and_to_local() -> None:
    np.testing.assert_allclose(rotation(np.pi / 2) @ [1.0, 0.0], [0.0, 1.0], atol=EXACT_ATOL)
    pose = np.array([10.0, -5.0, np.pi / 2])
    # a point 1 m north of the radar lies on the radar's +x axis when it faces north
    np.testing.assert_allclose(to_local(pose, [[10.0, -4.0]]), [[1.0, 0.0]], atol=EXACT_ATOL)
    assert rotation(np.zeros(3)).shape == (3, 2, 2)
    # several poses at once: each pose's view of the points, as one pose at a time gives it
    poses = np.array([[10.0, -5.0, np.pi / 2], [0.0, 0.0, -0.3], [3.0, 4.0, 2.0]])
    points = np.array([[10.0, -4.0], [1.0, 2.0]])
    np.testing.assert_array_equal(to_local(poses, points), np.stack([to_local(p, points) for p in poses]))


def test_radar_is_a_rigid_transform_of_the_truth(rng: np.random.Generator) -> None:
    radar = InfrastructureRadar(default_cov=_tiny_cov())
    pose = np.array([30.0, 40.0, 2.1])
    ids = np.arange(5)
    states = rng.normal(size=(5, 4)) * 30
    batch, origin = radar.measure(3, pose, ids, states, rng)
    assert (batch.sensor == 3).all() and (batch.subject == -1).all()
    back = batch.z @ rotation(pose[2]).T + pose[:2]  # local → global
    np.testing.assert_allclose(back, states[origin, :2], atol=1e-9)
    # the topology (pairwise distances) is the same in both frames (Zhang Fig. 1)
    d_local = np.linalg.norm(batch.z[:, None] - batch.z[None], axis=-1)
    d_global = np.linalg.norm(states[origin, None, :2] - states[None, origin, :2], axis=-1)
    np.testing.assert_allclose(d_local, d_global, atol=1e-9)


def test_radar_range_and_noise(rng: np.random.Generator) -> None:
    radar = InfrastructureRadar({1: np.diag([0.1, 0.4])}, max_range=100.0)
    states = np.array([[50.0, 0, 0, 0], [150.0, 0, 0, 0]])
    _, origin = radar.measure(1, [0.0, 0.0, 0.0], [0, 1], states, rng)
    assert origin.tolist() == [0]
    draws = np.concatenate([radar.measure(1, [0.0, 0.0, 0.0], [0], states[:1], rng)[0].z
                            for _ in range(4000)])
    var = draws.var(axis=0)
    np.testing.assert_allclose(var, [0.1, 0.4], rtol=N_SIGMA * np.sqrt(2 / 4000))


def test_radar_rejects_bad_range() -> None:
    with pytest.raises(InvalidInputError, match="max_range"):
        InfrastructureRadar(default_cov=np.eye(2), max_range=0.0)


def test_radar_field_of_view(rng: np.random.Generator) -> None:
    # a radar at (5, 5) looking north (yaw π/2), ±π/4 about its boresight, 20 m
    radar = InfrastructureRadar(default_cov=_tiny_cov(), max_range=20.0, field_of_view=np.pi / 4)
    pose = np.array([5.0, 5.0, np.pi / 2])
    bearing = np.deg2rad([0.0, 40.0, -44.0, 46.0, -50.0, 180.0, 90.0, 10.0])  # from north, counter-clockwise
    distance = np.array([10.0, 10.0, 19.0, 10.0, 5.0, 3.0, 8.0, 21.0])
    xy = pose[:2] + distance[:, None] * np.stack([-np.sin(bearing), np.cos(bearing)], axis=1)
    states = np.concatenate([xy, np.zeros((8, 2))], axis=1)
    batch, origin = radar.measure(9, pose, np.arange(8), states, rng)
    assert sorted(origin.tolist()) == [0, 1, 2]  # within ±45° and 20 m only
    # the rows are the vehicles in the radar's frame: distance along the boresight (x) and left (y)
    local = distance[origin, None] * np.stack([np.cos(bearing[origin]), np.sin(bearing[origin])], axis=1)
    np.testing.assert_allclose(batch.z, local, atol=1e-9)
    # all around (the default, the papers' radar): everything within range, behind it too
    _, origin = InfrastructureRadar(default_cov=_tiny_cov(), max_range=20.0).measure(9, pose, np.arange(8),
                                                                                    states, rng)
    assert sorted(origin.tolist()) == [0, 1, 2, 3, 4, 5, 6]


@pytest.mark.parametrize("fov", [0.0, -1.0, 3.2, float("nan"), float("inf"), "wide", True])
def test_radar_rejects_bad_field_of_view(fov: object) -> None:
    with pytest.raises(InvalidInputError, match="field_of_view"):
        InfrastructureRadar(default_cov=np.eye(2), field_of_view=fov)


def test_radar_field_of_view_in_to_dict() -> None:
    # all around is left out, so the setups of the papers' radars keep their setup.json
    assert "field_of_view" not in InfrastructureRadar(default_cov=np.eye(2)).to_dict()
    narrow = InfrastructureRadar(default_cov=np.eye(2), field_of_view=1.0).to_dict()
    assert narrow["field_of_view"] == 1.0
    assert sensor_from_dict(json.loads(json.dumps(narrow))).field_of_view == 1.0


def test_odometry_is_the_displacement(rng: np.random.Generator) -> None:
    odo = Odometry(default_cov=_tiny_cov())
    now, before = rng.normal(size=(3, 4)), rng.normal(size=(3, 4))
    batch = odo.measure([5, 6, 8], now, before, rng)
    assert batch.sensor.tolist() == [5, 6, 8] and batch.subject.tolist() == [5, 6, 8]
    np.testing.assert_allclose(batch.z, now[:, :2] - before[:, :2], atol=EXACT_ATOL)
    assert len(odo.measure([], np.zeros((0, 4)), np.zeros((0, 4)), rng)) == 0


# ----------------------------------------------------------------------------
# serialisation
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("sensor", [
    GnssPosition({0: 0.01 * np.eye(2), 1: 15.0 * np.eye(2)}),
    GnssPosition(default_cov=np.diag([4.0, 4.0, 0.1, 0.1]), state_indices=(0, 1, 2, 3)),
    RelativePosition({3: np.diag([2.0, 0.5])}, default_cov=np.eye(2)),
    AnonymousPosition(default_cov=0.5 * np.eye(2), state_indices=(0, 2)),
    InfrastructureRadar({7: 0.1 * np.eye(2)}, max_range=150.0),
    InfrastructureRadar(default_cov=0.1 * np.eye(2), max_range=50.0, field_of_view=np.pi / 3),
    Odometry(default_cov=np.eye(2)),
], ids=["gnss", "gnss-pos-vel", "v2f", "anonymous", "radar", "radar-fov", "odometry"])
def test_sensor_from_dict_round_trip(sensor, rng: np.random.Generator) -> None:
    data = json.loads(json.dumps(sensor.to_dict()))  # must survive JSON (setup.json)
    again = sensor_from_dict(data)
    assert type(again) is type(sensor)
    assert again.state_indices == sensor.state_indices
    assert again.covariances.keys() == sensor.covariances.keys()
    for key, cov in sensor.covariances.items():
        np.testing.assert_array_equal(again.covariances[key], cov)
    if sensor.default_cov is None:
        assert again.default_cov is None
    else:
        np.testing.assert_array_equal(again.default_cov, sensor.default_cov)
    assert again.to_dict() == sensor.to_dict()


def test_sensor_from_dict_unknown_model() -> None:
    with pytest.raises(InvalidInputError, match="unknown"):
        sensor_from_dict({"model": "lidar"})


def test_fit_pose_inverts_to_local(rng: np.random.Generator) -> None:
    pose = np.array([*rng.uniform(-100, 100, 2), rng.uniform(-np.pi, np.pi)])
    world = rng.normal(0, 30, (5, 2))
    fitted = fit_pose(world, to_local(pose, world))
    np.testing.assert_allclose(fitted[:2], pose[:2], atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (fitted[2] - pose[2]))), 0.0, atol=1e-12)
