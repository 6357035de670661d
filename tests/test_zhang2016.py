"""The Zhang 2016 scenarios, the set-valued metrics (assignment, OSPA, eq. 20) and the paper's ordering."""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig, run_experiment
from cooploc.geometry import to_local
from cooploc.metrics import evaluate, optimal_assignment, ospa, set_errors, total_rmse
from cooploc.reproduce.zhang2016 import per_run_total
from cooploc.results import summarize
from cooploc.scenarios import get_preset
from cooploc.scenarios.zhang2016 import INITIAL_STATES_PAPER, RADAR_ID, ZhangParams, initial_states
from cooploc.types import Estimate, StateSet

NOISE_SIGMAS = 6.0  # bound of sample statistics in standard errors (false alarm ~1e-9)


@pytest.fixture(scope="module")
def runs(seed: int) -> dict:
    return {name: get_preset(name).generate(np.random.default_rng([seed, 11]))
            for name in ("zhang2016-cv", "zhang2016-ct2", "zhang2016-ct4")}


def test_initial_states_in_cooploc_layout() -> None:
    x = initial_states()
    np.testing.assert_array_equal(x[0], [0.0, 100.0, -1.5, -1.0])   # paper [0, −1.5, 100, −1]
    np.testing.assert_array_equal(x[:, [0, 2, 1, 3]], INITIAL_STATES_PAPER)


def test_cv_vehicles_move_in_straight_lines(runs: dict) -> None:
    rec = runs["zhang2016-cv"]
    x = rec.truth.vehicle_states
    k = np.arange(x.shape[0])[:, None, None]
    np.testing.assert_allclose(x[..., :2], x[0, :, :2] + k * x[0, :, 2:], atol=1e-9)
    assert rec.setup.vehicle_layout.position == (0, 1)
    assert rec.truth.sensor_poses.shape == (1, 3) and rec.setup.infrastructure_ids == (RADAR_ID,)


@pytest.mark.parametrize("name, turning", [("zhang2016-ct2", [0, 4]), ("zhang2016-ct4", [0, 1, 3, 4])])
def test_turning_vehicles_keep_speed_and_turn_at_omega(runs: dict, name: str, turning: list[int]) -> None:
    v = runs[name].truth.vehicle_states[..., 2:]
    speed = np.linalg.norm(v, axis=-1)
    np.testing.assert_allclose(speed, np.broadcast_to(speed[0], speed.shape), rtol=1e-12)  # constant
    heading = np.unwrap(np.arctan2(v[..., 1], v[..., 0]), axis=0)
    rate = np.diff(heading, axis=0).mean(0)                                    # rad per 1 s step
    expected = np.array(get_preset(name).params.turn_rates)
    assert np.count_nonzero(expected) == len(turning) and np.all(expected[turning] != 0)
    np.testing.assert_allclose(rate, expected, atol=1e-12)


def test_rows_are_anonymous_and_noisy_as_stated(runs: dict) -> None:
    rec = runs["zhang2016-cv"]
    pose = rec.truth.sensor_poses[0]
    residual_gnss, residual_radar = [], []
    for k, frame in enumerate(rec.frames):
        gnss, radar = frame.batches["gnss"], frame.batches["radar"]
        assert (gnss.sensor == -1).all() and (gnss.subject == -1).all() and (radar.subject == -1).all()
        truth = rec.truth.vehicle_states[k][:, :2]
        residual_gnss.append(gnss.z - truth[rec.truth.origin[k]["gnss"]])
        residual_radar.append(radar.z - to_local(pose, truth[rec.truth.origin[k]["radar"]]))
    for residual, variance in ((np.concatenate(residual_gnss), 0.5), (np.concatenate(residual_radar), 0.1)):
        n = residual.shape[0]
        # sample variance of Gaussian noise: standard error variance · sqrt(2 / n)
        assert np.all(np.abs(residual.var(0) - variance) < NOISE_SIGMAS * variance * np.sqrt(2 / n))
    # shuffled: the origin order is not the vehicle order at every step
    assert any(not np.array_equal(o["gnss"], np.arange(5)) for o in rec.truth.origin)


