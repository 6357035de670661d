"""`cooploc view`: the kept estimates, the regenerated run, the per-frame data, the Plotly
figure, the HTML file, the size limits, the animation and the command line.

Everything runs on tiny results folders (a dozen steps, serial backend); the page is
checked here from the Python figure object and the written file, and in a real browser
by ``tests/integration/test_view_browser.py``.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from cooploc.cli import app
from cooploc.errors import CooplocError, InvalidInputError
from cooploc.experiment import ExperimentConfig, run_experiment, run_one, run_recording
from cooploc.metrics import evaluate
from cooploc.results import write_results
from cooploc.view import estimates as kept
from cooploc.view import frames as frames_module
from cooploc.view import write_animation, write_view
from cooploc.view.data import load_run
from cooploc.view.figure import build_figure
from cooploc.view.frames import ellipses, frame_data
from cooploc.view.scene import scene

pytest.importorskip("plotly")
runner = CliRunner()


def _results(tmp_path_factory, scenario, estimators, runs=2, **overrides):
    cfg = ExperimentConfig.build(scenario, estimators, scenario_overrides=overrides, runs=runs, seed=3,
                                 backend="serial")
    folder = tmp_path_factory.mktemp(scenario)
    write_results(run_experiment(cfg), folder)
    return folder


@pytest.fixture(scope="module")
def froehle(tmp_path_factory):
    return _results(tmp_path_factory, "froehle2018", ["gnss-kf", "oracle-kf"], n_steps=12)


@pytest.fixture(scope="module")
def road(tmp_path_factory):
    """Brambilla's road: V2V links, a road, and an estimator that decides associations."""
    return _results(tmp_path_factory, "brambilla-road", ["icp-da-lc"], runs=1)


def _errors(folder, run):
    import pyarrow.parquet as pq

    rows = pq.read_table(folder / "errors.parquet").to_pylist()
    return {(r["estimator"], r["step"], r["kind"], r["id"]): r["err_pos"] for r in rows if r["run"] == run}


# ----------------------------------------------------------------------------
# what `cooploc run` keeps, and the regenerated recording
# ----------------------------------------------------------------------------


def test_run_keeps_run_0_estimates_bit_for_bit(froehle):
    view = load_run(froehle, 0)
    assert not view.recomputed
    again = run_one(view.config, 0).estimates
    assert set(again) == set(view.estimates) == {"gnss-kf", "oracle-kf"}
    for name, estimates in again.items():
        for mine, theirs in zip(view.estimates[name], estimates, strict=True):
            np.testing.assert_array_equal(mine.vehicles.ids, theirs.vehicles.ids)
            np.testing.assert_array_equal(mine.vehicles.mean, theirs.vehicles.mean)
            np.testing.assert_array_equal(mine.vehicles.cov, theirs.vehicles.cov)
            if theirs.features is not None and len(theirs.features):
                np.testing.assert_array_equal(mine.features.mean, theirs.features.mean)
    assert run_one(view.config, 1).estimates is None  # only run 0 is kept


def test_regenerated_recording_and_kept_estimates_give_the_stored_errors(froehle):
    """The recording is not stored: regenerated from config.toml, it must score the kept
    estimates exactly as errors.parquet recorded them."""
    view = load_run(froehle, 0)
    stored = _errors(froehle, 0)
    for name, estimates in view.estimates.items():
        table = evaluate(view.recording, estimates)
        kinds = {0: "vehicle", 1: "feature"}
        for step, kind, i, err in zip(table.step, table.kind, table.id, table.err_pos, strict=True):
            assert stored[(name, int(step), kinds[int(kind)], int(i))] == err


def test_a_run_not_kept_is_computed_again_with_the_same_numbers(froehle):
    view = load_run(froehle, 1)
    assert view.recomputed
    stored = _errors(froehle, 1)
    table = evaluate(view.recording, view.estimates["gnss-kf"])
    assert [stored[("gnss-kf", int(s), "vehicle", int(i))] for s, i in
            zip(table.step[table.kind == 0], table.id[table.kind == 0], strict=True)] == \
        list(table.err_pos[table.kind == 0])


def test_estimates_file_round_trip_with_associations(road):
    view = load_run(road, 0)
    decided = [e.info["v2f_association"] for e in view.estimates["icp-da-lc"] if "v2f_association" in e.info]
    assert decided and any((d >= 0).any() for d in decided)
    assert kept.read_estimates(road, 5, 12, 4) is None  # a run that is not in the file


def test_damaged_estimates_file_is_a_clear_error(tmp_path):
    (tmp_path / kept.ESTIMATES_FILE).write_text("not parquet")
    with pytest.raises(InvalidInputError, match=r"estimates\.parquet"):
        kept.read_estimates(tmp_path, 0, 3, 4)


