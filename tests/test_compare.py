"""`cooploc compare` (issue 14, item 3): the method × scenario table end to end, which
estimators apply to a scenario, the scenarios' declared bounds, one-line errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import cooploc.results
from cooploc.cli import app
from cooploc.compare import default_presets, plan
from cooploc.errors import ConfigError
from cooploc.experiment import run_generators
from cooploc.registry import construct, estimators, get_estimator, get_preset, presets, unused_kinds

runner = CliRunner()
SMALL = ["--set", "n_steps=8", "--runs", "3", "--seed", "2", "--backend", "serial", "--no-progress"]
NAMES = ["gnss-kf", "oracle-kf", "icp", "plbp"]


def _strict(text: str) -> dict:
    def refuse(constant: str) -> None:
        raise AssertionError(f"not strict JSON: {constant}")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare") / "out"
    args = ["compare", "-s", "froehle2018", "-s", "brambilla-road", *(a for n in NAMES for a in ("-e", n)),
            *SMALL, "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return out


def test_writes_the_tables_the_heat_map_and_a_results_folder_per_scenario(compared):
    for preset in ("froehle2018", "brambilla-road"):
        summary = _strict((compared / preset / "summary.json").read_text())
        assert summary["runs"] == 3 and summary["complete"]
    assert (compared / "compare.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = _strict((compared / "compare.json").read_text())
    assert [t["scenario"] for t in data["scenarios"]] == ["froehle2018", "brambilla-road"]
    for t in data["scenarios"]:
        assert list(t["estimators"]) == NAMES and t["bound"] == "oracle-kf"
    text = (compared / "compare.md").read_text()
    assert "## froehle2018" in text and "## brambilla-road" in text
    assert text.count("| `gnss-kf` |") == 4  # the two overviews and the two scenario tables
    assert "| `icp` | n/a |" in text and "| *bound* | oracle-kf | oracle-kf |" in text


def test_refused_estimators_are_listed_with_the_reason_never_a_number(compared):
    data = _strict((compared / "compare.json").read_text())
    froehle, road = data["scenarios"]
    assert set(froehle["estimators"]["icp"]) == {"refused"}
    assert "full relative state" in froehle["estimators"]["icp"]["refused"]
    assert "needs the measurement kinds aoa" in road["estimators"]["plbp"]["refused"]
    assert road["estimators"]["icp"]["vehicle_rmse"] > 0  # runs where its sensors are
    summary = _strict((compared / "froehle2018" / "summary.json").read_text())
    assert set(summary["estimators"]) == {"gnss-kf", "oracle-kf"}  # refused ones never ran
    rows = [line for line in (compared / "compare.md").read_text().splitlines()
            if line.startswith("| `icp` | not run |")]
    assert len(rows) == 1 and "full relative state" in rows[0]  # froehle2018's table


def test_ratios_and_interval_come_from_the_scenario_summaries(compared):
    data = _strict((compared / "compare.json").read_text())
    road = data["scenarios"][1]
    summary = _strict((compared / "brambilla-road" / "summary.json").read_text())
    icp = summary["estimators"]["icp"]["vehicle_rmse_all"]
    row = road["estimators"]["icp"]
    assert row["vehicle_rmse"] == icp
    assert row["association_accuracy_per_step"] is None   # known association: nothing decided
    assert row["ratio_bound"] == pytest.approx(icp / summary["estimators"]["oracle-kf"]["vehicle_rmse_all"])
    assert row["ratio_gnss_kf"] == pytest.approx(icp / summary["estimators"]["gnss-kf"]["vehicle_rmse_all"])
    assert road["estimators"]["oracle-kf"]["ratio_bound"] == 1.0
    low, high = row["interval_90"]
    per_run = np.array(list(summary["estimators"]["icp"]["per_run_vehicle_rmse"].values()))
    assert per_run.min() <= low <= high <= per_run.max()  # pooled over resampled runs
    assert f"| `icp` | {icp:.2f} |" in (compared / "compare.md").read_text()


def test_each_method_is_also_measured_against_the_bound_of_its_own_sensors(compared):
    road = _strict((compared / "compare.json").read_text())["scenarios"][1]["estimators"]
    assert road["icp"]["own_bound"] == "oracle-kf"                      # GNSS + V2F
    assert road["icp"]["ratio_own_bound"] == pytest.approx(road["icp"]["ratio_bound"])
    # gnss-kf's own bound, kf-known-da (GNSS alone), was not compared: no number, the reason
    assert road["gnss-kf"]["own_bound"] == "kf-known-da" and road["gnss-kf"]["ratio_own_bound"] is None
    assert "kf-known-da was not among the estimators compared" in road["gnss-kf"]["own_bound_note"]
    text = (compared / "compare.md").read_text()
    assert f"({road['icp']['ratio_own_bound']:.2f}× oracle-kf)" in text
    assert "| `gnss-kf` | kf-known-da |" not in text and "no own-bound ratio: kf-known-da" in text


def test_numbers_equal_those_of_cooploc_run(compared, tmp_path):
    result = runner.invoke(app, ["run", "brambilla-road", "-e", "icp", *SMALL, "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    alone = _strict((tmp_path / "summary.json").read_text())["estimators"]["icp"]["vehicle_rmse_all"]
    compared_icp = _strict((compared / "brambilla-road" / "summary.json").read_text())
    assert compared_icp["estimators"]["icp"]["vehicle_rmse_all"] == alone


def test_applicability_is_decided_by_construct_on_run_0s_setup():
    [p] = plan(["zhang2016-cv"], ["gnss-kf", "kf-known-da"], scenario_overrides={"n_steps": 3}, runs=2,
               seed=5, backend="serial")
    assert [e.name for e in p.config.estimators] == ["kf-known-da"]
    scenario_rng, rngs = run_generators(5, 0, ["gnss-kf"])
    recording = get_preset("zhang2016-cv").generate(scenario_rng, p.config.scenario_params)
    with pytest.raises(ConfigError) as refused:
        construct(get_estimator("gnss-kf"), recording.setup, None, rngs["gnss-kf"])
    assert p.refused == {"gnss-kf": str(refused.value)}
    [nothing] = plan(["aoa-grid"], ["gnss-kf"], backend="serial")
    assert nothing.config is None and "can use nothing" in nothing.refused["gnss-kf"]


def test_a_scenario_where_nothing_runs_is_still_a_table(tmp_path):
    result = runner.invoke(app, ["compare", "-s", "aoa-grid", "-e", "gnss-kf", "--runs", "1",
                                 "--backend", "serial", "--no-progress", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    [t] = _strict((tmp_path / "compare.json").read_text())["scenarios"]
    assert t["results"] is None and t["bound"] is None and "refused" in t["estimators"]["gnss-kf"]
    assert not (tmp_path / "aoa-grid").exists()
    assert "no estimator can run here" in (tmp_path / "compare.md").read_text()


def test_presets_declare_their_bound():
    bounds = {name: p.bound for name, p in presets().items()}
    assert bounds["froehle2018"] == bounds["brambilla-road"] == bounds["brambilla-crossroad"] == "oracle-kf"
    assert {bounds[f"zhang2016-{v}"] for v in ("cv", "ct2", "ct4")} == {"oracle-pose"}
    assert {bounds[f"gulati-{n}v"] for n in (2, 3, 4)} == {"oracle-pose-smoother"}
    assert all(b == "oracle-kf" for n, b in bounds.items() if n.startswith("sumo-"))
    assert all(bounds[n] is None for n in ("aoa-grid", "aoa-grid-tracking"))
    assert all(b is None or b in estimators() for b in bounds.values())
    for name in ("froehle2018", "brambilla-road", "brambilla-crossroad", "zhang2016-cv", "gulati-2v"):
        preset = get_preset(name)  # it runs there
        recording = preset.generate(np.random.default_rng(0), preset.params.with_overrides({"n_steps": 3}))
        rng = np.random.default_rng(1)
        construct(get_estimator(preset.bound), recording.setup, None, rng, recording.truth)
    # the radar-pose bounds use every sensor of their scenarios; oracle-kf would leave the
    # radar aside (it fuses the odometry), so it bounds nothing there
    for name in ("zhang2016-cv", "gulati-2v"):
        preset = get_preset(name)
        recording = preset.generate(np.random.default_rng(0), preset.params.with_overrides({"n_steps": 3}))
        assert unused_kinds(get_estimator(preset.bound), recording.setup) == ()
    assert unused_kinds(get_estimator("oracle-kf"), recording.setup) == ("radar",)


def test_default_presets_leave_out_the_sumo_cities():
    names = default_presets()
    assert "froehle2018" in names and "gulati-2v" in names
    assert not any(n.startswith("sumo-") for n in names)


@pytest.fixture
def no_runs(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("an experiment ran")
    monkeypatch.setattr(cooploc.results, "run_to_folder", refuse)


@pytest.mark.parametrize(("args", "parts"), [
    (["-s", "nowhere"], ["unknown scenario 'nowhere'", "froehle2018"]),
    (["-s", "froehle2018", "-e", "nobody"], ["unknown estimator 'nobody'", "gnss-kf"]),
    (["-s", "froehle2018", "-s", "froehle2018"], ["'froehle2018' is listed twice"]),
    (["-s", "froehle2018", "--set", "n_stepz=3"], ["n_stepz"]),
])
def test_mistakes_are_one_line_before_any_run(no_runs, tmp_path, args, parts):
    result = runner.invoke(app, ["compare", *args, "--backend", "serial", "--out", str(tmp_path / "x")])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    for part in parts:
        assert part in result.output
    assert not (tmp_path / "x").exists()


def _row(rmse: float, unused: list[str], own: str | None, ratio: float | None, **extra) -> dict:
    return {"vehicle_rmse": rmse, "interval_90": [rmse, rmse], "association_accuracy": None,
            "association_accuracy_per_step": None, "steps_per_second": 1.0, "failed_runs": 0,
            "unused_kinds": unused, "ratio_gnss_kf": rmse / 3.0, "ratio_bound": rmse / 1.5,
            "own_bound": own, "ratio_own_bound": ratio, **extra}


def test_a_bound_that_leaves_aside_a_kind_the_method_reads_is_flagged():
    from cooploc.compare import _kinds_beyond, markdown
    rows = {"gnss-kf": _row(3.0, ["v2f"], "kf-known-da", None),
            "oracle-kf": _row(1.5, ["odometry"], "oracle-kf", 1.0),
            "rsu-bp": _row(1.45, [], "oracle-kf", 1.45 / 1.5),
            "plbp": _row(2.5, ["odometry", "v2f"], None, None)}
    assert _kinds_beyond(rows, "rsu-bp", "oracle-kf") == ["odometry"]
    assert _kinds_beyond(rows, "plbp", "oracle-kf") == []            # reads no more than the bound
    assert _kinds_beyond(rows, "oracle-kf", "oracle-kf") == []
    assert _kinds_beyond(rows, "rsu-bp", None) == [] and _kinds_beyond(rows, "rsu-bp", "icp") == []
    rows["rsu-bp"].update(beyond_bound=["odometry"], beyond_own_bound=["odometry"])
    data = {"interval_90": "x", "scenarios": [{"scenario": "s", "bound": "oracle-kf", "runs": 1, "seed": 0,
                                               "results": "s", "no_ratio": {}, "estimators": rows}]}
    text = markdown(data)
    assert "1.45 m (0.97× oracle-kf†)" in text and "1.50 m (1.00× oracle-kf)" in text
    # one note per bound, even when the scenario's bound and the method's own are the same
    note = "uses odometry, which oracle-kf leaves aside: oracle-kf is not a bound for it here"
    assert text.count(note) == 1