def test_misses_and_clutter(seed: int) -> None:
    preset = get_preset("zhang2016-cv")
    rec = preset.generate(np.random.default_rng([seed, 12]), preset.params.with_overrides(
        {"n_steps": 30, "detection_probability": 0.5, "clutter_rate": 3.0}))
    counts = np.array([len(f.batches["gnss"]) for f in rec.frames])
    origins = np.concatenate([o["gnss"] for o in rec.truth.origin])
    assert (origins == -1).any() and (counts != 5).any()


def test_params_are_validated() -> None:
    with pytest.raises(ConfigError, match="n_vehicles"):
        ZhangParams(n_vehicles=6)
    with pytest.raises(ConfigError, match="turn_rates"):
        ZhangParams(n_vehicles=2, turn_rates=(0.1, 0.1, 0.1))


# ----------------------------------------------------------------------------
# metrics of set-valued estimates
# ----------------------------------------------------------------------------


def test_ospa_known_values() -> None:
    X = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert ospa(X, X) == 0.0
    assert ospa(X, X[::-1] + np.array([0.0, 3.0])) == pytest.approx(3.0)             # order is ignored
    # one missed target costs c: ((0 + c²) / 2)^{1/2}
    assert ospa(X[:1], X, cutoff=10.0) == pytest.approx(np.sqrt(50.0))
    assert ospa(np.zeros((0, 2)), np.zeros((0, 2))) == 0.0
    assert ospa(np.zeros((0, 2)), X, cutoff=7.0) == 7.0


def test_assignment_errors_ignore_labels(rng: np.random.Generator) -> None:
    true = rng.uniform(-50, 50, (5, 2))
    est = true[[3, 0, 4, 1, 2]] + 0.1
    rows, cols = optimal_assignment(est, true)
    np.testing.assert_array_equal(cols[np.argsort(rows)], [3, 0, 4, 1, 2])
    np.testing.assert_allclose(set_errors(est, true), np.sqrt(0.02))
    assert np.isnan(set_errors(est[:4], true)).sum() == 1


def test_evaluate_assigns_set_valued_estimates(runs: dict) -> None:
    rec = runs["zhang2016-cv"]
    k = 7
    true = rec.truth.vehicle_states[k]
    shuffled = StateSet(np.arange(5), true[[4, 2, 0, 1, 3]] + 0.5, np.repeat(np.eye(4)[None], 5, 0))
    estimates = [Estimate(shuffled, None, {"set_valued": True})] * len(rec.frames)
    table = evaluate(rec, estimates)
    at_k = table.step == k
    np.testing.assert_allclose(table.err_pos[at_k], np.sqrt(0.5), rtol=1e-12)
    # the same estimate without the mark is scored by id: the shuffle shows
    labelled = evaluate(rec, [Estimate(shuffled)] * len(rec.frames))
    assert labelled.err_pos[labelled.step == k].max() > 10


def test_total_rmse_is_eq_20() -> None:
    step = np.array([0, 0, 1, 1])
    err = np.array([1.0, 2.0, 3.0, 0.0])
    assert total_rmse(step, err) == pytest.approx(np.sqrt(((1 + 4) + 9) / 2))


def test_summary_has_total_rmse_and_ospa(seed: int) -> None:
    config = ExperimentConfig.build("zhang2016-cv", ["kf-known-da", "gm-phd"], runs=2, seed=seed % 1000,
                                    backend="serial", scenario_overrides={"n_steps": 10})
    summary = summarize(run_experiment(config))
    for name in ("kf-known-da", "gm-phd"):
        entry = summary["estimators"][name]
        assert entry["total_rmse"] > 0 and entry["ospa"] > 0
        assert entry["total_rmse"] == pytest.approx(np.sqrt(5) * entry["vehicle_rmse_all"], rel=1e-9)


