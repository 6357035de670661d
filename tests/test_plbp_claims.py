"""The PLBP claims (`cooploc.reproduce.plbp_claims`) on fabricated numbers.

A scene's data that shows every behaviour the paper describes reproduces every claim;
each fabricated departure (no convergence, prior linearization as good as posterior,
too few vehicles within the target, a curved σ²_θ response, a costly σ_p, plbp far
from the MAP reference, a narrow field of view) turns exactly the claims that state it
into "not reproduced", and the report's sentences follow the verdicts.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from cooploc.reproduce.claims import NOT_REPRODUCED, REPRODUCED
from cooploc.reproduce.plbp import FOV_SWEEP, SWEEPS
from cooploc.reproduce.plbp_claims import claims, field_of_view_sentence, reference_sentence, scene_claims

SNAPSHOTS = 20


def _good() -> dict[str, Any]:
    """One scene's data.json part in which the paper's statements all hold."""
    rng = np.random.default_rng(0)
    noise = 0.05 * rng.standard_normal(SNAPSHOTS)
    pos = [7.0, 3.0, 2.0, 1.6, 1.52, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5]
    heading = [0.35, 0.15, 0.09, 0.07, 0.061, 0.06, 0.06, 0.06, 0.06, 0.06, 0.06]

    def sweep(key: str, pos_curve: list[float], head_curve: list[float]) -> dict[str, Any]:
        values = list(SWEEPS[key][1])
        curve = {"pos": pos_curve, "heading": head_curve, "within": [0.97] * len(values),
                 "within_per_run": [[0.97] * 4] * len(values)}
        return {"values": values, "curves": {"plbp": curve, "prior-lbp": curve}}

    var = np.array(SWEEPS["aoa_variance"][1])
    return {
        "scenario_params": {"aoa_variance": 0.1, "field_of_view": np.pi / 2},
        "fig4": {"plbp/L3": {"pos": pos, "heading": heading},
                 "prior-lbp/L3": {"pos": [p * 1.5 for p in pos], "heading": [h * 1.5 for h in heading]}},
        "per_snapshot": {
            "plbp/pos": list(1.5 + noise), "plbp/heading": list(0.06 + noise / 50),
            "prior-lbp/pos": list(2.5 + noise), "prior-lbp/heading": list(0.09 + noise / 50),
            "map/pos": list(1.5 + noise * 0.9), "map/heading": list(0.06 + noise / 55),
            "plbp/within_J3": [0.97] * SNAPSHOTS, "plbp/within_J5": [0.97] * SNAPSHOTS,
        },
        "fig6": {
            "communication_radius": sweep("communication_radius", [4.0, 2.5, 1.5, 1.3, 1.2],
                                          [0.2, 0.1, 0.06, 0.05, 0.05]),
            "aoa_variance": sweep("aoa_variance", list(1.0 + 5 * var), list(0.02 + 0.4 * var)),
            "prior_position_std": sweep("prior_position_std", [1.0, 1.2, 1.5, 2.0, 3.0, 4.0],
                                        [0.05, 0.055, 0.06, 0.07, 0.08, 0.09]),
            "prior_heading_std": sweep("prior_heading_std", [1.0, 1.1, 1.3, 1.5, 1.8, 2.2],
                                       [0.02, 0.03, 0.05, 0.06, 0.08, 0.1]),
        },
        "field_of_view": {"values": list(FOV_SWEEP),
                          "curves": {"plbp": {"within_per_run": [[0.97, 0.96, 0.98]] * len(FOV_SWEEP)}}},
    }


def _outcomes(d: dict[str, Any]) -> dict[str, str]:
    found = scene_claims("scene", d)
    return {c.statement: c.outcome for c in found.all()}


def test_every_claim_holds_on_data_that_shows_it() -> None:
    outcomes = _outcomes(_good())
    assert len(outcomes) == 17 + 2 + len(FOV_SWEEP)
    assert set(outcomes.values()) == {REPRODUCED}, {k: v for k, v in outcomes.items() if v != REPRODUCED}


def _set(d: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    """A copy of `d` with d[path[0]][path[1]]… replaced by `value`."""
    d = copy.deepcopy(d)
    *keys, last = path
    target = d
    for k in keys:
        target = target[k]
    target[last] = value
    return d


@pytest.mark.parametrize(("path", "value", "failing"), [
    # still falling beyond J = 4: not converged (position only)
    (("fig4", "plbp/L3", "pos"), [7.0, 3.0, 2.0, 1.8, 1.7, 1.6, 1.5, 1.4, 1.3, 1.2, 1.1],
     {"Fig. 4: position RMSE converges for J ≥ 4"}),
    # J = 1 → 3 gives nothing
    (("fig4", "plbp/L3", "heading"), [0.35, 0.061, 0.06, 0.06, 0.06, 0.06, 0.06, 0.06, 0.06, 0.06, 0.06],
     {"Fig. 4: J = 1 → 3 improves the heading RMSE significantly"}),
    # prior linearization as good as posterior: the paired interval contains 0
    (("per_snapshot", "prior-lbp/pos"),
     list(1.5 + 0.05 * np.random.default_rng(1).standard_normal(SNAPSHOTS)),
     {"Fig. 4: posterior linearization clearly beats prior linearization (position)"}),
    # J = 3 clearly worse than J = 5
    (("per_snapshot", "plbp/within_J3"), [0.90] * SNAPSHOTS, {"Fig. 5: J = 3 performs like J = 5"}),
    # R_c = 20 m worse than 10 m
    (("fig6", "communication_radius", "curves", "plbp", "heading"), [0.1, 0.2, 0.06, 0.05, 0.05],
     {"Fig. 6: heading RMSE falls rapidly from R_c = 10 to 30 m"}),
    # a saturating response to σ²_θ
    (("fig6", "aoa_variance", "curves", "plbp", "pos"), [1.0, 2.0, 2.4, 2.5, 2.5],
     {"Fig. 6: position RMSE grows about linearly in σ²_θ"}),
    # σ_p 0.5 → 10 m costs 3 m; worse than the prior above 10 m
    (("fig6", "prior_position_std", "curves", "plbp", "pos"), [1.0, 1.5, 2.0, 4.0, 22.0, 30.0],
     {"Fig. 6: σ_p 0 → 10 m costs less than 2 m (position)",
      "Fig. 6: for σ_p > 10 m still better than the prior"}),
    # σ_α changes nothing
    (("fig6", "prior_heading_std", "curves", "plbp", "pos"), [1.0] * 6,
     {"Fig. 6: position RMSE rises rapidly with σ_α"}),
])
def test_each_departure_fails_its_claims(path: tuple[str, ...], value: Any, failing: set[str]) -> None:
    outcomes = _outcomes(_set(_good(), path, value))
    assert {k for k, v in outcomes.items() if v == NOT_REPRODUCED} == failing


def test_nearly_all_the_reference_and_their_sentences() -> None:
    d = _set(_good(), ("per_snapshot", "plbp/within_J5"), [0.90] * SNAPSHOTS)
    d = _set(d, ("per_snapshot", "plbp/within_J3"), [0.90] * SNAPSHOTS)
    found = scene_claims("scene", d)
    assert found.nearly_all.outcome == NOT_REPRODUCED
    assert all(c.outcome == REPRODUCED for c in found.reference)
    text = reference_sentence(found, 4.0, d["scenario_params"])
    assert "as accurate as the centralized optimum" in text and "information in this scene" in text
    assert "≈ 17 rows" in text and "gives 4.0" in text            # (1.96 √0.1 / 0.15)² = 17.1
    # plbp 30 % worse than the MAP estimate in position: the sentence says so
    worse = _set(d, ("per_snapshot", "plbp/pos"), list(np.multiply(d["per_snapshot"]["map/pos"], 1.3)))
    found = scene_claims("scene", worse)
    assert [c.outcome for c in found.reference] == [NOT_REPRODUCED, REPRODUCED]
    text = reference_sentence(found, 4.0, d["scenario_params"])
    assert text.startswith("In position `plbp` is less accurate than the centralized optimum "
                           "(mean ratio 1.3)")


def test_the_field_of_view_sentence_follows_the_verdicts() -> None:
    d = _good()
    assert "for every field of view of the sweep (45°, 60°, 75°, 90°)" in field_of_view_sentence(
        "scene", scene_claims("scene", d))
    shares = [[0.80, 0.85], [0.90, 0.92], [0.96, 0.97], [0.97, 0.99]]
    d = _set(d, ("field_of_view", "curves", "plbp", "within_per_run"), shares)
    sentence = field_of_view_sentence("scene", scene_claims("scene", d))
    assert sentence.endswith("holds on `scene` for Δ = 75°, 90°, not for Δ = 45°, 60°.")
    d = _set(d, ("field_of_view", "curves", "plbp", "within_per_run"), [[0.5, 0.6]] * 4)
    assert "for none of the fields of view" in field_of_view_sentence("scene", scene_claims("scene", d))


def test_claims_cover_every_scene() -> None:
    data = {"scenes": {"a": _good(), "b": _good()}}
    records = claims(data)
    assert len(records) == 2 * (17 + 2 + len(FOV_SWEEP))
    assert records[0].quantity.startswith("a: ") and records[-1].quantity.startswith("b: ")
