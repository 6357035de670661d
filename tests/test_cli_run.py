"""`cooploc run`: --config reruns and overrides, output-folder protection, one-line errors
checked before any run, help defaults, the summary table (issue 16, items 3, 6, 7)."""

from __future__ import annotations

import json
import re
import sys

import pytest
from typer.testing import CliRunner

import cooploc.budget
import cooploc.experiment
import cooploc.results
from cooploc.cli import app

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

runner = CliRunner()
SMALL = ["--set", "n_steps=10", "--runs", "2", "--seed", "3", "--backend", "serial", "--no-progress"]


def _run(*args: str, env: dict[str, str] | None = None):
    return runner.invoke(app, ["run", *args], env=env)


def _one_line_error(result, *parts: str) -> None:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    for part in parts:
        assert part in result.output, result.output


@pytest.fixture
def no_runs(monkeypatch):
    """Refused configurations must fail before anything is simulated."""
    def refuse(*args, **kwargs):
        raise AssertionError("an experiment ran")
    monkeypatch.setattr(cooploc.experiment, "run_experiment", refuse)
    monkeypatch.setattr(cooploc.results, "run_to_folder", refuse)  # what `cooploc run` calls


@pytest.fixture
def folder(tmp_path):
    """A results folder of froehle2018 / gnss-kf, 2 runs, seed 3."""
    out = tmp_path / "first"
    result = _run("froehle2018", "-e", "gnss-kf", *SMALL, "--out", str(out))
    assert result.exit_code == 0, result.output
    return out


def _config(folder) -> dict:
    return tomllib.loads((folder / "config.toml").read_text())


# --- item 3: --config reruns into its own folder; options override; nothing ignored -----------


def test_config_reruns_into_its_own_folder(folder):
    before = json.loads((folder / "summary.json").read_text())
    result = _run("--config", str(folder / "config.toml"), "--no-progress")
    assert result.exit_code == 0, result.output
    assert f"results: {folder}/" in result.output.replace("\n", "")
    after = json.loads((folder / "summary.json").read_text())
    assert after["estimators"]["gnss-kf"]["vehicle_rmse"] == before["estimators"]["gnss-kf"]["vehicle_rmse"]


def test_config_options_override_the_file(folder, tmp_path):
    out = tmp_path / "other"
    result = _run("--config", str(folder / "config.toml"), "--out", str(out), "--runs", "1", "--seed", "7",
                  "--set", "n_steps=12", "-e", "gnss-kf", "-e", "oracle-kf",
                  "--est-set", "oracle-kf.feature_timeout=9", "--backend", "processes", "--workers", "1",
                  "--no-progress")
    assert result.exit_code == 0, result.output
    config = _config(out)
    assert (config["runs"], config["seed"], config["backend"], config["workers"]) == (1, 7, "processes", 1)
    assert config["scenario_params"]["n_steps"] == 12
    assert list(config["estimators"]) == ["gnss-kf", "oracle-kf"]
    assert config["estimators"]["oracle-kf"]["feature_timeout"] == 9
    assert _config(folder)["runs"] == 2  # the source folder is untouched


def test_config_keeps_the_file_values_not_given(folder, tmp_path):
    out = tmp_path / "other"
    result = _run("--config", str(folder / "config.toml"), "--out", str(out), "--runs", "1", "--no-progress")
    assert result.exit_code == 0, result.output
    config = _config(out)
    assert (config["seed"], config["backend"], config["scenario_params"]["n_steps"]) == (3, "serial", 10)


def test_changed_config_is_not_written_over_its_folder(folder, no_runs):
    result = _run("--config", str(folder / "config.toml"), "--runs", "5", "--no-progress")
    _one_line_error(result, "holds the results of another configuration", "--overwrite")
    assert _config(folder)["runs"] == 2


def test_overwrite_replaces_another_configuration(folder):
    result = _run("--config", str(folder / "config.toml"), "--runs", "1", "--overwrite", "--no-progress")
    assert result.exit_code == 0, result.output
    assert _config(folder)["runs"] == 1


def test_plain_run_does_not_write_over_another_results_folder(folder, no_runs):
    result = _run("froehle2018", "-e", "oracle-kf", *SMALL, "--out", str(folder))
    _one_line_error(result, str(folder), "--overwrite")


def test_plain_run_may_repeat_itself_into_its_folder(folder):
    # the same experiment with another backend gives the same numbers: allowed
    args = [a if a != "serial" else "processes" for a in SMALL]
    result = _run("froehle2018", "-e", "gnss-kf", *args, "--out", str(folder))
    assert result.exit_code == 0, result.output


def test_summary_without_config_is_protected(tmp_path, no_runs):
    (tmp_path / "summary.json").write_text("{}")
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", *SMALL, "--out", str(tmp_path)), "--overwrite")


def test_config_refuses_another_scenario(folder, no_runs):
    result = _run("zhang2016-cv", "--config", str(folder / "config.toml"))
    _one_line_error(result, "'zhang2016-cv' differs from 'froehle2018'")


