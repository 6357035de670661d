"""The sensors of every paper on SUMO traffic (issue 19): radars, odometry, AoA, anonymous GNSS.

Most checks lay the sensors (`sumo.lay_sensors`) over a `Traffic` made by hand here, so
that the geometry is known and no SUMO run is needed: radar rows against the radar's
pose, range and field of view; odometry against the true displacement; AoA against the
headings; anonymous GNSS against the identified rows; the busiest junctions. Noise is
checked by its moments over many draws (`helpers.assert_covariance_close`, 6σ: a
correct simulator fails with probability below ~1e-7 for any seed). The last checks
use the tiny SUMO grid: SUMO's angle as the truth's heading, and the numbers of the
estimators that ran on the `sumo-*` presets before, bit for bit with the new families
on and off.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.errors import ConfigError, CooplocError
from cooploc.geometry import rotation, to_local, wrap_angle
from cooploc.io import load_recording, save_recording
from cooploc.scenarios import get_preset, sumo
from cooploc.sensors import AngleOfArrival, AnonymousPosition, InfrastructureRadar, Odometry
from cooploc.types import Recording
from helpers import assert_covariance_close, make_traffic, run_estimator

#: every new family off: the sensors of the recording before issue 19
BRAMBILLA_ONLY = {"radar": False, "odometry": False, "aoa": False, "anonymous_gnss": False}
ALL_ON = {"radar": True, "odometry": True, "aoa": True}
#: the kinds of the recording before issue 19
OLD_KINDS = ("gnss", "v2f")
#: the smallest variance a parameter takes: noise of about 1e-6 m (rad), so that rows equal
#: the noise-free geometry to this tolerance (1e-6 σ, 10 σ margin)
TINY = 1e-12
GEOMETRY_ATOL = 1e-5


def params_for(run: sumo.Traffic, **overrides: object) -> sumo.SumoParams:
    """`SumoParams` whose step count is the hand-made traffic's (dt = 1 s)."""
    return sumo.SumoParams(dt=1.0, duration=float(run.t.size), **overrides)


def lay(run: sumo.Traffic, seed: object, **keys: object) -> Recording:
    """The recording of `run` with only the families in `keys` on (besides GNSS and V2F)."""
    return sumo.lay_sensors(params_for(run, **{**BRAMBILLA_ONLY, **keys}), run, np.random.default_rng(seed))


