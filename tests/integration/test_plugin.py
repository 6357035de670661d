"""A third-party plug-in, installed and run as a user would, without touching cooploc.

The example package `examples/plugin` (estimator `huber-kf`, scenario family
`motorway`) is installed into a temporary folder with pip — offline: no index, no
dependencies, no build isolation — and every check runs in a fresh interpreter whose
path holds that folder, so that cooploc finds the plug-in only through its entry
points. A distribution whose entry points name a missing module must be left out with
a `PluginWarning`, and must not break the rest.

Building offline needs a setuptools that builds wheels by itself (>= 70.1); the ``dev``
extra asks for one.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import pytest

import cooploc
from cooploc.registry import ESTIMATOR_GROUP, SCENARIO_GROUP

pytestmark = pytest.mark.slow

PLUGIN = Path(__file__).resolve().parents[2] / "examples" / "plugin"
COOPLOC_SRC = Path(cooploc.__file__).resolve().parents[1]  # the cooploc under test


def write_distribution(site: Path, name: str, version: str,
                       entry_points: Mapping[str, Mapping[str, str]]) -> Path:
    """An installed distribution's metadata folder: what `importlib.metadata` reads."""
    folder = site / f"{name.replace('-', '_')}-{version}.dist-info"
    folder.mkdir(parents=True)
    (folder / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (folder / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{key} = {value}\n" for key, value in points.items()) + "\n"
        for group, points in entry_points.items()))
    return folder


