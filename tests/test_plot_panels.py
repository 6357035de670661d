"""Which vehicles get a panel or a table column when there are many (`plots.shown_ids`): on
aoa-grid the first six ids are the anchors, so the first ones alone would hide the rest."""

from __future__ import annotations

from cooploc.plots import MAX_PANELS, run_report, shown_ids


def test_few_vehicles_are_all_shown():
    assert shown_ids(range(MAX_PANELS)) == list(range(MAX_PANELS))


def test_many_vehicles_are_sampled_from_first_to_last():
    assert shown_ids(range(51)) == [0, 10, 20, 30, 40, 50]   # aoa-grid: anchors are 0–5
    assert shown_ids([str(i) for i in range(51)])[1:] == ["10", "20", "30", "40", "50"]


def test_the_report_of_a_grid_run_shows_vehicles_beyond_the_anchors():
    rmse = {str(i): 0.1 if i < 6 else 5.0 for i in range(51)}
    summary = {"scenario": "aoa-grid-tracking", "runs": 1, "seed": 0, "cooploc_version": "0",
               "estimators": {"plbp": {"vehicle_rmse": rmse, "vehicle_rmse_all": 4.7,
                                       "feature_rmse_all": None, "steps_per_second": 10.0}}}
    text = run_report(summary, [])
    header = next(line for line in text.splitlines() if line.startswith("| estimator"))
    assert "vehicle 50 [m]" in header and "vehicle 5 [m]" not in header