# ----------------------------------------------------------------------------
# the paper's ordering (Fig. 3, CV)
# ----------------------------------------------------------------------------


@pytest.mark.slow
def test_ordering_on_zhang2016_cv(seed: int) -> None:
    """The paper's Fig. 3 ordering SME < KF < PHD against what we measure, paired over runs.

    Measured (`cooploc reproduce zhang2016`, 20 runs; and 24 runs, seed 5): the Kalman
    filter given the association is the most accurate. SME (here its UKF form, the one
    fast enough for the test budget; `sme-pf` with 2000 particles is worse still) is
    *worse* than KF by ≈ 0.2 m of total error (z ≈ 4.5 over 24 paired runs): the radar's
    topology adds one scalar per step, too little to pay for the approximation of the
    nonlinear filter. GM-PHD with the known vehicle count equals KF to ~1 cm in most
    runs and fails in some (two vehicles merged at a crossing), so KF ≤ PHD.

    The checks are on the sign of paired means (16 runs: a false alarm needs a
    ≈ 3.7-standard-error excursion, probability ~1e-4), and on KF ≤ PHD to 1 cm per run
    in the median (PHD's update reduces to KF's for separated vehicles).
    """
    names = ["kf-known-da", "gm-phd", "sme-ukf"]
    config = ExperimentConfig.build("zhang2016-cv", names, runs=16, seed=seed % 100_000, backend="serial")
    result = run_experiment(config)
    total = {n: np.array(per_run_total(result, n)) for n in names}
    assert all(np.isfinite(v).all() for v in total.values())
    sme_minus_kf = float(np.mean(total["sme-ukf"] - total["kf-known-da"]))
    assert sme_minus_kf > 0, "SME beat KF: the paper's claim now reproduces — update the report"
    assert np.median(total["gm-phd"] - total["kf-known-da"]) > -0.01
    assert total["gm-phd"].mean() > total["kf-known-da"].mean() - 0.01


# ----------------------------------------------------------------------------
# what the topology can add (reproduce.zhang2016_information)
# ----------------------------------------------------------------------------


@pytest.mark.slow
def test_expected_error_of_the_known_association_kf_matches_monte_carlo(seed: int) -> None:
    # the analysis propagates kf-known-da's error exactly (gains, noise, the turns the CV
    # model misses); eq. (20) squared, mean over runs, must match it within 6 standard errors
    from cooploc.reproduce.zhang2016_information import expected_squared_error

    config = ExperimentConfig.build("zhang2016-ct4", ["kf-known-da"], runs=40, seed=seed % 1000,
                                    backend="serial", scenario_overrides={"n_steps": 40})
    result = run_experiment(config)
    squared = np.array(per_run_total(result, "kf-known-da")) ** 2
    preset = get_preset("zhang2016-ct4")
    rec = preset.generate(np.random.default_rng(0), preset.params.with_overrides({"n_steps": 40}))
    expected = expected_squared_error(rec, use_topology=False).mean()
    se = squared.std(ddof=1) / np.sqrt(squared.size)
    assert abs(squared.mean() - expected) <= NOISE_SIGMAS * se, (squared.mean(), expected, se)


def test_topology_gain_is_small_and_vanishes_with_a_useless_radar(runs: dict) -> None:
    import dataclasses

    from cooploc.reproduce.zhang2016_information import topology_gain
    from cooploc.sensors import InfrastructureRadar

    rec = runs["zhang2016-cv"]
    gain = topology_gain(rec)
    # one scalar per step against 2N GPS coordinates: a few per cent, never a loss
    assert 0.0 < gain.gain < 0.1 and gain.kf_topology < gain.kf
    radar = InfrastructureRadar(default_cov=1e6 * np.eye(2))
    blind = dataclasses.replace(rec.setup, sensors={**rec.setup.sensors, "radar": radar})
    useless = topology_gain(dataclasses.replace(rec, setup=blind))
    np.testing.assert_allclose(useless.kf_topology, useless.kf, rtol=1e-4)   # T's variance ~ 1e6 m²