def install(source: Path, site: Path) -> None:
    """Install the example package from `source` into `site` with pip, offline."""
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
         "--no-build-isolation", "--no-cache-dir", "--disable-pip-version-check",
         "--target", str(site), str(source)],
        check=True, capture_output=True, text=True,
        env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"})


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Path]]:
    """{"site": the installed plug-in, "broken": a broken distribution, "work": scratch}."""
    work = tmp_path_factory.mktemp("plugin")
    source = work / "source"  # pip builds in the tree it is given: keep examples/ clean
    shutil.copytree(PLUGIN, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    site, broken = work / "site", work / "broken"
    install(source, site)
    write_distribution(broken, "cooploc-broken-plugin", "0.0.1", {
        ESTIMATOR_GROUP: {"broken-kf": "cooploc_no_such_module:BrokenKF"},
        SCENARIO_GROUP: {"broken-road": "cooploc_no_such_module.road"},
    })
    yield {"site": site, "broken": broken, "work": work}
    shutil.rmtree(work, ignore_errors=True)


def python(*args: str, paths: list[Path], cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run `python *args` with `paths` and the cooploc under test on its path."""
    pythonpath = [*map(str, paths), str(COOPLOC_SRC)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(pythonpath), "COLUMNS": "250"}
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=600)


def test_the_example_installs_offline(folders: dict[str, Path]) -> None:
    site = folders["site"]
    assert (site / "cooploc_example_plugin" / "huber_kf.py").is_file()
    [dist_info] = site.glob("cooploc_example_plugin-*.dist-info")
    entry_points = (dist_info / "entry_points.txt").read_text()
    assert "[cooploc.estimators]" in entry_points and "huber-kf" in entry_points
    assert "[cooploc.scenarios]" in entry_points and "cooploc_example_plugin.motorway" in entry_points


def test_cooploc_list_shows_the_plugin(folders: dict[str, Path]) -> None:
    result = python("-m", "cooploc", "list", paths=[folders["site"]], cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    for word in ("huber-kf", "Huber-robust GNSS update", "motorway-multipath", "motorway ",
                 "gnss-kf", "froehle2018"):
        assert word in result.stdout, word
    assert "PluginWarning" not in result.stderr


def test_cooploc_run_compares_the_plugin_with_a_built_in(folders: dict[str, Path]) -> None:
    out = folders["work"] / "results"
    result = python("-m", "cooploc", "run", "motorway-multipath", "-e", "huber-kf", "-e", "gnss-kf",
                    "--runs", "2", "--seed", "1", "--backend", "serial", "--set", "n_steps=60",
                    "--est-set", "huber-kf.threshold=3", "--out", str(out), "--no-progress",
                    paths=[folders["site"]], cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario"] == "motorway-multipath" and summary["runs"] == 2
    assert summary["params"]["n_steps"] == 60 and summary["params"]["outlier_probability"] == 0.1
    assert set(summary["estimators"]) == {"huber-kf", "gnss-kf"}
    assert summary["estimators"]["huber-kf"]["params"]["threshold"] == 3.0
    for est in summary["estimators"].values():
        assert math.isfinite(est["vehicle_rmse_all"])
        assert set(est["vehicle_rmse"]) == {str(i) for i in range(6)}
    assert (out / "errors.parquet").is_file() and (out / "config.toml").is_file()


def test_the_plugin_estimator_passes_the_contract(folders: dict[str, Path]) -> None:
    code = ("import json\nfrom cooploc.testing import check_estimator\n"
            "print(json.dumps(check_estimator('huber-kf')))")
    result = python("-c", code, paths=[folders["site"]], cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout.strip().splitlines()[-1])
    assert all(v == "passed" or v.startswith("skipped") for v in outcome.values()), outcome
    for check in ("interface", "valid_estimates", "empty_frames", "same_seed", "enter_and_leave",
                  "long_run", "truth_only_to_references", "true_states_never_read"):
        assert outcome[check] == "passed", (check, outcome[check])


def test_a_broken_plugin_is_left_out_with_a_warning(folders: dict[str, Path]) -> None:
    paths = [folders["site"], folders["broken"]]
    result = python("-m", "cooploc", "list", paths=paths, cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    assert "PluginWarning" in result.stderr and "'broken-kf'" in result.stderr
    assert "huber-kf" in result.stdout and "motorway-multipath" in result.stdout
    assert "broken" not in result.stdout
    code = ("import json, warnings\nimport cooploc.registry as registry\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    names = sorted(registry.estimators())\n"
            "print(json.dumps({'names': names, 'warnings': [[w.category.__module__ + '.' + "
            "w.category.__name__, str(w.message)] for w in caught]}))")
    result = python("-c", code, paths=paths, cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    seen = json.loads(result.stdout.strip().splitlines()[-1])
    assert "huber-kf" in seen["names"] and "broken-kf" not in seen["names"]
    assert [category for category, _ in seen["warnings"]] == ["cooploc.registry.PluginWarning"] * 2
    estimator, scenario = (text for _, text in seen["warnings"])
    assert "'broken-kf' (cooploc_no_such_module:BrokenKF) of group cooploc.estimators was left out: " \
           "ModuleNotFoundError" in estimator
    assert "'broken-road'" in scenario and "group cooploc.scenarios" in scenario


def test_without_outliers_the_huber_filter_is_the_kalman_filter(folders: dict[str, Path]) -> None:
    """An independent check of the plug-in's method: with a threshold no fix reaches,
    every weight is 1 and `huber-kf` must give `gnss-kf`'s numbers (the module's claim)."""
    code = (
        "import json, numpy as np, cooploc\n"
        "preset = cooploc.get_preset('motorway')\n"
        "rec = preset.generate(np.random.default_rng(4), preset.params.with_overrides({'n_steps': 60}))\n"
        "out = {}\n"
        "for name, params in (('gnss-kf', None), ('huber-kf', {'threshold': 1e12})):\n"
        "    cls = cooploc.get_estimator(name)\n"
        "    p = None if params is None else cls.Params(**params)\n"
        "    est = cooploc.make_estimator(name, rec.setup, p, np.random.default_rng(0))\n"
        "    out[name] = [e.vehicles.mean.tolist() for e in cooploc.estimate(est, rec)]\n"
        "print(json.dumps(out))\n")
    result = python("-c", code, paths=[folders["site"]], cwd=folders["work"])
    assert result.returncode == 0, result.stderr
    means = json.loads(result.stdout.strip().splitlines()[-1])
    # same Joseph-form updates with R / 1: equal up to round-off
    np.testing.assert_allclose(means["huber-kf"], means["gnss-kf"], rtol=1e-12, atol=1e-9)
