"""The viewer page in a real browser: headless Chromium (Debian's ``chromium``) loads the
file offline, and the page must render without a JavaScript error, draw the traces the
Python figure holds, carry its animation frames, and give a screenshot that is not blank.

`.ci/run` installs chromium where it is missing; only where no chromium binary exists is
the test skipped, with that reason.
"""

from __future__ import annotations

import numpy as np
import pytest

from cooploc.experiment import ExperimentConfig, run_experiment
from cooploc.results import write_results
from cooploc.view import write_view
from cooploc.view.browser import chromium, load_page, screenshot
from cooploc.view.data import load_run
from cooploc.view.figure import build_figure
from cooploc.view.frames import frame_data
from cooploc.view.scene import scene

pytest.importorskip("plotly")
pytestmark = pytest.mark.skipif(chromium() is None,
                                reason="no chromium binary (apt-get install chromium; .ci/run does)")


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    cfg = ExperimentConfig.build("brambilla-road", ["gnss-kf", "icp-da-lc"], runs=1, seed=2,
                                 backend="serial")
    folder = tmp_path_factory.mktemp("road")
    write_results(run_experiment(cfg), folder)
    view = load_run(folder, 0)
    fig = build_figure(scene(view.preset, view.config.scenario_params, view.recording),
                       frame_data(view.recording, view.estimates, view.rmse))
    return write_view(folder), [t.name for t in fig.data], len(fig.frames)


def test_page_renders_without_javascript_errors(page):
    path, names, n_frames = page
    report = load_page(path)
    assert report.errors == []
    assert report.status["rendered"] is True
    assert report.status["traces"] == names        # what plotly drew is the Python figure
    for name in ("roads", "truth", "V2V links", "gnss-kf", "icp-da-lc", "icp-da-lc: association",
                 "icp-da-lc RMSE", "shown step"):
        assert name in report.status["traces"]
    assert report.status["frames"] == n_frames == 12
    assert "main-svg" in report.dom                # plotly's SVG layers are in the page


def test_screenshot_is_not_blank(page, tmp_path):
    from PIL import Image

    path, _, _ = page
    png = screenshot(path, tmp_path / "shot.png", size=(1200, 800))
    with Image.open(png) as image:
        pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    assert pixels.shape[0] == 1200 * 800
    not_white = (pixels < 235).any(axis=1).mean()
    colours = np.unique(pixels // 16, axis=0).shape[0]
    assert not_white > 0.02, f"only {not_white:.1%} of the screenshot is not white"
    assert colours > 20, f"only {colours} colour levels: nothing drawn"
    # the paper's colours are on the map: red truth and green first estimator
    red = ((pixels[:, 0] > 180) & (pixels[:, 1] < 90) & (pixels[:, 2] < 90)).sum()
    green = ((pixels[:, 1] > 130) & (pixels[:, 0] < 90) & (pixels[:, 2] < 90)).sum()
    assert red > 20 and green > 20
