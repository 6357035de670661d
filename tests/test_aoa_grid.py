"""The `aoa-grid` scenario and the `AngleOfArrival` sensor against brute force and statistics.

- Links are exactly the pairs within R_c (all-pairs distances).
- AoA rows are exactly the in-view directions of the links; the wrapped residuals are
  N(0, σ²_θ) (a statistical check that passes for any seed).
- Priors are centred on the truth with the stated covariance (whitened errors).
- Vehicles sit in lanes with headings along the streets; tracking moves them straight.
- Recordings survive a save/load round trip (sensor and motion model serialise).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import norm

from cooploc.errors import ConfigError, InvalidInputError
from cooploc.geometry import wrap_angle
from cooploc.io import load_recording, save_recording
from cooploc.metrics import evaluate
from cooploc.scenarios import get_preset
from cooploc.scenarios.aoa_grid import AoaGridParams, anchor_ids, generate
from cooploc.sensors import AngleOfArrival, sensor_from_dict
from cooploc.types import Estimate, StateSet

# For N independent standard normal draws, the sample mean has standard deviation
# 1/sqrt(N) and the sample variance sqrt(2/N); 6 of those fail with probability < 1e-8.
N_SIGMA = 6.0


def _runs(seed: int, runs: int, **overrides):
    params = AoaGridParams().with_overrides(overrides)
    return params, [generate(params, np.random.default_rng([seed, 11, r])) for r in range(runs)]


def test_bearing_and_field_of_view_by_hand() -> None:
    aoa = AngleOfArrival(default_cov=np.array([[0.1]]), field_of_view=np.pi / 3)
    receiver = np.array([0.0, 0.0, 0.0])
    points = np.array([[0.0, 10.0, 0.0], [10.0, 0.0, 0.0], [-10.0, -1e-9, 0.0], [5.0, -5.0, 0.0]])
    theta = aoa.bearing(receiver, points)
    np.testing.assert_allclose(theta, [np.pi / 2, 0.0, -np.pi, -np.pi / 4], atol=1e-9)
    # Δ = π/3: left array sees [π/6, 5π/6], right array [−5π/6, −π/6]: ahead and behind are blind
    np.testing.assert_array_equal(aoa.in_view(theta), [True, False, False, True])
    # the default Δ = π/2: each array sees its half-plane, the two together every direction
    wide = AngleOfArrival(default_cov=np.array([[0.1]]))
    assert wide.field_of_view == np.pi / 2
    np.testing.assert_array_equal(wide.in_view(np.linspace(-np.pi, np.pi, 721)), True)
    # a receiver heading north (α = π/2) sees the point ahead of the first one to its right
    assert aoa.bearing(np.array([0.0, 0.0, np.pi / 2]), points[1]) == pytest.approx(-np.pi / 2)


def test_log_likelihood_is_the_wrapped_gaussian() -> None:
    aoa = AngleOfArrival(default_cov=np.array([[0.1]]))
    batch = aoa.measure(np.array([0, 1]), np.array([[0.0, 0.0, 0.0], [0.0, 10.0, np.pi]]),
                        np.array([[0, 1]]), np.random.default_rng(0))
    rx = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, np.pi]])[batch.sensor]
    tx = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, np.pi]])[batch.subject]
    residual = wrap_angle(batch.z[:, 0] - aoa.bearing(rx, tx))
    np.testing.assert_allclose(aoa.log_likelihood(batch, rx, tx),
                               norm.logpdf(residual, scale=np.sqrt(0.1)), rtol=1e-12)


def test_sensor_validation_and_round_trip() -> None:
    with pytest.raises(InvalidInputError, match="field_of_view"):
        AngleOfArrival(default_cov=np.array([[0.1]]), field_of_view=2.0)
    with pytest.raises(InvalidInputError, match="state_indices"):
        AngleOfArrival(default_cov=np.array([[0.1]]), state_indices=(0, 1))
    aoa = AngleOfArrival({4: np.array([[0.3]])}, np.array([[0.1]]), field_of_view=1.0)
    back = sensor_from_dict(aoa.to_dict())
    assert isinstance(back, AngleOfArrival) and back.field_of_view == 1.0
    np.testing.assert_array_equal(back.variance_of([4, 5])[:, 0, 0], [0.3, 0.1])


def test_links_and_rows_match_brute_force(seed: int) -> None:
    params, recs = _runs(seed, 3)
    aoa: AngleOfArrival = recs[0].setup.sensors["aoa"]
    for rec in recs:
        frame, states = rec.frames[0], rec.truth.vehicle_states[0]
        d = np.linalg.norm(states[:, None, :2] - states[None, :, :2], axis=-1)
        want = {(i, j) for i, j in zip(*np.nonzero(d <= params.communication_radius), strict=True)
                if i < j}
        got = {tuple(sorted(map(int, link))) for link in frame.links}
        assert got == want and len(frame.links) == len(want)
        rows = {(int(s), int(t)) for s, t in zip(frame.batches["aoa"].sensor,
                                                  frame.batches["aoa"].subject, strict=True)}
        seen = {(i, j) for a, b in want for i, j in ((a, b), (b, a))
                if aoa.in_view(aoa.bearing(states[i], states[j]))}
        assert rows == seen


def test_aoa_noise_and_priors_have_the_stated_statistics(seed: int) -> None:
    params, recs = _runs(seed, 6)
    white_aoa, white_prior = [], []
    for rec in recs:
        batch, states = rec.frames[0].batches["aoa"], rec.truth.vehicle_states[0]
        residual = wrap_angle(batch.z[:, 0] - rec.setup.sensors["aoa"].bearing(
            states[batch.sensor], states[batch.subject]))
        white_aoa.append(residual / np.sqrt(params.aoa_variance))
        prior = rec.setup.vehicle_prior
        err = prior.mean - states
        err[:, 2] = wrap_angle(err[:, 2])
        white_prior.append((err / np.sqrt(np.diagonal(prior.cov, axis1=1, axis2=2))).ravel())
        anchors = anchor_ids(params)
        np.testing.assert_allclose(np.sqrt(prior.cov[anchors][:, [0, 1, 2], [0, 1, 2]]),
                                   np.broadcast_to([0.1, 0.1, 0.01], (anchors.size, 3)))
        np.testing.assert_allclose(np.sqrt(prior.cov[anchors.size:][:, [0, 1, 2], [0, 1, 2]]),
                                   np.broadcast_to([5.0, 5.0, 0.35], (51 - anchors.size, 3)))
    for white in (np.concatenate(white_aoa), np.concatenate(white_prior)):
        n = white.size
        # σ_θ = 0.32 rad: wrapping changes the N(0, σ²) law by less than 1e-20
        assert abs(white.mean()) < N_SIGMA / np.sqrt(n)
        assert abs(white.var() - 1.0) < N_SIGMA * np.sqrt(2.0 / n)


def test_vehicles_drive_in_lanes_along_the_streets(seed: int) -> None:
    params, (rec,) = _runs(seed, 1, n_steps=6, grid_size=200.0, block_size=50.0)
    states = rec.truth.vehicle_states
    heading = states[0, :, 2]
    on_axis = np.isclose(np.abs(np.cos(heading)), 1.0) | np.isclose(np.abs(np.sin(heading)), 1.0)
    assert on_axis.all() and np.all((heading >= -np.pi) & (heading < np.pi))
    # distance to the street's centre line along the cross axis is (l + ½) lane widths
    cross = np.where(np.isclose(np.abs(np.cos(heading)), 1.0), states[0, :, 1], states[0, :, 0])
    centre = (np.floor(cross / params.block_size) + 0.5) * params.block_size   # mid-block lines
    offset = np.abs(cross - centre)
    lanes = offset / params.lane_width - 0.5
    np.testing.assert_allclose(lanes, np.round(lanes), atol=1e-9)
    assert lanes.max() <= params.lanes - 1
    # tracking: constant heading, straight at constant speed within [speed_min, speed_max]
    np.testing.assert_array_equal(states[:, :, 2], np.broadcast_to(heading, states.shape[:2]))
    step = np.linalg.norm(np.diff(states[:, :, :2], axis=0), axis=-1) / params.dt
    assert np.allclose(step, step[0]) and step.min() >= params.speed_min - 1e-9
    assert step.max() <= params.speed_max + 1e-9
    assert "gnss" not in rec.frames[0].batches
    assert all(len(f.batches["gnss"]) == 51 for f in rec.frames[1:])


def test_metrics_report_wrapped_heading_errors(seed: int) -> None:
    _, (rec,) = _runs(seed, 1)
    truth = rec.truth.vehicle_states[0]
    mean = truth.copy()
    mean[:, 2] = wrap_angle(truth[:, 2] + np.pi - 0.02) - np.pi + 0.02 + 0.05   # across ±π
    cov = np.repeat(np.eye(3)[None], 51, axis=0)
    errors = evaluate(rec, [Estimate(StateSet(rec.frames[0].vehicles, mean, cov))])
    np.testing.assert_allclose(errors.err_heading, 0.05, atol=1e-9)
    np.testing.assert_allclose(errors.err_pos, 0.0, atol=1e-12)


def test_recording_round_trip(tmp_path, seed: int) -> None:
    _, (rec,) = _runs(seed, 1, n_steps=3)
    save_recording(rec, tmp_path / "rec")
    back = load_recording(tmp_path / "rec")
    assert back.setup.sensors["aoa"].to_dict() == rec.setup.sensors["aoa"].to_dict()
    assert back.setup.vehicle_motion == rec.setup.vehicle_motion
    for a, b in zip(rec.frames, back.frames, strict=True):
        np.testing.assert_array_equal(a.batches["aoa"].z, b.batches["aoa"].z)
        np.testing.assert_array_equal(a.links, b.links)


def test_presets_and_validation() -> None:
    assert get_preset("aoa-grid").params.n_steps == 1
    assert get_preset("aoa-grid-tracking").params.n_steps > 1
    # the notes' default field of view, in the snapshot and its tracking variant alike
    for name in ("aoa-grid", "aoa-grid-tracking"):
        assert get_preset(name).params.field_of_view == np.pi / 2, name
    rec = get_preset("aoa-grid-tracking").generate(np.random.default_rng(0),
                                                   get_preset("aoa-grid-tracking").params.with_overrides(
                                                       {"n_steps": 2}))
    assert rec.setup.sensors["aoa"].field_of_view == np.pi / 2
    with pytest.raises(ConfigError, match="field_of_view"):
        AoaGridParams(field_of_view=3.0)
    with pytest.raises(ConfigError, match="block_size"):
        AoaGridParams(grid_size=50.0, block_size=100.0)
    with pytest.raises(ConfigError, match="communication_radius"):
        AoaGridParams().with_overrides({"communication_radius": "-1"})
    # fewer vehicles than anchors: every vehicle is an anchor
    assert anchor_ids(AoaGridParams(n_vehicles=3)).tolist() == [0, 1, 2]
