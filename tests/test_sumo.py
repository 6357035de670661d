"""The `sumo-*` scenario family: SUMO traffic → Recording (cooploc.scenarios.sumo).

Everything runs on the tiny generated grid (`TINY_GRID`, about 1 s of SUMO per
simulation) with the cache in a temporary folder. Checks are exact (geometry, ids,
presence, covariances by zone) except where SUMO's integration scheme is involved
(velocity vs position differences), where the tolerance is stated.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from cooploc.errors import ConfigError, CooplocError
from cooploc.scenarios import get_preset, presets, sumo
from cooploc.types import Recording
from helpers import run_estimator


@pytest.fixture(scope="module")
def tiny() -> sumo.SumoParams:
    return get_preset("sumo-grid-tlr").params.with_overrides(sumo.TINY_GRID)


@pytest.fixture(scope="module")
def recording(sumo_cache, tiny: sumo.SumoParams, seed: int) -> Recording:
    return sumo.generate(tiny, np.random.default_rng([seed, 80]))


# ----------------------------------------------------------------------------
# registry, parameters, missing extra
# ----------------------------------------------------------------------------


def test_presets_on_two_real_networks_in_both_regulations() -> None:
    names = set(presets())
    for net in ("braunschweig", "berlin", "grid"):
        for regulation in ("tlr", "vsr"):
            preset = get_preset(f"sumo-{net}-{regulation}")
            assert preset.params.network == net and preset.params.regulation == regulation
    assert {"sumo-braunschweig-tlr", "sumo-berlin-vsr"} <= names
    # the paper's §VI settings
    params = get_preset("sumo-berlin-tlr").params
    assert params.dt == 0.75 and params.sensing_range == 50.0
    assert params.gnss_position_std == (3.0, 8.0, 15.0)
    assert params.gnss_velocity_std == (0.1, 0.17, 0.45)


def test_real_networks_are_found_in_the_installed_package() -> None:
    for name in sumo.NETWORKS:
        path = sumo.network_path(name)
        assert path.is_file() and path.parent.parent.name == "game"


@pytest.mark.parametrize(("key", "value"), [("network", "atlantis"), ("regulation", "none"),
                                            ("zone_radii", (300.0, 100.0)), ("dt", 0.0),
                                            ("gnss_position_std", (3.0, 8.0))])
def test_bad_parameters_name_the_field(key: str, value: object) -> None:
    with pytest.raises(ConfigError, match=key):
        sumo.SumoParams(**{key: value})


def test_missing_extra_is_a_clear_error(monkeypatch: pytest.MonkeyPatch, tiny: sumo.SumoParams) -> None:
    monkeypatch.setitem(sys.modules, "sumolib", None)  # `import sumolib` raises ImportError
    assert "sumo-grid-tlr" in presets()  # listing presets never needs SUMO
    with pytest.raises(sumo.SumoNotInstalledError, match=r"cooploc\[sumo\]") as info:
        sumo.generate(tiny, np.random.default_rng(0))
    assert isinstance(info.value, CooplocError)


# ----------------------------------------------------------------------------
# the recording
# ----------------------------------------------------------------------------


def test_vehicles_enter_and_leave_with_stable_ids(recording: Recording) -> None:
    truth = recording.truth
    present = truth.vehicle_present
    assert (~present[0] & present.any(axis=0)).any(), "some vehicle enters"
    assert (present[0] & ~present[-1]).any(), "some vehicle leaves"
    for k, frame in enumerate(recording.frames):
        np.testing.assert_array_equal(np.sort(frame.vehicles), truth.vehicle_ids[present[k]])
    # ids are the trip numbers of randomTrips (v0, v1, ...): departure order
    assert (truth.vehicle_ids >= 0).all() and (truth.vehicle_ids < sumo.STATIC_FEATURE_ID_OFFSET).all()
    assert not np.isin(truth.vehicle_ids, truth.feature_ids).any()
    # absent rows are zero, present ones inside the network
    assert not truth.vehicle_states[~present].any()
    # the prior lists exactly the vehicles present at step 0; later ones are born
    np.testing.assert_array_equal(np.sort(recording.setup.vehicle_prior.ids),
                                  truth.vehicle_ids[present[0]])
    assert recording.setup.birth_cov is not None


def test_velocity_is_sumos_and_matches_the_motion(recording: Recording, tiny: sumo.SumoParams) -> None:
    # SUMO integrates x_{k+1} = x_k + v_{k+1} dt (Euler, its default): the position
    # difference over a step equals the next step's velocity on straight road; turns
    # and junction internal lanes bend it, so the median is checked (tolerance 0.3 m/s)
    truth, dt = recording.truth, tiny.dt
    both = truth.vehicle_present[1:] & truth.vehicle_present[:-1]
    diff = (truth.vehicle_states[1:, :, :2] - truth.vehicle_states[:-1, :, :2]) / dt
    error = np.linalg.norm(diff - truth.vehicle_states[1:, :, 2:], axis=2)[both]
    assert np.median(error) < 0.3
    speed = np.linalg.norm(truth.vehicle_states[..., 2:], axis=2)[truth.vehicle_present]
    assert speed.max() < 20.0  # urban speed limit 13.9 m/s with SUMO's speed factor


def test_pedestrians_walk_across_junctions_without_jumps(recording: Recording, tiny: sumo.SumoParams) -> None:
    # without walking areas SUMO moves a pedestrian over a junction in one step (jumps of
    # 5-17 m on the quick grid); no CV model allows that, and oracle-kf then drags the vehicles
    # that see the pedestrian. A walk moves at most ~2 m/s (bends on walking areas)
    truth = recording.truth
    walking = truth.feature_ids >= sumo.PEDESTRIAN_ID_OFFSET
    both = (truth.feature_present[1:] & truth.feature_present[:-1])[:, walking]
    step = np.linalg.norm(np.diff(truth.feature_states[:, walking, :2], axis=0), axis=2)[both]
    assert step.size > 100
    assert step.max() < 3.0 * tiny.dt


def test_gnss_covariance_follows_the_zone_each_step(recording: Recording, sumo_cache,
                                                    tiny: sumo.SumoParams, seed: int) -> None:
    zone_cov = np.stack([np.diag([p**2, p**2, v**2, v**2]) for p, v in
                         zip(tiny.gnss_position_std, tiny.gnss_velocity_std, strict=True)])
    run = sumo.traffic(tiny, _traffic_seed(seed))
    seen = set()
    for k, frame in enumerate(recording.frames):
        gnss = frame.batches["gnss"]
        np.testing.assert_array_equal(gnss.subject, np.sort(frame.vehicles))  # one fix each
        np.testing.assert_array_equal(gnss.sensor, gnss.subject)
        states = recording.truth.vehicles_at(k, gnss.subject)
        zone = sumo.zone_of(states, run.centre, tiny.zone_radii)
        np.testing.assert_array_equal(gnss.cov, zone_cov[zone])
        seen |= set(zone.tolist())
    assert seen == {0, 1, 2}, "the tiny run spans the three zones"


def test_v2f_rows_within_sensing_range_and_links_within_communication_range(
        recording: Recording, tiny: sumo.SumoParams) -> None:
    truth = recording.truth
    for k, frame in enumerate(recording.frames):
        v2f, origin = frame.batches["v2f"], truth.origin[k]["v2f"]
        assert (v2f.subject == -1).all()  # the association is unknown to estimators
        vehicles = truth.vehicles_at(k, v2f.sensor)
        features = truth.features_at(k, origin)
        distance = np.linalg.norm(features[:, :2] - vehicles[:, :2], axis=1)
        assert (distance <= tiny.sensing_range).all()
        # P_D = 1: every feature within range is detected by every vehicle
        on = truth.feature_present[k]
        pos_v = truth.vehicles_at(k, frame.vehicles)[:, :2]
        pos_f = truth.feature_states[k, on, :2]
        expected = (np.linalg.norm(pos_v[:, None] - pos_f[None], axis=2) <= tiny.sensing_range).sum()
        assert len(v2f) == expected
        # links: exactly the pairs within R_c
        d = np.linalg.norm(pos_v[:, None] - pos_v[None], axis=2)
        assert len(frame.links) == np.triu(d <= tiny.communication_range, 1).sum()
    pedestrians = truth.feature_ids >= sumo.PEDESTRIAN_ID_OFFSET
    assert pedestrians.any() and (~truth.feature_present[:, pedestrians]).any(), "pedestrians come and go"
    static = ~pedestrians
    assert truth.feature_present[:, static].all()
    assert not np.diff(truth.feature_states[:, static], axis=0).any()  # static features stay


def test_static_features_are_spread_and_capped(sumo_cache, tiny: sumo.SumoParams, seed: int) -> None:
    run = sumo.traffic(tiny, _traffic_seed(seed))
    points = run.static_features
    assert 0 < points.shape[0] <= tiny.max_static_features
    d = np.linalg.norm(points[:, None] - points[None], axis=2)
    assert d[np.triu_indices(points.shape[0], 1)].min() >= tiny.min_feature_spacing
    assert (run.static_kind == 0).any(), "signal poles come first"
    assert run.signals.shape[0] > 0  # TLR grid: signalised junctions


def test_tlr_and_vsr_share_network_features_and_demand(sumo_cache, tiny: sumo.SumoParams) -> None:
    tlr = sumo.traffic(tiny, 3)
    vsr = sumo.traffic(dataclasses.replace(tiny, regulation="vsr"), 3)
    assert tlr.signals.shape[0] > 0 and vsr.signals.shape[0] == 0
    np.testing.assert_array_equal(tlr.static_features, vsr.static_features)
    np.testing.assert_array_equal(tlr.centre, vsr.centre)
    # the same trips (ids = trip numbers) drive both variants
    assert np.intersect1d(tlr.vehicle_ids, vsr.vehicle_ids).size >= 0.5 * tlr.vehicle_ids.size


def test_estimators_follow_the_traffic(recording: Recording) -> None:
    # gnss-kf is a consistent per-vehicle filter: its velocity estimate should beat
    # the raw zone-C fix (σ_v = 0.45 m/s) on average, its positions stay within the
    # zone-C standard deviation (15 m) in RMSE
    estimates = run_estimator("gnss-kf", recording)
    errors = []
    for k, estimate in enumerate(estimates):
        true = recording.truth.vehicles_at(k, estimate.vehicles.ids)
        errors.append(estimate.vehicles.mean - true)
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(np.sum(errors[:, :2] ** 2, axis=1))) < 15.0
    assert np.isfinite(errors).all()


# ----------------------------------------------------------------------------
# reproducibility and cache
# ----------------------------------------------------------------------------


def _traffic_seed(seed: int) -> int:
    """The traffic seed `generate` draws from `default_rng([seed, 80])`."""
    rng_traffic = np.random.default_rng([seed, 80]).spawn(4)[0]
    return int(rng_traffic.integers(2**31 - 1))


def _assert_same(a: Recording, b: Recording) -> None:
    np.testing.assert_array_equal(a.truth.vehicle_ids, b.truth.vehicle_ids)
    np.testing.assert_array_equal(a.truth.vehicle_states, b.truth.vehicle_states)
    np.testing.assert_array_equal(a.truth.feature_states, b.truth.feature_states)
    for fa, fb in zip(a.frames, b.frames, strict=True):
        for kind in fa.batches:
            np.testing.assert_array_equal(fa.batches[kind].z, fb.batches[kind].z)
        np.testing.assert_array_equal(fa.links, fb.links)


def test_cache_is_deterministic_and_reused(recording: Recording, sumo_cache, tiny: sumo.SumoParams,
                                           seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    files = sorted(sumo_cache.glob("*.npz"))
    assert files, "the traffic was cached"
    key = sumo.cache_key(tiny, _traffic_seed(seed))
    assert any(key in f.name for f in files)
    # SUMO itself is deterministic: simulating again gives the cached arrays bit for bit
    fresh = sumo.simulate_traffic(tiny, _traffic_seed(seed))
    cached = sumo.Traffic.load(next(f for f in files if key in f.name))
    for field in dataclasses.fields(sumo.Traffic):
        np.testing.assert_array_equal(getattr(fresh, field.name), getattr(cached, field.name))

    # the same run again, and a run that changes only sensor parameters, never simulate
    def refuse(*_: object) -> None:
        raise AssertionError("simulated although the traffic is cached")

    monkeypatch.setattr(sumo.cache, "simulate_traffic", refuse)  # where `traffic` looks it up
    _assert_same(recording, sumo.generate(tiny, np.random.default_rng([seed, 80])))
    other = dataclasses.replace(tiny, sensing_range=30.0, gnss_position_std=(1.0, 2.0, 3.0))
    assert sumo.cache_key(other, 1) == sumo.cache_key(tiny, 1)
    sumo.generate(other, np.random.default_rng([seed, 80]))
    # the key changes with anything that changes the traffic
    assert sumo.cache_key(dataclasses.replace(tiny, vehicle_period=5.0), 1) != sumo.cache_key(tiny, 1)
    assert sumo.cache_key(tiny, 2) != sumo.cache_key(tiny, 1)


def test_fixed_traffic_seed_shares_traffic_across_runs(sumo_cache, tiny: sumo.SumoParams) -> None:
    fixed = dataclasses.replace(tiny, traffic_seed=3)
    a = sumo.generate(fixed, np.random.default_rng(1))
    b = sumo.generate(fixed, np.random.default_rng(2))
    np.testing.assert_array_equal(a.truth.vehicle_states, b.truth.vehicle_states)
    assert not np.array_equal(a.frames[0].batches["gnss"].z, b.frames[0].batches["gnss"].z)


def test_cache_dir_follows_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path))
    assert sumo.cache_dir() == tmp_path / "sumo"
    monkeypatch.delenv("COOPLOC_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert sumo.cache_dir() == tmp_path / "xdg" / "cooploc" / "sumo"


def test_traci_fallback_gives_the_same_traffic(sumo_cache, tiny: sumo.SumoParams,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    in_process = sumo.simulate_traffic(tiny, 4)
    monkeypatch.setitem(sys.modules, "libsumo", None)  # no libsumo: SUMO runs as a subprocess
    assert sumo.simulation._simulator().__name__ == "traci"
    subprocess_run = sumo.simulate_traffic(tiny, 4)
    np.testing.assert_array_equal(in_process.vehicle_states, subprocess_run.vehicle_states)
    np.testing.assert_array_equal(in_process.pedestrian_states, subprocess_run.pedestrian_states)