# ----------------------------------------------------------------------------
# the report's claims: verdicts from fabricated per-run numbers
# ----------------------------------------------------------------------------


def _fabricated(rng: np.random.Generator, sme_offset: float, bound: bool) -> dict:
    from cooploc.reproduce import zhang2016 as z

    runs = 20
    base = 1.75 + 0.05 * rng.standard_normal(runs)          # common random numbers: paired runs
    data = {"runs": runs, "seed": 0, "quick": False, "compared": list(z.COMPARED)}
    for s, factor in zip(z.SCENARIOS, (1.0, 1.02, 1.5), strict=True):
        totals = {"kf-known-da": base, "gm-phd": base + 0.1,
                  "sme-pf": factor * (base + sme_offset + 0.005 * rng.standard_normal(runs)),
                  "sme-ukf": base + 0.2, z.BOUND: 0.5 * base if bound else [],
                  z.AXES_LABEL: 3 * base, z.AXES_UKF_LABEL: 9 * base, z.BOOTSTRAP_LABEL: base + 0.4,
                  z.NO_TOPOLOGY_LABEL: base + 0.3 if s == z.SCENARIOS[0] else []}
        data[s] = {"per_run_total": {k: list(np.asarray(v, dtype=float)) for k, v in totals.items()},
                   "information": {"kf": 1.75, "kf_topology": 1.68, "gain": 0.04,
                                   "kf_per_step": [3.06] * 10, "kf_topology_per_step": [2.82] * 10},
                   "separated": [True] * 10, "per_run_separated": {}, "per_step": {}, "ospa": {}}
    return data


def test_claims_follow_fabricated_numbers(rng: np.random.Generator) -> None:
    from cooploc.reproduce.claims import NOT_CHECKED, NOT_REPRODUCED, REPRODUCED
    from cooploc.reproduce.zhang2016 import claims, report

    better = {c.statement: c.outcome for c in claims(_fabricated(rng, -0.05, bound=True))}
    assert better["SME better than the Kalman filter (Figs. 2–3, CV)"] == REPRODUCED
    assert better["SME better than the PHD filter (Fig. 3, CT4)"] == NOT_REPRODUCED      # ×1.5 in CT-4
    assert better["the Kalman filter better than the PHD filter (§4.1, CT2)"] == REPRODUCED
    assert better["SME in CT-2 almost the same as in CV (Fig. 3)"] == REPRODUCED
    assert better["SME in CT-4 degrades a lot against CV (Fig. 3)"] == REPRODUCED
    assert better["the high performance of SME is mainly from the topology (§4.1)"] == REPRODUCED
    assert better["sums of powers per axis (eq. 17) lose no information (§3.2.3)"] == NOT_REPRODUCED
    assert better["SME does not reach what the radar gives with its transformation known (§4.1, CV)"] == \
        REPRODUCED
    worse = {c.statement: c.outcome for c in claims(_fabricated(rng, +0.05, bound=False))}
    assert worse["SME better than the Kalman filter (Figs. 2–3, CV)"] == NOT_REPRODUCED
    assert worse["SME does not reach what the radar gives with its transformation known (§4.1, CV)"] == \
        NOT_CHECKED
    text = "\n".join(report(_fabricated(rng, +0.05, bound=False)))
    assert "not significantly below" in text and "significantly below kf-known-da" not in text.replace(
        "not significantly below kf-known-da", "")