def test_config_accepts_its_own_scenario(folder):
    result = _run("froehle2018", "--config", str(folder / "config.toml"), "--no-progress")
    assert result.exit_code == 0, result.output


# --- item 2: --out checked before any run ------------------------------------------------------


def test_out_is_checked_before_any_run(tmp_path, no_runs):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", "--out", str(a_file)), "--out", "is a file")
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", "--out", str(a_file / "below")),
                    "--out: cannot write to", "below")
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", "--out", ""), "--out must name a folder, got ''")


# --- item 4: unclear inputs --------------------------------------------------------------------


@pytest.mark.parametrize(("args", "parts"), [
    (["--est-set", "gnss-kf.anything=1"], ["unknown key 'anything'", "gnss-kf has no parameters"]),
    (["--backend", "serial", "--workers", "5"], ["workers apply to the processes and dask backends",
                                                 "workers = 5"]),
    (["--set", "n_steps=5", "--set", "n_steps=6"], ["--set gives 'n_steps' twice: '5' and '6'"]),
    (["-e", "oracle-kf", "--est-set", "oracle-kf.feature_timeout=5", "--est-set",
      "oracle-kf.feature_timeout=6"], ["--est-set gives 'oracle-kf.feature_timeout' twice"]),
])
def test_unclear_inputs_are_refused(args, parts, no_runs):
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", *args), *parts)


def test_reproduce_refuses_workers_with_serial():
    result = runner.invoke(app, ["reproduce", "froehle2018", "--backend", "serial", "--workers", "2"])
    _one_line_error(result, "workers apply to the processes and dask backends")


@pytest.mark.parametrize(("command", "defaults"), [
    ("run", ["[default: results/SCENARIO, or the folder of", "[default: all cores]", "[default: 10]",
             "[default: processes]"]),
    ("reproduce", ["[default: the paper's]", "[default: results/reproduce-PAPER]", "[default: all cores]"]),
])
def test_help_shows_the_defaults(command, defaults):
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "250"})
    assert result.exit_code == 0
    text = re.sub(r"\s+", " ", result.output)
    for default in defaults:
        assert default in text, default


def test_help_documents_config_overrides_and_overwrite():
    text = re.sub(r"[\s│]+", " ", runner.invoke(app, ["run", "--help"], env={"COLUMNS": "250"}).output)
    assert "override the file's values" in text and "--overwrite" in text
    assert "rerun into its own folder" in text


def test_summary_table_never_cuts_names_or_numbers(tmp_path):
    out = tmp_path / "r"
    names = ["gnss-kf", "oracle-kf", "kf-known-da"]
    result = _run("froehle2018", *[a for n in names for a in ("-e", n)], *SMALL,
                  "--set", "n_vehicles=8", "--out", str(out), env={"COLUMNS": "80"})
    assert result.exit_code == 0, result.output
    assert "…" not in result.output
    summary = json.loads((out / "summary.json").read_text())
    for name, est in summary["estimators"].items():
        assert name in result.output
        assert f"{est['vehicle_rmse_all']:.3f}" in result.output
    assert "vehicles shown; all in summary.json" in result.output.replace("\n", " ").replace("  ", " ")


# --- item 6: sizes and overflow-prone values refused up front ----------------------------------


@pytest.fixture
def sixteen_gb(monkeypatch):
    """A machine with 16 GB available, whatever runs the test."""
    monkeypatch.setattr(cooploc.budget, "available_memory", lambda: 16 * 10**9)


@pytest.mark.parametrize("args", [
    ["-e", "gnss-kf", "--set", "n_steps=100000000"],
    ["-e", "oracle-kf", "--set", "n_features=20000", "--runs", "1"],
    ["-e", "gnss-kf", "--runs", str(10**9)],
])
def test_huge_sizes_are_refused_with_the_memory_estimate(args, sixteen_gb, no_runs):
    result = _run("froehle2018", *args)
    _one_line_error(result, "needs about", "of memory", "16 GB available")


@pytest.mark.parametrize("setting", ["dt=1e300", "noise_density=1e300", "vehicle_position_std=1e200"])
def test_overflowing_values_are_refused_with_the_range(setting, no_runs):
    key = setting.split("=")[0]
    _one_line_error(_run("froehle2018", "-e", "gnss-kf", "--set", setting), f"{key} must lie in")


def test_a_long_experiment_is_announced_before_it_starts(monkeypatch, tmp_path):
    def stop(*args, **kwargs):
        raise cooploc.experiment.ConfigError("stopped by the test")
    monkeypatch.setattr(cooploc.results, "run_to_folder", stop)
    result = _run("froehle2018", "-e", "oracle-kf", "--set", "n_features=1000", "--runs", "20",
                  "--workers", "2", "--out", str(tmp_path), "--no-progress")
    assert "note: this experiment needs at least" in result.output and "days of computing" in result.output
    assert "stopped by the test" in result.output  # the note came before the run
