"""The claims of `reproduce brambilla2020` and `reproduce sumo` on fabricated data: each
verdict follows the numbers, and a missing estimator leaves a claim not checked."""

from __future__ import annotations

from typing import Any

import numpy as np

from cooploc.reproduce import brambilla2020_claims as bc
from cooploc.reproduce import sumo
from cooploc.reproduce.claims import NOT_CHECKED, NOT_REPRODUCED, REPRODUCED, Claim

RUNS = 20


def _point(rmse: dict[str, float], shares: dict[str, float] | None = None, discarded: float = 0.0,
           feature_factor: dict[str, float] | None = None, seed: int = 0) -> dict[str, Any]:
    """A setting whose per-run RMSEs scatter ±2 % (common to all estimators, as paired runs
    do) around `rmse`, with per-step association shares around `shares`."""
    rng = np.random.default_rng(seed)
    common = 1.0 + 0.02 * rng.standard_normal(RUNS)
    own = 1.0 + 0.002 * rng.standard_normal((len(rmse), RUNS))
    point: dict[str, Any] = {"rmse": dict(rmse), "feature_rmse": {}, "nees": {}, "per_run": {},
                             "association": {}}
    for (label, value), noise in zip(rmse.items(), own, strict=True):
        vehicle = value * common * noise
        feature = vehicle * (feature_factor or {}).get(label, 1.0)
        point["per_run"][label] = {"vehicle": vehicle.tolist(), "feature": feature.tolist()}
    for label, share in (shares or {}).items():
        per_run = np.clip(share + 0.005 * rng.standard_normal(RUNS), 0, 1)
        point["association"][label] = {"per_step": share, "track": share, "discarded": discarded,
                                       "per_step_per_run": per_run.tolist()}
    return point


def _paper_like() -> dict[str, Any]:
    """Numbers as the paper describes them."""
    lc, one, pf, icp, gnss = bc.LC, bc.ETA_ONE, bc.PF, bc.ICP, bc.GNSS
    road = {
        bc.spacing_key(0.5): _point({gnss: 6, pf: 5, one: 5, icp: 5}, {one: 0.54}),
        bc.spacing_key(3.0): _point({gnss: 6, pf: 5.3, one: 5.5, icp: 5}, {one: 0.92},
                                    feature_factor={one: 1.5}),
        bc.spacing_key(6.0): _point({gnss: 6, pf: 5, one: 5, icp: 5}, {one: 0.99}),
    }
    static = {}
    for i, (nf, eta_one_rmse, share_one, share, discarded) in enumerate(
            [(3, 4.0, 0.99, 0.99, 0.0), (10, 3.5, 0.97, 0.98, 0.01), (20, 3.3, 0.9, 0.95, 0.03),
             (60, 5.5, 0.6, 0.9, 0.1)]):
        known = 3.3 if nf >= 20 else 5 - 0.17 * nf
        point = _point({gnss: 5, lc: known, one: eta_one_rmse, icp: known}, {one: share_one}, seed=i)
        point["rmse"][one] = point["rmse"][lc] if nf < 60 else eta_one_rmse
        point["per_run"][one] = point["per_run"][lc] if nf < 60 else point["per_run"][one]
        point["association"][lc] = {"per_step": share, "track": share, "discarded": discarded,
                                    "per_step_per_run": [share] * RUNS}
        point["sensed_per_vehicle"] = 4.2
        static[str(nf)] = point
    moving = {f"{v:g}": _point({gnss: 5, lc: 3.3 + 0.1 * v, icp: 3.3}, {lc: 0.95 - 0.02 * v},
                               discarded=0.01 * v, seed=10 + i) for i, v in enumerate((1.0, 2.0, 5.0))}
    return {"road": road, "crossroad_features": static, "crossroad_speed": moving}


def _by_statement(claims: list[Claim]) -> dict[str, Claim]:
    return {c.statement: c for c in claims}


def test_numbers_as_the_paper_describes_them_reproduce_every_claim() -> None:
    claims = bc.claims(_paper_like())
    failed = [(c.statement, c.verdict.ours, c.verdict.test) for c in claims if c.outcome != REPRODUCED]
    assert not failed
    assert len(claims) == 30


