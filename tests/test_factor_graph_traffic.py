"""The Gulati 2017 factor graphs in traffic (issue 19): per-radar topology factors.

Recordings are the hand-made traffic of `test_sme_traffic` (two queues around two
road-side radars of unknown pose, vehicles entering late and leaving early, no SUMO
run). Oracles: the truth's row origins (which vehicles each radar's rows come from —
the graph must find these sets from its own beliefs), the batch smoother (iSAM2 solves
the same graph), and the graph of the same frames without radar rows.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cooploc.estimators.factor_graph import NEW, OLD, GraphData, ISAM2Params
from cooploc.estimators.factor_graph.estimates import PositionFilter
from cooploc.registry import make_estimator
from cooploc.types import Recording
from test_sme_traffic import _queues, _without


@pytest.fixture(scope="module")
def traffic() -> Recording:
    return _queues()


@pytest.mark.parametrize("kind", [OLD, NEW])
def test_each_topology_factor_joins_the_vehicles_its_radar_sees(kind: str, traffic: Recording) -> None:
    """Two radars, each seeing its own queue: every per-radar topology factor joins exactly
    the vehicles behind one radar's rows (truth origins), and both radars give factors."""
    data = GraphData(traffic.setup, kind, 900.0)
    assert data.fields is not None   # two radars of finite range: the per-radar mode
    filt = PositionFilter()
    matched: set[int] = set()
    n_factors = 0
    for k, frame in enumerate(traffic.frames):
        f = data.add_frame(frame)
        belief = filt.step(f)
        f = data.add_radar_topology(frame, belief.mean, belief.cov)
        radar = frame.batches["radar"]
        origin = traffic.truth.origin[k]["radar"]
        truth_sets = {int(s): set(origin[radar.sensor == s].tolist()) for s in np.unique(radar.sensor)}
        for current in f.topology_current:
            ids = set(f.ids[np.searchsorted(f.vars, current)].tolist())
            radars = [s for s, seen in truth_sets.items() if seen == ids]
            assert radars, f"step {k}: factor over {sorted(ids)}, radars see {truth_sets}"
            matched.update(radars)
        n_factors += f.topology_s.size
    assert len(matched) == 2
    assert n_factors >= len(traffic.frames)   # most steps, both radars
    assert data.n_topology == n_factors


def test_vehicles_entering_and_leaving_isam2_ends_at_the_batch_solution(traffic: Recording) -> None:
    """Vehicles enter late and leave early: each estimate holds exactly the present vehicles,
    finite, and iSAM2's last estimate is the batch smoother's of the last step (the same
    graph, the same per-radar factors)."""
    frames = traffic.frames[:45]   # vehicle 3 enters at step 10, 12 at 25, 5 leaves at 40
    isam = make_estimator("fg-isam2", traffic.setup, None, np.random.default_rng(0))
    filtered = [isam.step(f) for f in frames]
    batch = make_estimator("fg-topology-new", traffic.setup, None, np.random.default_rng(0))
    for f in frames:
        batch.step(f)
    smoothed = batch.smooth()
    assert isam.data.n_topology == batch.data.n_topology > 0
    for f, a, b in zip(frames, filtered, smoothed, strict=True):
        for e in (a, b):
            np.testing.assert_array_equal(e.vehicles.ids, np.sort(f.vehicles))
            assert np.isfinite(e.vehicles.mean).all() and np.isfinite(e.vehicles.cov).all()
    # relinearize_threshold 0.1 m leaves linearisation points up to 0.1 m stale
    last, best = filtered[-1].vehicles.mean[:, :2], smoothed[-1].vehicles.mean[:, :2]
    np.testing.assert_allclose(last, best, atol=0.05)


def test_vehicles_entering_and_leaving_are_marginalised_out_of_isam2(traffic: Recording) -> None:
    """Fixed lag of 3 steps while vehicles enter (at steps 10 and 25) and one leaves (at
    40): iSAM2 holds exactly the variables of the last 4 steps — none of the vehicle that
    left once it is 4 steps gone — every estimate holds exactly the present vehicles, finite, and stays
    within linearisation error of the full iSAM2's (measured ≤ 0.03 m)."""
    lag = 3
    full = make_estimator("fg-isam2", traffic.setup, ISAM2Params(lag=0), np.random.default_rng(0))
    lagged = make_estimator("fg-isam2", traffic.setup, ISAM2Params(lag=lag), np.random.default_rng(0))
    for k, f in enumerate(traffic.frames):
        a, b = full.step(f), lagged.step(f)
        np.testing.assert_array_equal(b.vehicles.ids, np.sort(f.vehicles))
        assert np.isfinite(b.vehicles.mean).all() and np.isfinite(b.vehicles.cov).all()
        # relinearize_threshold 0.1 m: linearisation points up to 0.1 m stale in either
        np.testing.assert_allclose(b.vehicles.mean, a.vehicles.mean, rtol=0, atol=0.1)
        kept = set(lagged.isam.getLinearizationPoint().keys())
        assert len(lagged.data.frames) == min(k + 1, lag + 1)   # the graph data holds the window
        window = set(np.concatenate([g.vars for g in lagged.data.frames]).tolist())
        assert kept == window
    assert set(traffic.frames[39].vehicles.tolist()) - set(traffic.frames[-1].vehicles.tolist())   # one left
    assert lagged.data.n_topology > 0


@pytest.mark.parametrize("name", ["fg-topology-old", "fg-isam2"])
def test_without_radar_rows_the_graph_is_the_no_radar_graph(name: str, traffic: Recording) -> None:
    """No radar rows: the estimates of a setup without radars. Bit for bit for the batch
    graph; iSAM2 with radars in the setup starts new variables elsewhere and relinearises
    every update, which on this linear graph changes round-off only."""
    frames = _without(traffic, "radar")
    sensors = {k: v for k, v in traffic.setup.sensors.items() if k != "radar"}
    bare = dataclasses.replace(traffic.setup, sensors=sensors)
    runs = []
    for setup in (traffic.setup, bare):
        est = make_estimator(name, setup, None, np.random.default_rng(0))
        out = [est.step(f) for f in frames]
        runs.append(est.smooth() if hasattr(est, "smooth") else out)
    assert runs[0][-1].info["topology"] == 0
    atol = 0.0 if name == "fg-topology-old" else 1e-9
    for a, b in zip(*runs, strict=True):
        np.testing.assert_allclose(a.vehicles.mean, b.vehicles.mean, rtol=0, atol=atol)
        np.testing.assert_allclose(a.vehicles.cov, b.vehicles.cov, rtol=0, atol=atol)
