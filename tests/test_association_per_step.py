"""The two V2F association measures of `cooploc.metrics`: per track over the run, and
per step (Brambilla et al. 2020 §V), against brute force and fabricated label swaps."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from cooploc.experiment import ExperimentConfig, run_experiment
from cooploc.metrics import paired_features, score_association
from cooploc.results import summarize
from cooploc.testing import preset_recording
from cooploc.types import Estimate, Recording, StateSet


def _brute_force_match(ids, pos, fids, fpos) -> dict[int, int]:
    """Track → feature by enumerating every one-to-one matching of the smaller set into
    the larger one (minimum summed squared distance); left-over tracks get −1."""
    n, m = len(ids), len(fids)
    best, best_cost = {int(t): -1 for t in ids}, np.inf
    if n == 0 or m == 0:
        return best
    cost = ((pos[:, None, :] - fpos[None, :, :]) ** 2).sum(-1)
    if n <= m:
        for cols in itertools.permutations(range(m), n):
            c = sum(cost[i, j] for i, j in enumerate(cols))
            if c < best_cost:
                best_cost, best = c, {int(ids[i]): int(fids[j]) for i, j in enumerate(cols)}
    else:
        for rows in itertools.permutations(range(n), m):
            c = sum(cost[i, j] for j, i in enumerate(rows))
            if c < best_cost:
                best_cost = c
                best = {int(t): -1 for t in ids} | {int(ids[i]): int(fids[j]) for j, i in enumerate(rows)}
    return best


def _brute_force_paired(row_tracks, track_ids, track_pos, feature_ids, feature_pos) -> list[np.ndarray]:
    """The rule of `paired_features` written out step by step, with brute-force matchings."""
    matches = [_brute_force_match(*step)
               for step in zip(track_ids, track_pos, feature_ids, feature_pos, strict=True)]
    out = []
    for k, rows in enumerate(row_tracks):
        paired = []
        for t in rows:
            earlier = [j for j in range(k) if t in matches[j]]
            if t < 0:
                paired.append(-1)
            elif earlier:
                paired.append(matches[earlier[-1]][t])
            else:
                paired.append(matches[k].get(t, -1))
        out.append(np.array(paired, dtype=np.int64))
    return out


@pytest.mark.parametrize("seed", range(40))
def test_paired_features_equal_brute_force_on_tiny_cases(seed: int) -> None:
    rng = np.random.default_rng(seed)
    steps = int(rng.integers(1, 6))
    pool_tracks = np.array([7, 8, 9, 12])
    pool_features = np.array([100, 101, 102, 103])
    row_tracks, track_ids, track_pos, feature_ids, feature_pos = [], [], [], [], []
    for _ in range(steps):
        ids = np.sort(rng.choice(pool_tracks, int(rng.integers(0, 5)), replace=False))
        fids = np.sort(rng.choice(pool_features, int(rng.integers(0, 4)), replace=False))
        track_ids.append(ids)
        track_pos.append(rng.normal(size=(ids.size, 2)) * 5)
        feature_ids.append(fids)
        feature_pos.append(rng.normal(size=(fids.size, 2)) * 5)
        # rows may name tracks not estimated this step, or none (−1)
        row_tracks.append(rng.choice(np.append(pool_tracks, -1), int(rng.integers(0, 6))))
    got = paired_features(row_tracks, track_ids, track_pos, feature_ids, feature_pos)
    want = _brute_force_paired(row_tracks, track_ids, track_pos, feature_ids, feature_pos)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


def test_a_common_shift_of_all_tracks_changes_no_match() -> None:
    features = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.3]])
    tracks = features + np.array([[0.04, -0.02], [-0.03, 0.05], [0.01, 0.02]])
    ids, fids = np.array([3, 4, 5]), np.array([10, 11, 12])
    for shift in ([0.0, 0.0], [7.0, -3.0], [-0.6, 0.0]):   # far more than the 0.5 m spacing
        paired = paired_features([ids], [ids], [tracks + shift], [fids], [features])
        np.testing.assert_array_equal(paired[0], fids)


# ----------------------------------------------------------------------------
# fabricated estimates on a road recording: 2 vehicles, 2 features 3 m apart
# ----------------------------------------------------------------------------

TRACKS = (7, 9)


@pytest.fixture(scope="module")
def road() -> Recording:
    return preset_recording("brambilla-road", 0, {"n_steps": 20})


def _estimates(recording: Recording, swapped: list[bool]) -> list[Estimate]:
    """Track 7 holds feature A's rows and sits at A, track 9 B's — except at the steps
    where `swapped` is true, where both vehicles consistently give each feature's rows
    to the other track, and the tracks' estimates follow their rows."""
    truth = recording.truth
    a, b = truth.feature_ids[:2]
    out = []
    for k, swap in enumerate(swapped):
        origin = truth.origin[k]["v2f"]
        first, second = TRACKS[::-1] if swap else TRACKS
        track = np.where(origin == a, first, np.where(origin == b, second, -1))
        states = truth.feature_states[k][:2]
        order = [1, 0] if swap else [0, 1]
        features = StateSet(np.array(TRACKS), states[order], np.broadcast_to(np.eye(4), (2, 4, 4)).copy())
        vehicles = StateSet(truth.vehicle_ids, truth.vehicle_states[k], np.broadcast_to(
            np.eye(4), (truth.vehicle_ids.size, 4, 4)).copy())
        out.append(Estimate(vehicles, features, {"v2f_track": track, "v2f_discarded": 0}))
    return out