@pytest.mark.parametrize("run", [-1, 2])
def test_run_out_of_range_names_the_option(froehle, run):
    with pytest.raises(InvalidInputError, match=r"--run must lie in \[0, 1\]"):
        load_run(froehle, run)


def test_a_folder_without_config_is_refused(tmp_path):
    with pytest.raises(CooplocError, match=r"no config\.toml"):
        load_run(tmp_path, 0)


# ----------------------------------------------------------------------------
# per-frame data, ellipses, size limits
# ----------------------------------------------------------------------------


def test_ellipse_outline_is_the_2_sigma_contour():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(3, 2, 2))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2)
    mean = rng.normal(size=(3, 2))
    outline = ellipses(mean, cov).reshape(3, -1, 2)[:, :-1]      # drop the NaN separator
    r = outline - mean[:, None]
    mahalanobis = np.einsum("nvi,nvi->nv", r, np.linalg.solve(cov[:, None], r[..., None])[..., 0])
    np.testing.assert_allclose(mahalanobis, 4.0, rtol=1e-9)     # 2σ: (p − m)ᵀ P⁻¹ (p − m) = 2²


def test_frame_data_errors_and_nees_match_the_truth(froehle):
    view = load_run(froehle, 0)
    data = frame_data(view.recording, view.estimates, view.rmse)
    assert list(data.steps) == list(range(12)) and not data.notes
    layer = data.layers["oracle-kf"]
    truth = view.recording.truth
    est = view.estimates["oracle-kf"][5].vehicles
    err = np.hypot(*(est.mean[:, :2] - truth.vehicle_states[5, :, :2]).T)
    np.testing.assert_allclose(layer.error[5], err, rtol=1e-12)
    e = truth.vehicle_states[5, :, :2] - est.mean[:, :2]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(est.cov[:, :2, :2], e[..., None])[..., 0])
    np.testing.assert_allclose(layer.nees[5], nees, rtol=1e-9)
    assert len(data.prior_xy) == 2 and set(data.rmse) == {"gnss-kf", "oracle-kf"}


def test_associations_split_into_right_and_wrong(road):
    view = load_run(road, 0)
    data = frame_data(view.recording, view.estimates, view.rmse)
    layer = data.layers["icp-da-lc"]
    assert layer.has_association
    segments = sum(len(r) + len(w) for r, w in zip(layer.right, layer.wrong, strict=True)) // 4
    decided = sum(int((e.info.get("v2f_association", np.zeros(0)) >= 0).sum())
                  for e in view.estimates["icp-da-lc"])
    assert segments == decided > 0
    assert any(len(link) for link in data.links)
    # every V2F row is a detection line: measuring vehicle → measured point
    assert sum(len(d) for d in data.detections) // 3 == sum(len(f.batch("v2f", 2))
                                                             for f in view.recording.frames)


def test_size_limits_thin_the_frames_and_say_so(froehle, monkeypatch):
    view = load_run(froehle, 0)
    monkeypatch.setattr(frames_module, "MAX_FRAMES", 5)
    monkeypatch.setattr(frames_module, "MAX_MARKERS_PER_FRAME", 4)
    data = frame_data(view.recording, view.estimates, view.rmse)
    assert list(data.steps) == [0, 3, 6, 9]
    assert any("1 in 3 steps" in n for n in data.notes)
    # 2 vehicles (truth, 2 estimators) + 3 features (truth, oracle-kf): 12 markers > 4
    assert any("1 in 3 vehicles and features" in n for n in data.notes)
    assert all(len(ids) == 1 for ids in data.truth_ids)
    assert len(data.rmse["gnss-kf"][0]) == 12  # the RMSE curve is never thinned


# ----------------------------------------------------------------------------
# figure and page
# ----------------------------------------------------------------------------


def _figure(folder, run=0):
    view = load_run(folder, run)
    data = frame_data(view.recording, view.estimates, view.rmse)
    return build_figure(scene(view.preset, view.config.scenario_params, view.recording), data), data


def test_figure_has_the_expected_traces_and_frames(froehle):
    fig, data = _figure(froehle)
    names = [t.name for t in fig.data]
    for name in ("true paths", "truth", "true features", "prior (step 0)", "V2F detections",
                 "gnss-kf", "gnss-kf 2σ",
                 "oracle-kf", "oracle-kf features", "gnss-kf RMSE", "oracle-kf RMSE", "shown step"):
        assert name in names
    assert len(fig.frames) == 12 == len(fig.layout.sliders[0].steps)
    moving = fig.frames[0].traces
    assert all(list(f.traces) == list(moving) and len(f.data) == len(moving) for f in fig.frames)
    assert [fig.data[i].name for i in moving][-3:] == ["truth", "true features", "shown step"]
    # hover: id, error and NEES of every estimate
    gnss = names.index("gnss-kf")
    custom = np.asarray(fig.frames[4].data[list(moving).index(gnss)].customdata)
    np.testing.assert_allclose(custom[:, 1], np.round(data.layers["gnss-kf"].error[4], 3))
    assert "NEES" in fig.data[gnss].hovertemplate
    # the legend toggles an estimator's markers, ellipses and RMSE curve together
    assert {fig.data[i].legendgroup for i, n in enumerate(names) if n.startswith("gnss-kf")} == {"gnss-kf"}