def driving(rng: np.random.Generator, n_steps: int = 12, n: int = 40, spread: float = 60.0) -> sumo.Traffic:
    """`n` vehicles driving straight with random velocities near the origin; some enter late
    and some leave early; eight static features among them."""
    start = np.concatenate([rng.uniform(-spread, spread, (n, 2)), rng.uniform(-10, 10, (n, 2))], axis=1)
    k = np.arange(n_steps)[:, None, None]
    states = np.concatenate([start[None, :, :2] + k * start[None, :, 2:],
                             np.broadcast_to(start[None, :, 2:], (n_steps, n, 2))], axis=2)
    enter = rng.integers(0, n_steps // 2, n)
    leave = rng.integers(n_steps // 2, n_steps + 1, n)
    present = (k[..., 0] >= enter) & (k[..., 0] < leave)
    features = rng.uniform(-spread, spread, (8, 2))
    return make_traffic(states, present, features=features)


def kinds_equal(a: Recording, b: Recording, kinds: tuple[str, ...]) -> None:
    """The rows, links and origins of `kinds` are the same in both recordings, bit for bit."""
    for k, (fa, fb) in enumerate(zip(a.frames, b.frames, strict=True)):
        np.testing.assert_array_equal(fa.vehicles, fb.vehicles)
        np.testing.assert_array_equal(fa.links, fb.links)
        for kind in kinds:
            ba, bb = fa.batches[kind], fb.batches[kind]
            for field in ("z", "cov", "sensor", "subject"):
                np.testing.assert_array_equal(getattr(ba, field), getattr(bb, field),
                                              err_msg=f"{k}: {kind}.{field}")
            np.testing.assert_array_equal(a.truth.origin[k][kind], b.truth.origin[k][kind])
    np.testing.assert_array_equal(a.setup.vehicle_prior.mean, b.setup.vehicle_prior.mean)


# ----------------------------------------------------------------------------
# randomness: the new families draw from new streams
# ----------------------------------------------------------------------------


def test_spawning_more_streams_keeps_the_first_four() -> None:
    # numpy's spawn(n) derives child i from (entropy, spawn_key + (i,)): asking for more
    # children leaves the first ones as they were — what keeps the old draws unchanged
    assert sumo.STREAMS[:4] == ("traffic", "prior", "gnss", "v2f")
    few = np.random.default_rng([7, 80]).spawn(4)
    many = np.random.default_rng([7, 80]).spawn(len(sumo.STREAMS))
    for a, b in zip(few, many[:4], strict=True):
        np.testing.assert_array_equal(a.random(5), b.random(5))
    assert not np.array_equal(many[3].random(5), many[4].random(5))


@pytest.mark.parametrize("on", [ALL_ON, {"radar": True}, {"odometry": True}, {"aoa": True},
                                {**ALL_ON, "anonymous_gnss": True}], ids=str)
def test_existing_rows_do_not_change_with_the_new_families(on: dict, rng: np.random.Generator,
                                                           seed: int) -> None:
    run = driving(rng)
    before, after = lay(run, [seed, 1]), lay(run, [seed, 1], **on)
    kinds = ("v2f",) if on.get("anonymous_gnss") else OLD_KINDS  # anonymous GNSS: its own check below
    kinds_equal(before, after, kinds)
    assert set(before.frames[3].batches) == set(OLD_KINDS)
    new = {k for k, v in on.items() if v and k != "anonymous_gnss"} | ({"anchor"} if on.get("aoa") else set())
    assert set(after.frames[3].batches) == set(OLD_KINDS) | new


def test_each_family_switches_off(rng: np.random.Generator, seed: int) -> None:
    run = driving(rng)
    rec = lay(run, seed)
    assert set(rec.setup.sensors) == set(OLD_KINDS)
    assert rec.setup.infrastructure_ids == () and rec.truth.sensor_poses.shape == (0, 3)
    assert all(set(f.batches) == set(OLD_KINDS) for f in rec.frames)
    on = lay(run, seed, **ALL_ON)
    assert set(on.setup.sensors) == {"gnss", "v2f", "radar", "odometry", "aoa", "anchor"}
    # the AoA anchors belong to the AoA family: a share of 0 leaves only the angles
    assert set(lay(run, seed, aoa=True, aoa_anchor_share=0.0).setup.sensors) == {*OLD_KINDS, "aoa"}
    # the defaults: radars and AoA on, odometry and anonymous GNSS off (module docstring)
    defaults = sumo.SumoParams()
    assert (defaults.radar, defaults.aoa) == (True, True)
    assert (defaults.odometry, defaults.anonymous_gnss) == (False, False)


# ----------------------------------------------------------------------------
# road-side radars
# ----------------------------------------------------------------------------


def test_radar_rows_lie_in_range_and_field_of_view_in_the_radar_frame(rng: np.random.Generator,
                                                                       seed: int) -> None:
    # 300 parked vehicles in a 90 m disc around a radar at (100, 50) that sees 50 m, ±1 rad
    n, centre = 300, np.array([100.0, 50.0])
    radius, angle = 90.0 * np.sqrt(rng.random(n)), rng.uniform(-np.pi, np.pi, n)
    xy = centre + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    states = np.concatenate([xy, np.zeros((n, 2))], axis=1)[None].repeat(3, axis=0)
    run = make_traffic(states, np.ones((3, n), dtype=bool), np.zeros((3, n)))
    rec = lay(run, seed, radar=True, radar_positions=tuple(centre), radar_range=50.0, radar_field_of_view=1.0,
              radar_variance=TINY)
    assert rec.setup.infrastructure_ids == (sumo.RADAR_ID_OFFSET,)
    model = rec.setup.sensors["radar"]
    assert isinstance(model, InfrastructureRadar)
    assert (model.max_range, model.field_of_view) == (50.0, 1.0)
    (pose,) = rec.truth.sensor_poses
    np.testing.assert_array_equal(pose[:2], centre)            # the named site; the yaw is drawn
    local = to_local(pose, xy)
    seen = (np.hypot(*local.T) <= 50.0) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) <= 1.0)
    expected = run.vehicle_ids[seen]
    assert 20 < expected.size < n  # the geometry cuts both ways
    for k, frame in enumerate(rec.frames):
        radar, origin = frame.batches["radar"], rec.truth.origin[k]["radar"]
        assert (radar.sensor == sumo.RADAR_ID_OFFSET).all() and (radar.subject == -1).all()
        np.testing.assert_array_equal(np.sort(origin), expected)
        # back to the world with R(θ) z + t: the rows are the vehicles' positions
        world = radar.z @ rotation(pose[2]).T + pose[:2]
        np.testing.assert_allclose(world, xy[np.searchsorted(run.vehicle_ids, origin)], atol=GEOMETRY_ATOL)
    assert not np.array_equal(rec.truth.origin[0]["radar"], rec.truth.origin[1]["radar"]), "rows are shuffled"


