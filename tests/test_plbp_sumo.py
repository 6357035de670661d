"""`plbp` / `prior-lbp` on the `sumo-*` code path: heading from the velocity, anchors, traffic.

Oracles and properties:
- `with_velocity_heading` against the analytic linearization of atan2 (a belief whose
  velocity spread is small against its speed: SLR → Jacobian), on both sides of ±π; a
  standing vehicle gets a spread heading, finite and positive definite.
- The anchors' fixes are the true [p_x, p_y, α] plus noise of the anchor covariance
  (moments over many draws), and a share of the vehicles.
- `tracking="own-fixes"` carries the GNSS filter's beliefs (equal to `gnss-kf`'s) and
  reports the AoA solve on them.
- A hand-made traffic (no SUMO needed, `sumo.lay_sensors`): vehicles enter and leave, one
  stands still, one is far from all others (no AoA link) and one pair sees no anchor.
  Every estimate is finite; the far vehicle's estimate equals `gnss-kf`'s (same motion
  model and fixes, nothing else reaches it); the estimates keep the layout's four
  components, headings are reported and scored against the truth.
- With AoA links to an anchor, the position error falls below `gnss-kf`'s (pooled over
  draws of the hand-made scene, a paired comparison on the same rows).
- A receiver that may stand (`heading.standing`, the χ²₂ test of v = 0 against scipy's
  quantile) has an unknown heading: its own bearings carry nothing (the estimates do not
  change when they are replaced by other angles), while the bearings others take of it
  still place it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.estimators import make_estimator
from cooploc.estimators.plbp import PLBPParams
from cooploc.estimators.plbp.heading import STANDING_CHI2, standing, with_velocity_heading
from cooploc.gaussian import Gaussians
from cooploc.geometry import wrap_angle
from cooploc.metrics import evaluate
from cooploc.scenarios import sumo
from cooploc.sensors import AngleOfArrival
from cooploc.types import Batch, Recording
from helpers import assert_covariance_close, make_traffic, run_estimator

# SLR vs Jacobian: with σ_v / |v| = 1e-4 the unscented regression differs from the
# Jacobian by O((σ_v/|v|)²) relative; 1e-6 leaves a wide margin above round-off.
JACOBIAN_RTOL = 1e-6
# plbp vs gnss-kf on a vehicle no AoA reaches: the same Kalman update in information
# form against Joseph form, over 12 steps; round-off of a few 4×4 solves.
SAME_FILTER_RTOL = 1e-7


def _belief(v: tuple[float, float], std: float) -> Gaussians:
    mean = np.array([[5.0, -3.0, *v]])
    cov = np.diag([4.0, 4.0, std**2, std**2])[None]
    cov[0, 0, 2] = cov[0, 2, 0] = 0.5 * 2.0 * std           # position and velocity correlated
    return Gaussians(mean, cov)


@pytest.mark.parametrize("v", [(8.0, 3.0), (-10.0, 1e-3), (-10.0, -1e-3), (0.5, -7.0)])
def test_heading_from_velocity_is_the_linearized_direction(v: tuple[float, float]) -> None:
    belief = _belief(v, std=1e-4 * np.hypot(*v))
    slip = 0.01**2
    joint = with_velocity_heading(belief, (2, 3), slip)
    vx, vy = v
    J = np.array([0.0, 0.0, -vy, vx]) / (vx**2 + vy**2)      # ∂ atan2(v_y, v_x) / ∂x
    P = belief.cov[0]
    np.testing.assert_array_equal(joint.mean[0, :4], belief.mean[0])
    np.testing.assert_array_equal(joint.cov[0, :4, :4], P)
    # the heading lies on the branch of the mean velocity, also next to ±π
    np.testing.assert_allclose(joint.mean[0, 4], np.arctan2(vy, vx), rtol=JACOBIAN_RTOL)
    np.testing.assert_allclose(joint.cov[0, :4, 4], P @ J, rtol=JACOBIAN_RTOL, atol=1e-18)
    np.testing.assert_allclose(joint.cov[0, 4, 4], J @ P @ J + slip, rtol=JACOBIAN_RTOL)


def test_a_standing_vehicle_gets_a_spread_heading() -> None:
    joint = with_velocity_heading(_belief((0.01, 0.0), std=0.1), (2, 3), 0.01**2)
    var = joint.cov[0, 4, 4]
    assert 1.0 < var <= np.pi**2          # the sigma points' headings spread over the circle
    assert np.linalg.eigvalsh(joint.cov[0])[0] > 0 and np.isfinite(joint.mean).all()
    empty = with_velocity_heading(Gaussians(np.zeros((0, 4)), np.zeros((0, 4, 4))), (2, 3), 0.01)
    assert empty.mean.shape == (0, 5) and empty.cov.shape == (0, 5, 5)


def test_standing_is_the_chi2_test_of_zero_velocity() -> None:
    from scipy.stats import chi2

    assert STANDING_CHI2 == pytest.approx(chi2.ppf(0.99, 2), rel=1e-12)
    P = np.array([[0.04, 0.01], [0.01, 0.09]])
    direction = np.array([0.6, -0.8])
    scale = np.sqrt(chi2.ppf(0.99, 2) / (direction @ np.linalg.solve(P, direction)))
    # velocities just inside and just outside the 0.99 ellipse of v = 0, another speed far out
    v = np.array([0.999 * scale * direction, 1.001 * scale * direction, [8.0, 0.0]])
    cov = np.repeat(np.diag([4.0, 4.0, 1.0, 1.0])[None], 3, axis=0)
    cov[:, 2:, 2:] = P
    beliefs = Gaussians(np.column_stack([np.zeros((3, 2)), v]), cov)
    np.testing.assert_array_equal(standing(beliefs, (2, 3)), [True, False, False])


# ----------------------------------------------------------------------------
# a hand-made traffic on the SUMO code path
# ----------------------------------------------------------------------------

T = 12


def _traffic() -> tuple[sumo.Traffic, sumo.SumoParams]:
    """Six vehicles (ids 1, 4, …, 16 by `make_traffic`): a column of
    three on a street (1, 4, 7), one of which (4) stands, a pair 200 m away (10, 13) that
    enters at step 3 and leaves after step 8, and a lone vehicle 1 km away (16)."""
    start = np.array([[0.0, 0.0, 10.0, 0.0], [12.0, 6.0, 0.0, 0.0], [-15.0, -4.0, 10.0, 0.0],
                      [200.0, 0.0, 0.0, 8.0], [210.0, 5.0, 0.0, 8.0], [1000.0, 1000.0, -6.0, 6.0]])
    k = np.arange(T)[:, None, None]
    states = np.concatenate([start[None, :, :2] + k * start[None, :, 2:],
                             np.broadcast_to(start[None, :, 2:], (T, 6, 2))], axis=2)
    present = np.ones((T, 6), dtype=bool)
    present[:3, 3:5] = False
    present[9:, 3:5] = False
    heading = np.arctan2(states[..., 3], states[..., 2])
    heading[:, 1] = np.pi / 2                                   # the standing vehicle faces north
    params = sumo.SumoParams(dt=1.0, duration=float(T), radar=False, aoa=True, aoa_range=40.0,
                             aoa_anchor_share=0.2, zone_radii=(5e3, 6e3),   # zone C: σ_p = 15 m
                             prior_position_std=15.0, prior_velocity_std=0.45)  # a prior like the fixes
    return make_traffic(states, present, heading), params


def _scenes(count: int) -> list[Recording]:
    """`count` noise draws of `_traffic` in each of which vehicle 1 is the only anchor."""
    run, params = _traffic()
    out = []
    for seed in range(2000):
        rec = sumo.lay_sensors(params, run, np.random.default_rng([seed, 90]))
        if {int(i) for f in rec.frames for i in f.batches["anchor"].subject} == {1}:
            out.append(rec)
            if len(out) == count:
                return out
    raise AssertionError(f"fewer than {count} draws with vehicle 1 alone as anchor")


@pytest.fixture(scope="module")
def scene() -> Recording:
    return _scenes(1)[0]


def test_anchor_fixes_are_truth_plus_the_anchor_noise(rng: np.random.Generator) -> None:
    n = 400
    start = np.concatenate([rng.uniform(-500, 500, (n, 2)), rng.uniform(-10, 10, (n, 2))], axis=1)
    run = make_traffic(np.repeat(start[None], 2, axis=0), np.ones((2, n), dtype=bool))
    params = sumo.SumoParams(dt=1.0, duration=2.0, radar=False, aoa_anchor_share=0.3,
                             anchor_position_std=0.2, anchor_heading_std=0.02)
    rec = sumo.lay_sensors(params, run, rng)
    first, second = (f.batches["anchor"] for f in rec.frames)
    np.testing.assert_array_equal(first.subject, second.subject)       # anchors for the whole run
    assert 0.2 < first.subject.size / n < 0.4
    col = np.searchsorted(rec.truth.vehicle_ids, first.subject)
    true = np.column_stack([rec.truth.vehicle_states[0, col, :2], rec.truth.vehicle_heading[0, col]])
    residual = first.z - true
    residual[:, 2] = wrap_angle(residual[:, 2])
    assert_covariance_close(residual, np.diag([0.04, 0.04, 0.0004]), mean=np.zeros(3))
    assert rec.setup.sensors["anchor"].state_indices == (0, 1, 4)


@pytest.mark.parametrize("name", ["plbp", "prior-lbp"])
def test_traffic_enters_leaves_stands_and_is_alone(name: str, scene: Recording) -> None:
    rec = scene
    estimates = run_estimator(name, rec)
    reference = run_estimator("gnss-kf", rec)
    for k, (e, g) in enumerate(zip(estimates, reference, strict=True)):
        np.testing.assert_array_equal(e.vehicles.ids, rec.frames[k].vehicles)
        assert e.vehicles.mean.shape[1] == 4 and np.isfinite(e.vehicles.mean).all()
        assert np.isfinite(e.vehicles.cov).all() and (np.linalg.eigvalsh(e.vehicles.cov)[:, 0] > 0).all()
        heading = np.asarray(e.info["heading"])
        assert heading.shape == e.vehicles.ids.shape and ((-np.pi <= heading) & (heading < np.pi)).all()
        # the lone vehicle (id 16) has no AoA: its belief is the GNSS filter's
        lone = e.vehicles.ids == 16
        np.testing.assert_allclose(e.vehicles.mean[lone], g.vehicles.mean[g.vehicles.ids == 16],
                                   rtol=SAME_FILTER_RTOL)
        g_cov = g.vehicles.cov[g.vehicles.ids == 16]
        np.testing.assert_allclose(e.vehicles.cov[lone], g_cov, rtol=SAME_FILTER_RTOL,
                                   atol=SAME_FILTER_RTOL * np.abs(g_cov).max())
    # the pair without an anchor in range had AoA links (between themselves) while present
    assert all(len(rec.frames[k].batches["aoa"]) >= 2 for k in range(3, 9))
    errors = evaluate(rec, estimates)
    moving = ~np.isin(errors.id, [4])
    assert np.isfinite(errors.err_heading).all()
    # moving vehicles: the heading follows the velocity (GNSS σ_v = 0.45 m/s at 8–10 m/s:
    # 0.05 rad a fix; measured 0.045–0.047 rad RMSE over 32 draws)
    assert np.sqrt(np.mean(errors.err_heading[moving] ** 2)) < 0.1


def test_anchor_links_beat_the_gnss_filter() -> None:
    # the column of three around the anchor (1): 4 and 7 see it every step within 40 m, and
    # GNSS and prior are zone C's (15 m). An anchor's bearing fixes one direction (≈ 4.5 m
    # across at 14 m against 15 m), so about 0.74 of the GNSS filter's RMSE is what to
    # expect. Measured: pooled over 32 draws 0.72 (plbp) and 0.70 (prior-lbp); pooled over
    # 4 draws it ranged 0.51–0.98, so 8 draws are pooled here, paired on the same rows.
    scenes = _scenes(8)
    ratios = {}
    for name in ("plbp", "prior-lbp"):
        num = den = 0.0
        for rec in scenes:
            est, ref = evaluate(rec, run_estimator(name, rec)), evaluate(rec, run_estimator("gnss-kf", rec))
            num += np.sum(est.err_pos[np.isin(est.id, [4, 7])] ** 2)
            den += np.sum(ref.err_pos[np.isin(ref.id, [4, 7])] ** 2)
        ratios[name] = np.sqrt(num / den)
    assert ratios["plbp"] < 0.9 and ratios["prior-lbp"] < 0.9, ratios


def test_own_fixes_carry_the_gnss_filter_and_solve_on_it(scene: Recording) -> None:
    # tracking="own-fixes": what is carried from step to step is each vehicle's filter of
    # its own fixes, so for the non-anchors it is gnss-kf's belief at every step, while
    # the reported estimate is the AoA solve on it
    estimator = make_estimator("plbp", scene.setup, PLBPParams(tracking="own-fixes"),
                               np.random.default_rng(0))
    reference = run_estimator("gnss-kf", scene)
    moved = False
    for frame, g in zip(scene.frames, reference, strict=True):
        e = estimator.step(frame)
        carried = estimator.vehicles.beliefs
        plain = e.vehicles.ids != 1                                      # 1 is the anchor
        np.testing.assert_allclose(carried.mean[plain], g.vehicles.mean[plain], rtol=SAME_FILTER_RTOL,
                                   atol=SAME_FILTER_RTOL * np.abs(g.vehicles.mean).max())
        np.testing.assert_allclose(carried.cov[plain], g.vehicles.cov[plain], rtol=SAME_FILTER_RTOL,
                                   atol=SAME_FILTER_RTOL * np.abs(g.vehicles.cov).max())
        moved |= not np.allclose(e.vehicles.mean[plain], g.vehicles.mean[plain], rtol=1e-3)
    assert moved                                                         # the AoA did change the estimates


@pytest.mark.parametrize("name", ["plbp", "prior-lbp"])
def test_no_anchors_at_all(name: str) -> None:
    run, params = _traffic()
    rec = sumo.lay_sensors(dataclasses.replace(params, aoa_anchor_share=0.0), run, np.random.default_rng(5))
    assert "anchor" not in rec.setup.sensors
    for e in run_estimator(name, rec):
        assert np.isfinite(e.vehicles.mean).all() and np.isfinite(e.vehicles.cov).all()
        assert np.isfinite(np.asarray(e.info["heading"])).all()


def test_a_layout_without_heading_or_velocity_is_refused(scene: Recording) -> None:
    bad = dataclasses.replace(scene.setup, sensors={**scene.setup.sensors, "aoa": AngleOfArrival(
        default_cov=np.array([[0.1]]), state_indices=(0, 1, 3))})
    with pytest.raises(ConfigError, match=r"plbp needs a vehicle layout with a heading.*indices \(0, 1, 3\)"):
        make_estimator("plbp", bad, None, np.random.default_rng(0))


@pytest.mark.parametrize("name", ["plbp", "prior-lbp"])
def test_a_standing_receivers_bearings_carry_nothing(name: str, scene: Recording) -> None:
    # vehicle 4 stands (v = 0, facing north) and is no anchor. In this draw its velocity
    # belief does not exclude v = 0 during the first 5 steps (v̂ᵀ P_v⁻¹ v̂ = 0.6–3.0; at step
    # 5 a draw of 13.2 > 9.21 passes it for moving), so there its heading is unknown and the
    # bearings it measures carry no information: turning them by 2 rad leaves every estimate
    # as it was. Before they were left out, a heading taken from a velocity that is noise was
    # the reference of these bearings (and the carried posterior counted that error again
    # at every step).
    def turned(batch: Batch) -> Batch:
        z = batch.z.copy()
        z[batch.sensor == 4] = wrap_angle(z[batch.sensor == 4] + 2.0)
        return Batch(z, batch.cov, batch.sensor, batch.subject)

    steps = 5
    frames = scene.frames[:steps]
    assert all((f.batches["aoa"].sensor == 4).any() for f in frames)
    plain, other = (make_estimator(name, scene.setup, None, np.random.default_rng(0)) for _ in range(2))
    for frame in frames:
        e = plain.step(frame)
        batches = {**frame.batches, "aoa": turned(frame.batches["aoa"])}
        t = other.step(dataclasses.replace(frame, batches=batches))
        np.testing.assert_array_equal(e.vehicles.mean, t.vehicles.mean)
        np.testing.assert_array_equal(e.vehicles.cov, t.vehicles.cov)
    # the bearings that others take of 4 still place it: its estimate is not the GNSS filter's
    four = [e.vehicles.mean[e.vehicles.ids == 4] for e in run_estimator(name, scene)[:steps]]
    gnss = [g.vehicles.mean[g.vehicles.ids == 4] for g in run_estimator("gnss-kf", scene)[:steps]]
    assert not np.allclose(np.concatenate(four), np.concatenate(gnss), rtol=1e-3)