def test_road_figure_has_roads_links_and_associations(road):
    fig, _ = _figure(road)
    names = [t.name for t in fig.data]
    for name in ("roads", "V2V links", "icp-da-lc: association", "icp-da-lc: wrong association"):
        assert name in names
    assert fig.data[names.index("icp-da-lc: association")].legendgroup != "icp-da-lc"


def test_page_is_one_offline_file(froehle, tmp_path):
    path = write_view(froehle, 0, tmp_path / "page.html")
    text = path.read_text()
    assert text.count("<html") == 1 and "Plotly.newPlot" in text
    assert len(text) > 3_000_000  # plotly.js is embedded
    assert not re.search(r"""<script[^>]+src=["']?https?:""", text)  # nothing to fetch
    assert 'id="cooploc-errors"' in text and 'id="cooploc-status"' in text
    assert "froehle2018: run 0 of 2, seed 3" in text


# ----------------------------------------------------------------------------
# animation
# ----------------------------------------------------------------------------


def test_gif_animation(froehle, tmp_path):
    from PIL import Image

    path = write_animation(froehle, 0, tmp_path / "run.gif", fps=4)
    with Image.open(path) as gif:
        assert gif.n_frames == 12


def test_mp4_where_ffmpeg_exists_else_a_clear_error(froehle, tmp_path):
    from matplotlib import animation

    if animation.writers.is_available("ffmpeg"):
        assert write_animation(froehle, 0, tmp_path / "run.mp4").stat().st_size > 0
    else:
        with pytest.raises(InvalidInputError, match="needs ffmpeg"):
            write_animation(froehle, 0, tmp_path / "run.mp4")


def test_animation_needs_a_known_suffix(froehle, tmp_path):
    with pytest.raises(InvalidInputError, match=r"gif or an \.mp4"):
        write_animation(froehle, 0, tmp_path / "run.avi")


# ----------------------------------------------------------------------------
# command line
# ----------------------------------------------------------------------------


def test_cli_view_and_its_errors(froehle, tmp_path):
    out = tmp_path / "v.html"
    result = runner.invoke(app, ["view", str(froehle), "--run", "1", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.stat().st_size > 0 and "computed again" in out.read_text()
    for args, message in ((["--run", "7"], "--run must lie in [0, 1]"),
                          (["--gif", "--out", str(tmp_path / "x.avi")], "a .gif or an .mp4")):
        bad = runner.invoke(app, ["view", str(froehle), *args])
        assert bad.exit_code == 2 and message in bad.output and "Traceback" not in bad.output
        assert len(bad.output.strip().splitlines()) == 1
    missing = runner.invoke(app, ["view", str(tmp_path / "nowhere")])
    assert missing.exit_code == 2 and "does not exist" in missing.output


def test_run_with_view_writes_the_page_and_links_it(tmp_path):
    out = tmp_path / "r"
    result = runner.invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "--runs", "1", "--set",
                                 "n_steps=6", "--out", str(out), "--backend", "serial", "--no-progress",
                                 "--view"])
    assert result.exit_code == 0, result.output
    assert (out / "view.html").stat().st_size > 0 and (out / "estimates.parquet").is_file()
    assert "](view.html)" in (out / "report.md").read_text()
    assert json.loads((out / "summary.json").read_text())["runs"] == 1


def test_sumo_scene_has_the_network_lanes(tmp_path, monkeypatch):
    """The lanes come from the network the traffic ran on (tiny grid: 2 × 2 junctions)."""
    pytest.importorskip("sumolib")
    from cooploc.registry import get_preset
    from cooploc.scenarios import sumo

    monkeypatch.setenv("COOPLOC_CACHE_DIR", str(tmp_path / "cache"))
    cfg = ExperimentConfig.build("sumo-grid-tlr", ["gnss-kf"], scenario_overrides=sumo.TINY_GRID, runs=1)
    recording = run_recording(cfg, 0)
    found = scene(get_preset("sumo-grid-tlr"), cfg.scenario_params, recording)
    lanes = found.roads[np.isfinite(found.roads).all(axis=1)]
    assert len(lanes) > 4 and len(found.junctions)
    assert found.infrastructure_labels.count("traffic light") > 0
    assert len(found.static_ids) == len(recording.truth.feature_ids) - \
        (recording.truth.feature_ids >= sumo.PEDESTRIAN_ID_OFFSET).sum()