def test_radar_noise_has_the_papers_covariance(rng: np.random.Generator, seed: int) -> None:
    run = driving(rng, n_steps=30, n=120, spread=30.0)
    rec = lay(run, seed, radar=True, radar_positions=(0.0, 0.0), radar_range=1e4)
    assert sumo.SumoParams().radar_variance == 0.1  # Zhang §4.1 and Gulati §IV-A
    (pose,) = rec.truth.sensor_poses
    truth = rec.truth
    true_xy = [truth.vehicles_at(k, truth.origin[k]["radar"])[:, :2] for k in range(len(rec.frames))]
    residuals = np.concatenate([f.batches["radar"].z - to_local(pose, xy)
                                for f, xy in zip(rec.frames, true_xy, strict=True)])
    assert residuals.shape[0] == rec.truth.vehicle_present.sum()  # all around, every vehicle
    assert_covariance_close(residuals, 0.1 * np.eye(2))


def test_busiest_junctions_are_chosen_from_the_traffic() -> None:
    # junctions: b busiest, a next but within range of b, c then, d (two roads) only if named
    ids = ["a", "b", "c", "d"]
    xy = np.array([[0.0, 0.0], [30.0, 0.0], [300.0, 0.0], [600.0, 0.0]])
    roads = np.array([4, 3, 3, 2])
    # vehicle-steps within 50 m: a 30, b 30 + 20, c 10, d 90
    spots = np.array([[30.0, 5.0], [70.0, 0.0], [300.0, 10.0], [600.0, 0.0]])
    vehicles = np.repeat(spots, [30, 20, 10, 90], axis=0)
    params = sumo.SumoParams(radar_range=50.0, n_radars=3)
    sites = sumo.radar_sites(params, np.array(ids), xy, roads, vehicles)
    np.testing.assert_array_equal(sites, xy[[1, 2]])  # a skipped: closer than 50 m to b
    # a tie (b and c, 5 each) goes to the smaller id first
    tie = np.repeat(np.array([[300.0, 0.0], [30.0, 45.0]]), 5, axis=0)
    np.testing.assert_array_equal(sumo.radar_sites(params, np.array(ids), xy, roads, tie), xy[[1, 2]])
    np.testing.assert_array_equal(sumo.radar_sites(params, np.array(ids), xy, roads, tie[::-1]), xy[[1, 2]])
    # a network without junctions of three roads: every junction is a candidate
    np.testing.assert_array_equal(
        sumo.radar_sites(dataclasses.replace(params, n_radars=1), np.array(ids), xy, np.full(4, 2), vehicles),
        xy[[3]])
    # named junctions, in the order given; unknown ones are refused naming the key
    named = dataclasses.replace(params, radar_junctions=("d", "a"))
    np.testing.assert_array_equal(sumo.radar_sites(named, np.array(ids), xy, roads, vehicles), xy[[3, 0]])
    with pytest.raises(ConfigError, match=r"radar_junctions must name junctions .* got 'e'"):
        sumo.radar_sites(dataclasses.replace(params, radar_junctions=("a", "e")), np.array(ids), xy, roads,
                         vehicles)


# ----------------------------------------------------------------------------
# odometry (Gulati eq. 4)
# ----------------------------------------------------------------------------


