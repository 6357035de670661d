"""The `aoa-manhattan` scene against its description (issue 15) and the estimator contract.

- Geometry: 51 vehicles, each in a lane of a one-way avenue or street of the map, at a
  lane centre, heading along its road in its road's direction; road centre lines
  270 m (avenues) and 80 m (streets) apart, a few hundred metres across.
- Lanes are equally dense: the share of vehicles on avenues is the avenues' share of
  lane length (a statistical check that passes for any seed).
- Anchors as the notes say: 6 of them, ids 0–5, σ_p = 0.1 m and σ_α = 0.01 rad; the
  others Table I's 5 m and 0.35 rad.
- Links are exactly the pairs within R_c; the default field of view Δ = π/2.
- The contract suite (`cooploc.testing`) on short runs of the scene, for every registered
  estimator that reads angles of arrival; a snapshot refuses a GNSS filter.
"""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.registry import construct, estimators, get_estimator, get_preset
from cooploc.scenarios.aoa_manhattan import AoaManhattanParams, anchor_ids, generate, road_lines
from cooploc.testing import check_estimator, on_preset

PRESET = "aoa-manhattan"
# For N Bernoulli(p) draws the share has standard deviation sqrt(p (1 − p) / N); 6 of
# those fail with probability < 1e-8.
N_SIGMA = 6.0


def _runs(seed: int, runs: int, **overrides):
    params = get_preset(PRESET).params.with_overrides(overrides)
    return params, [generate(params, np.random.default_rng([seed, 15, r])) for r in range(runs)]


def test_the_preset_is_the_notes_scene() -> None:
    params = get_preset(PRESET).params
    assert isinstance(params, AoaManhattanParams)
    assert (params.n_vehicles, params.n_anchors) == (51, 6)
    assert (params.avenue_spacing, params.street_spacing) == (270.0, 80.0)   # 270 m × 80 m blocks
    width, height = params.extent
    assert (width, height) == (540.0, 240.0)              # 2 × 3 blocks: a few hundred metres
    assert (params.communication_radius, params.aoa_variance) == (30.0, 0.10)       # Table I
    assert (params.prior_position_std, params.prior_heading_std) == (5.0, 0.35)
    assert params.field_of_view == np.pi / 2 and params.n_steps == 1


def test_vehicles_drive_in_the_lanes_of_one_way_roads(seed: int) -> None:
    params, recs = _runs(seed, 4)
    width, height = params.extent
    w = params.lane_width
    for rec in recs:
        x, y, heading = rec.truth.vehicle_states[0].T
        assert x.size == 51 and np.array_equal(rec.truth.vehicle_ids, np.arange(51))
        on_avenue = np.isclose(np.abs(np.sin(heading)), 1.0)
        assert (on_avenue | np.isclose(np.abs(np.cos(heading)), 1.0)).all()
        for avenue, across, along, spacing, lanes, length in (
                (True, x, y, params.avenue_spacing, params.avenue_lanes, height),
                (False, y, x, params.street_spacing, params.street_lanes, width)):
            rows = on_avenue == avenue
            road = np.round(across[rows] / spacing)                        # index of the nearest road
            n_roads = params.n_avenues if avenue else params.n_streets
            assert road.min() >= 0 and road.max() <= n_roads - 1
            # a lane centre of the road: (l − (k − 1)/2) lane widths from its centre line
            lane = (across[rows] - road * spacing) / w + (lanes - 1) / 2
            np.testing.assert_allclose(lane, np.round(lane), atol=1e-9)
            assert lane.min() > -0.5 and lane.max() < lanes - 0.5
            assert (along[rows] >= 0).all() and (along[rows] <= length).all()
            # one-way, directions alternating: avenue 0 northbound, street 0 eastbound
            forward = road % 2 == 0
            want = np.where(forward, np.pi / 2, -np.pi / 2) if avenue else np.where(forward, 0.0, -np.pi)
            np.testing.assert_allclose(heading[rows], want, atol=1e-12)