def test_each_verdict_follows_its_numbers() -> None:
    data = _paper_like()
    key = bc.spacing_key(0.5)
    for entry in data["road"][key]["association"].values():
        entry["per_step_per_run"] = (np.array(entry["per_step_per_run"]) + 0.2).tolist()   # 74 %, not 54 %
    three = data["road"][bc.spacing_key(3.0)]["per_run"]
    three[bc.PF], three[bc.ETA_ONE] = three[bc.ETA_ONE], three[bc.PF]                   # LC better than PF
    static = data["crossroad_features"]
    static["60"]["association"][bc.ETA_ONE]["per_step"] = 0.999                        # no fall at η = 1
    claims = _by_statement(bc.claims(data))
    share = claims["§V-A: ICP-DA-LC (η_TH = 1) pairs a measurement with its true feature, d_f = 0.5 m"]
    assert share.outcome == NOT_REPRODUCED and "interval outside" in share.verdict.test
    pf = claims["Fig. 7b: at d_f = 3 m the PF implementation is slightly better than LC"]
    assert pf.outcome == NOT_REPRODUCED and "reversed" in pf.verdict.test
    fall = claims["Fig. 9: the probability of correct association falls as N_f grows (η_TH = 1)"]
    assert fall.outcome == NOT_REPRODUCED
    assert claims["Fig. 9: ... and with selection (η_TH = 0.5)"].outcome == REPRODUCED


def test_an_estimator_that_did_not_run_leaves_its_claims_not_checked() -> None:
    data = _paper_like()
    for point in data["road"].values():
        for part in ("rmse", "per_run", "association"):
            point[part].pop(bc.PF, None)
    claims = bc.claims(data)
    unchecked = [c for c in claims if c.outcome == NOT_CHECKED]
    assert len(unchecked) == 4 and all(bc.PF in c.quantity for c in unchecked)


def test_recursion_lines_count_the_settings_from_the_paired_intervals() -> None:
    data = _paper_like()
    settings = ((data["road"][bc.spacing_key(0.5)], 7.0), (data["road"][bc.spacing_key(3.0)], 5.0),
                (data["crossroad_features"]["20"], 3.0))
    for point, recursion in settings:
        base = np.array(point["per_run"][bc.ICP]["vehicle"])
        point["rmse"][bc.RECURSION] = recursion
        point["per_run"][bc.RECURSION] = {"vehicle": (base * recursion / point["rmse"][bc.ICP]).tolist()}
    text = "\n".join(bc.recursion_lines(data))
    assert "Of 3 settings" in text and "lower vehicle RMSE in 1, the recursion in 1, and neither in 1" in text


# ----------------------------------------------------------------------------
# reproduce sumo
# ----------------------------------------------------------------------------


def _sumo_data(lc_tlr: float = 0.8, lc_vsr: float = 1.5) -> dict[str, Any]:
    def overall(position: float, velocity: float, feature: float | None = None) -> dict[str, Any]:
        return {"position": position, "velocity": velocity, "feature": feature}

    data: dict[str, Any] = {
        "vehicles_in_network": {"tlr": [40.0, 35.0], "vsr": [20.0, 18.0]},
        "overall": {"gnss-kf": {"tlr": overall(4.0, 0.3), "vsr": overall(3.5, 0.4)},
                    "icp-da-lc": {"tlr": overall(lc_tlr, 0.1, 0.9), "vsr": overall(lc_vsr, 0.2, 1.6)}},
        "fig16": {"gnss-kf": {r: {"position": [4.0, 3.9]} for r in ("tlr", "vsr")},
                  "icp-da-lc": {"tlr": {"position": [lc_tlr, lc_tlr]}, "vsr": {"position": [lc_vsr, 1.4]}}},
        "fig17": {"gnss-kf": {"C": {"p95": 5.3}}, "icp-da-lc": {"C": {"p95": 1.1}}},
    }
    return data


def test_sumo_claims_follow_the_numbers() -> None:
    claims = sumo.claims(_sumo_data())
    assert len(claims) == 11 and all(c.outcome == REPRODUCED for c in claims), [
        (c.statement, c.verdict.test) for c in claims if c.outcome != REPRODUCED]
    worse = _by_statement(sumo.claims(_sumo_data(lc_tlr=3.0)))
    assert worse["§VI-B: ICP-DA-LC reaches sub-metre accuracy (TLR)"].outcome == NOT_REPRODUCED
    gain = "Fig. 16a: the improvement over GNSS is far larger in TLR than in VSR"
    assert worse[gain].outcome == NOT_REPRODUCED


def test_sumo_claims_without_the_method_are_not_checked() -> None:
    data = _sumo_data()
    for part in ("overall", "fig16", "fig17"):
        data[part].pop("icp-da-lc")
    outcomes = [c.outcome for c in sumo.claims(data)]
    # the four claims on GNSS and traffic alone are still checked
    assert outcomes.count(NOT_CHECKED) == 7 and outcomes.count(REPRODUCED) == 4