def test_odometry_is_the_true_displacement_plus_noise(rng: np.random.Generator, seed: int) -> None:
    run = driving(rng, n_steps=40, n=80)
    rec = lay(run, seed, odometry=True)
    model = rec.setup.sensors["odometry"]
    assert isinstance(model, Odometry)
    np.testing.assert_array_equal(model.default_cov, np.eye(2))  # Gulati §IV-A: 1 m²
    assert len(rec.frames[0].batches["odometry"]) == 0            # nobody has a previous step
    truth, residuals = rec.truth, []
    for k, frame in enumerate(rec.frames[1:], start=1):
        odo = frame.batches["odometry"]
        both = truth.vehicle_ids[truth.vehicle_present[k] & truth.vehicle_present[k - 1]]
        np.testing.assert_array_equal(odo.subject, both)  # a vehicle's first step has none
        np.testing.assert_array_equal(odo.sensor, both)
        np.testing.assert_array_equal(truth.origin[k]["odometry"], both)
        delta = truth.vehicles_at(k, both)[:, :2] - truth.vehicles_at(k - 1, both)[:, :2]
        residuals.append(odo.z - delta)
    residuals = np.concatenate(residuals)
    assert residuals.shape[0] > 1000
    assert_covariance_close(residuals, np.eye(2))


# ----------------------------------------------------------------------------
# angle of arrival (papers/plbp_model_notes.md)
# ----------------------------------------------------------------------------


def test_aoa_geometry_against_headings(seed: int) -> None:
    # vehicle A at the origin heading north; B 10 m east heading east; C 45 m north (beyond
    # the 30 m AoA range of everybody, within R_c); D 10 m north of A heading east
    xy = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 45.0], [0.0, 10.0]])
    heading = np.array([np.pi / 2, 0.0, 0.0, 0.0])
    states = np.concatenate([xy, np.zeros((4, 2))], axis=1)[None]
    run = make_traffic(states, np.ones((1, 4), dtype=bool), heading[None])
    a, b, _, d = run.vehicle_ids
    rec = lay(run, seed, aoa=True, aoa_variance=TINY)
    model = rec.setup.sensors["aoa"]
    assert isinstance(model, AngleOfArrival) and model.state_indices == (0, 1, 4)
    assert model.field_of_view == np.pi / 2
    np.testing.assert_array_equal(model.default_cov, [[TINY]])
    aoa = rec.frames[0].batches["aoa"]
    got = {(int(s), int(t)): float(z) for s, t, z in zip(aoa.sensor, aoa.subject, aoa.z[:, 0], strict=True)}
    expected = {
        (a, b): -np.pi / 2,          # east of a northbound receiver: its right array's normal
        (b, a): -np.pi,              # behind an eastbound receiver (Δ = π/2: still seen)
        (a, d): 0.0,                 # straight ahead
        (d, a): -np.pi / 2,
        (b, d): wrap_angle(np.arctan2(10.0, -10.0)),
        (d, b): wrap_angle(np.arctan2(-10.0, 10.0)),
    }
    assert set(got) == set(expected)  # c is linked (R_c = 250 m) but beyond the AoA range
    assert len(rec.frames[0].links) == 6
    for pair, angle in expected.items():
        assert abs(wrap_angle(got[pair] - angle)) < GEOMETRY_ATOL, (pair, got[pair], angle)
    np.testing.assert_array_equal(rec.truth.origin[0]["aoa"], aoa.subject)
    np.testing.assert_array_equal(rec.truth.vehicle_heading[0], heading)
    # narrower arrays (Δ = π/4) are blind ahead and behind: only side-on pairs remain
    side = lay(run, seed, aoa=True, aoa_variance=TINY, aoa_field_of_view=np.pi / 4).frames[0].batches["aoa"]
    pairs = set(zip(side.sensor.tolist(), side.subject.tolist(), strict=True))
    assert pairs == {(a, b), (d, a), (b, d), (d, b)}


def test_aoa_noise_has_the_papers_variance(rng: np.random.Generator, seed: int) -> None:
    run = driving(rng, n_steps=6, n=150, spread=40.0)
    rec = lay(run, seed, aoa=True)
    model, truth = rec.setup.sensors["aoa"], rec.truth
    assert model.default_cov[0, 0] == 0.10  # Table I: σ²_θ = 0.10 rad²
    residuals = []
    for k, frame in enumerate(rec.frames):
        aoa, ids = frame.batches["aoa"], frame.vehicles
        heading = truth.vehicle_heading[k, truth.vehicle_present[k]]  # ids are sorted as the truth's
        full = np.concatenate([truth.vehicles_at(k, ids), heading[:, None]], axis=1)
        cols = np.searchsorted(ids, np.stack([aoa.sensor, aoa.subject], axis=1))
        distance = np.hypot(*(full[cols[:, 0], :2] - full[cols[:, 1], :2]).T)
        assert (distance <= 30.0).all()
        residuals.append(wrap_angle(aoa.z[:, 0] - model.bearing(full[cols[:, 0]], full[cols[:, 1]])))
    residuals = np.concatenate(residuals)[:, None]
    assert residuals.shape[0] > 1000
    assert_covariance_close(residuals, np.array([[0.10]]))