def _rows(recording: Recording) -> np.ndarray:
    return np.array([recording.truth.origin[k]["v2f"].size for k in range(len(recording.frames))])


def test_scattered_swaps_keep_the_track_measure_high_and_halve_the_per_step_one(road: Recording) -> None:
    swapped = [k % 4 == 2 for k in range(len(road.frames))]     # every 4th step, for that step only
    _, score = score_association(road, _estimates(road, swapped))
    rows = _rows(road)
    assert score.total == rows.sum()
    # per track: each track's majority is its own feature; only the swapped steps' rows are wrong
    assert score.correct == rows[~np.array(swapped)].sum()
    # per step: the rows of a swapped step, and of the step after it, went to the other belief
    changed = np.array([False] + [swapped[k] != swapped[k - 1] for k in range(1, len(swapped))])
    assert score.per_step_correct == rows[~changed].sum()
    assert score.correct / score.total >= 0.7 and score.per_step_correct / score.total <= 0.55


def test_one_lasting_swap_costs_the_per_step_measure_one_step(road: Recording) -> None:
    T = len(road.frames)
    swapped = [k >= T // 2 for k in range(T)]          # the tracks trade features for good
    _, score = score_association(road, _estimates(road, swapped))
    rows = _rows(road)
    assert score.per_step_correct == rows.sum() - rows[T // 2]
    assert score.correct == max(rows[: T // 2].sum(), rows[T // 2:].sum())


def test_decisions_by_feature_id_score_the_same_both_ways(road: Recording) -> None:
    estimates = []
    for k in range(len(road.frames)):
        origin = road.truth.origin[k]["v2f"].copy()
        origin[: k % 2] = -1                          # one wrong decision every other step
        estimates.append(Estimate(StateSet.empty(4), None, {"v2f_association": origin}))
    _, score = score_association(road, estimates)
    assert score.per_step_correct == score.correct < score.total


@pytest.mark.slow
def test_summary_holds_both_measures() -> None:
    config = ExperimentConfig.build("brambilla-road", ["icp-da-lc", "icp"], runs=2, seed=1, backend="serial",
                                    scenario_overrides={"feature_spacing": 0.5})
    summary = summarize(run_experiment(config))["estimators"]
    lc = summary["icp-da-lc"]
    assert 0.0 <= lc["association_accuracy_per_step"] <= 1.0
    assert 0.0 <= lc["association_accuracy"] <= 1.0
    assert summary["icp"]["association_accuracy_per_step"] is None   # known association: nothing decided