def test_lanes_are_equally_dense(seed: int) -> None:
    params, recs = _runs(seed, 40)
    width, height = params.extent
    avenue_lanes = params.n_avenues * params.avenue_lanes * height
    p = avenue_lanes / (avenue_lanes + params.n_streets * params.street_lanes * width)
    on_avenue = np.concatenate([np.isclose(np.abs(np.sin(r.truth.vehicle_states[0, :, 2])), 1.0)
                                for r in recs])
    assert abs(on_avenue.mean() - p) < N_SIGMA * np.sqrt(p * (1 - p) / on_avenue.size)


def test_anchors_links_and_arrays(seed: int) -> None:
    params, recs = _runs(seed, 3)
    anchors = anchor_ids(params)
    assert anchors.tolist() == [0, 1, 2, 3, 4, 5]
    for rec in recs:
        std = np.sqrt(np.diagonal(rec.setup.vehicle_prior.cov, axis1=1, axis2=2))
        np.testing.assert_allclose(std[anchors], np.broadcast_to([0.1, 0.1, 0.01], (6, 3)))
        np.testing.assert_allclose(std[6:], np.broadcast_to([5.0, 5.0, 0.35], (45, 3)))
        states = rec.truth.vehicle_states[0]
        d = np.linalg.norm(states[:, None, :2] - states[None, :, :2], axis=-1)
        want = {(i, j) for i, j in zip(*np.nonzero(d <= params.communication_radius), strict=True) if i < j}
        assert {tuple(sorted(map(int, link))) for link in rec.frames[0].links} == want
        # Δ = π/2: every link is measured at both ends
        assert len(rec.frames[0].batches["aoa"]) == 2 * len(want)
        assert rec.setup.sensors["aoa"].field_of_view == np.pi / 2


def test_road_lines_and_validation() -> None:
    params = get_preset(PRESET).params
    lines = road_lines(params)
    assert len(lines) == 3 * (params.n_avenues + params.n_streets)     # centre line and two edges
    centres = lines[1::3]
    np.testing.assert_allclose([c[0, 0] for c in centres[:3]], [0.0, 270.0, 540.0])
    np.testing.assert_allclose([c[0, 1] for c in centres[3:]], [0.0, 80.0, 160.0, 240.0])
    np.testing.assert_allclose(lines[0][0, 0], -2 * params.lane_width)            # 4-lane avenue
    with pytest.raises(ConfigError, match="n_avenues"):
        AoaManhattanParams(n_avenues=1)
    with pytest.raises(ConfigError, match="field_of_view"):
        params.with_overrides({"field_of_view": "2.0"})


# ----------------------------------------------------------------------------
# the estimator contract on the scene
# ----------------------------------------------------------------------------

#: the checks that must pass here (missed_detections_and_clutter skips: the scene has no
#: detection probability; froehle_traffic is a froehle2018 run; long_run is slow, left out)
RUN_HERE = ("interface", "valid_estimates", "empty_frames", "same_seed", "enter_and_leave",
            "truth_only_to_references", "true_states_never_read")
#: the estimators that read angles of arrival; the others ignore the scene's AoA rows and
#: are held to the contract on their own presets
AOA = sorted(n for n, cls in estimators().items() if "aoa" in getattr(cls, "usable_sensors", {}))


def test_the_aoa_estimators_are_found() -> None:
    assert {"plbp", "prior-lbp"} <= set(AOA)


@pytest.mark.parametrize("name", AOA)
def test_contract_on_manhattan(name: str, seed: int) -> None:
    """The contract on short tracking runs of the scene (a fix per step from step 1 on)."""
    outcome = check_estimator(on_preset(name, PRESET), seed=seed, slow=False)
    assert all(outcome[c] == "passed" for c in RUN_HERE), outcome


def test_a_snapshot_needs_an_aoa_estimator(seed: int) -> None:
    """The paper's snapshot offers angles of arrival only: a GNSS filter is refused."""
    rec = get_preset(PRESET).generate(np.random.default_rng([seed, 16]))
    with pytest.raises(ConfigError, match="gnss-kf"):
        construct(get_estimator("gnss-kf"), rec.setup, None, np.random.default_rng(0))