# ----------------------------------------------------------------------------
# anonymous GNSS (Zhang 2016 §3.2)
# ----------------------------------------------------------------------------


def test_anonymous_gnss_keeps_the_rows_without_their_vehicle(rng: np.random.Generator, seed: int) -> None:
    run = driving(rng)
    named, anon = lay(run, [seed, 3]), lay(run, [seed, 3], anonymous_gnss=True)
    model = anon.setup.sensors["gnss"]
    assert isinstance(model, AnonymousPosition) and model.state_indices == (0, 1, 2, 3)
    np.testing.assert_array_equal(model.default_cov, named.setup.sensors["gnss"].default_cov)
    shuffled = 0
    for k, (fa, fb) in enumerate(zip(named.frames, anon.frames, strict=True)):
        a, b = fa.batches["gnss"], fb.batches["gnss"]
        assert (b.sensor == -1).all() and (b.subject == -1).all()
        origin = anon.truth.origin[k]["gnss"]
        # the same rows: each anonymous row is its vehicle's identified row (z and covariance)
        rows = np.searchsorted(a.subject, origin)
        np.testing.assert_array_equal(np.sort(origin), a.subject)
        np.testing.assert_array_equal(b.z, a.z[rows])
        np.testing.assert_array_equal(b.cov, a.cov[rows])
        shuffled += not np.array_equal(origin, a.subject)
    assert shuffled > len(anon.frames) // 2, "rows come in random order"
    kinds_equal(named, anon, ("v2f",))


# ----------------------------------------------------------------------------
# parameters, saving, the cache
# ----------------------------------------------------------------------------


@pytest.mark.parametrize(("key", "value"), [
    ("radar_positions", "10,20,30"), ("radar_field_of_view", "4"), ("radar_field_of_view", "0"),
    ("aoa_field_of_view", "2"), ("n_radars", "0"), ("radar_range", "-5"), ("radar_variance", "0"),
    ("odometry_variance", "nan"), ("aoa_variance", "-0.1"), ("aoa_range", "0"), ("odometry", "maybe"),
    ("radar", "2"), ("anonymous_gnss", "sometimes"), ("radar_junctions", "A0,A0"),
])
def test_bad_values_name_the_key(key: str, value: str) -> None:
    with pytest.raises(CooplocError, match=key):
        get_preset("sumo-grid-tlr").params.with_overrides({key: value})


def test_radar_sites_named_twice_name_the_key() -> None:
    with pytest.raises(CooplocError, match="radar_positions"):
        sumo.SumoParams().with_overrides({"radar_junctions": "A0", "radar_positions": "1,2"})


def test_unknown_junction_is_refused_at_generation(rng: np.random.Generator) -> None:
    run = driving(rng)
    with pytest.raises(CooplocError, match=r"radar_junctions .*'nowhere'"):
        sumo.lay_sensors(params_for(run, radar_junctions=("j0", "nowhere")), run, rng)


def test_saved_recording_keeps_heading_radars_and_field_of_view(tmp_path, rng: np.random.Generator,
                                                                 seed: int) -> None:
    run = driving(rng)
    rec = sumo.lay_sensors(params_for(run, **ALL_ON, radar_field_of_view=1.2, radar_positions=(0, 0, 50, 0)),
                           run, np.random.default_rng(seed))
    again = load_recording(save_recording(rec, tmp_path / "rec"))   # validated on loading
    np.testing.assert_array_equal(again.truth.vehicle_heading, rec.truth.vehicle_heading)
    np.testing.assert_array_equal(again.truth.sensor_poses, rec.truth.sensor_poses)
    assert again.setup.infrastructure_ids == rec.setup.infrastructure_ids
    assert again.setup.sensors["radar"].field_of_view == 1.2
    assert again.setup.sensors["aoa"].state_indices == (0, 1, 4)
    kinds_equal(rec, again, ("gnss", "v2f", "radar", "odometry", "aoa"))