def _with_analysis(data: dict, rng: np.random.Generator, mht_offset: float, pf_offset: float,
                   few_offset: float, exact_gain: float = 0.1) -> dict:
    """`data` with the MHT's totals, sme-pf's, and in CT-4 the 2000-particle sme-pf's, offset
    from kf-known-da's per run (and the split into separated and close steps)."""
    from cooploc.reproduce import zhang2016 as z

    for s in z.SCENARIOS:
        kf = np.asarray(data[s]["per_run_total"]["kf-known-da"])

        def noise(size: int = kf.size) -> np.ndarray:   # paired run-to-run scatter
            return 0.003 * rng.standard_normal(size)

        totals = data[s]["per_run_total"]
        totals["sme-pf"] = list(kf + pf_offset + noise())
        totals[z.HYPOTHESES_LABEL] = list(kf + mht_offset + noise())
        totals[z.ANONYMOUS_LABEL] = list(kf + 0.005 + noise())
        few = kf + pf_offset + few_offset + noise()
        totals[z.PARTICLES_LABEL] = list(few) if s == z.SCENARIOS[-1] else []
        totals[z.EXACT_LABEL] = list(kf + pf_offset - exact_gain + noise())
        data[s]["separated"] = [True] * 8 + [False] * 2
        data[s]["per_run_separated"] = {"sme-pf": list(kf - 0.04 + noise()), "kf-known-da": list(kf)}
        data[s]["per_run_close"] = {"sme-pf": list(kf + 0.2 + noise()), "kf-known-da": list(kf),
                                    z.HYPOTHESES_LABEL: list(kf - 0.05 + noise())}
    return data


def test_analysis_of_the_gap_follows_fabricated_numbers(rng: np.random.Generator) -> None:
    from cooploc.reproduce.claims import NOT_REPRODUCED, REPRODUCED
    from cooploc.reproduce.zhang2016 import analysis_checks, report

    # ours: the information allows −0.07 m, sme-pf trails by +0.03 m, 4× fewer particles cost +0.12 m
    ours = _with_analysis(_fabricated(rng, 0.0, bound=True), rng, -0.07, +0.03, +0.12)
    checks = {c.statement: c.outcome for c in analysis_checks(ours)}
    information = "SME's information (anonymous rows + T) allows beating the Kalman filter (CT4)"
    assert checks[information] == REPRODUCED
    assert checks["sme-pf reaches what its information allows (CT4)"] == NOT_REPRODUCED
    assert checks["sme-pf's particle approximation has converged (CT4)"] == NOT_REPRODUCED
    assert checks["where some pair of vehicles is < 10 m apart, SME beats the Kalman filter (CT4)"] == \
        NOT_REPRODUCED
    assert checks["where every pair of vehicles is ≥ 10 m apart, SME beats the Kalman filter (CT4)"] == \
        REPRODUCED
    text = "\n".join(report(ours))
    assert "beats `kf-known-da` significantly in CV, CT2, CT4:" in text
    assert "does not reach the MHT within 3% in CV, CT2, CT4" in text
    assert "has not converged, so part of the gap is ours" in text
    exact = "the exact density of the sums of powers improves on eq. (19)'s Gaussian pseudo-noise (CT4)"
    assert checks[exact] == REPRODUCED    # and it closes the gap to the MHT that the Gaussian leaves
    assert checks["with the exact density sme-pf reaches what its information allows (CT4)"] == REPRODUCED
    assert "With the exact density of the sums of powers in place of eq. (19)'s Gaussian" in text
    # the method: the information allows nothing, sme-pf reaches it, the particle count has converged
    method = _with_analysis(_fabricated(rng, 0.0, bound=True), rng, 0.0, +0.002, 0.0, exact_gain=-0.01)
    checks = {c.statement: c.outcome for c in analysis_checks(method)}
    assert checks[exact] == NOT_REPRODUCED
    assert checks[information] == NOT_REPRODUCED
    assert checks["sme-pf reaches what its information allows (CT4)"] == REPRODUCED
    assert checks["sme-pf's particle approximation has converged (CT4)"] == REPRODUCED
    text = "\n".join(report(method))
    assert "no filter here beats `kf-known-da` significantly" in text
    assert "reaches the MHT within 3% everywhere" in text
    assert "the particle count has converged" in text