def test_old_cache_files_are_simulated_again(tmp_path, monkeypatch: pytest.MonkeyPatch,
                                             rng: np.random.Generator) -> None:
    # a cache file of format 3 lacks the heading and the junctions: never read as traffic
    pytest.importorskip("sumolib", reason="the cache key reads the SUMO version")
    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path))
    assert sumo.CACHE_FORMAT >= 4
    fresh = driving(rng)
    params = params_for(fresh)
    path = sumo.cache_path(params, 1)
    path.parent.mkdir(parents=True)
    new_fields = {"vehicle_heading", "junction_ids", "junctions", "junction_roads"}
    np.savez_compressed(path, **{f.name: getattr(fresh, f.name) for f in dataclasses.fields(fresh)
                                 if f.name not in new_fields})
    with pytest.raises(KeyError):
        sumo.Traffic.load(path)
    monkeypatch.setattr(sumo.cache, "simulate_traffic", lambda *_: fresh)
    np.testing.assert_array_equal(sumo.traffic(params, 1).vehicle_heading, fresh.vehicle_heading)
    np.testing.assert_array_equal(sumo.Traffic.load(path).junction_ids, fresh.junction_ids)  # rewritten


# ----------------------------------------------------------------------------
# on SUMO traffic: the heading, and the estimators of before
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny() -> sumo.SumoParams:
    """The tiny grid for 12 s, one traffic for every check here (one SUMO run)."""
    pytest.importorskip("sumolib", reason="the sumo extra is not installed")
    return get_preset("sumo-grid-tlr").params.with_overrides({**sumo.TINY_GRID, "duration": 12.0,
                                                              "traffic_seed": 7})


def test_heading_is_sumos_angle_along_the_velocity(sumo_cache, tiny: sumo.SumoParams, seed: int) -> None:
    rec = sumo.generate(dataclasses.replace(tiny, odometry=True), np.random.default_rng([seed, 81]))
    truth = rec.truth
    speed = np.hypot(truth.vehicle_states[..., 2], truth.vehicle_states[..., 3])
    moving = truth.vehicle_present & (speed > 0.5)
    assert moving.sum() > 30 and (truth.vehicle_present & (speed < 0.1)).any(), "some vehicles stand"
    # v = speed (cos α, sin α): SUMO's angle, clockwise from north, turned into cooploc's
    along = np.arctan2(truth.vehicle_states[..., 3], truth.vehicle_states[..., 2])
    np.testing.assert_allclose(wrap_angle(along - truth.vehicle_heading)[moving], 0.0, atol=1e-9)
    assert not truth.vehicle_heading[~truth.vehicle_present].any()
    # the radars stand at junctions of the grid, one per junction at most
    run = sumo.traffic(tiny, tiny.traffic_seed)
    poses = truth.sensor_poses
    assert 0 < poses.shape[0] <= tiny.n_radars
    assert all((np.abs(run.junctions - p[:2]).sum(axis=1) == 0).any() for p in poses)
    assert all(len(f.batches["odometry"]) for f in rec.frames[1:])


@pytest.mark.parametrize("name", ["gnss-kf", "icp", "icp-da-lc"])
def test_estimators_of_before_give_the_same_numbers(name: str, sumo_cache, tiny: sumo.SumoParams,
                                                    seed: int) -> None:
    # the default families (radars, AoA) are read by none of them: bit for bit as before
    rng = [seed, 82]
    with_new = sumo.generate(tiny, np.random.default_rng(rng))
    without = sumo.generate(dataclasses.replace(tiny, **BRAMBILLA_ONLY), np.random.default_rng(rng))
    assert {"radar", "aoa"} <= set(with_new.setup.sensors)
    a, b = run_estimator(name, with_new), run_estimator(name, without)
    for ea, eb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ea.vehicles.ids, eb.vehicles.ids)
        np.testing.assert_array_equal(ea.vehicles.mean, eb.vehicles.mean)
        np.testing.assert_array_equal(ea.vehicles.cov, eb.vehicles.cov)


def test_lay_sensors_is_generate_on_given_traffic(sumo_cache, tiny: sumo.SumoParams, seed: int) -> None:
    made = sumo.generate(tiny, np.random.default_rng([seed, 83]))
    laid = sumo.lay_sensors(tiny, sumo.traffic(tiny, tiny.traffic_seed), np.random.default_rng([seed, 83]))
    kinds_equal(made, laid, ("gnss", "v2f", "radar", "aoa"))
    np.testing.assert_array_equal(made.truth.sensor_poses, laid.truth.sensor_poses)
