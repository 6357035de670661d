"""`--resume` (issue 17 item 3): an interrupted study goes on in its folder, keeping the runs
it finished and running only the others, with the numbers of an uninterrupted study; a
folder of another experiment is refused in one line naming what differs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

import cooploc.experiment
from cooploc.cli import app
from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig, run_one
from cooploc.results import RUNS_FOLDER, finished_runs, merge_runs, run_to_folder, write_run

STUDY = ["froehle2018", "-e", "gnss-kf", "-e", "oracle-kf"]
ARGS = [*STUDY, "--runs", "4", "--seed", "3", "--set", "n_steps=12"]


def config(runs: int = 4, seed: int = 3) -> ExperimentConfig:
    """The experiment of ARGS."""
    return ExperimentConfig.build("froehle2018", ["gnss-kf", "oracle-kf"], scenario_overrides={"n_steps": 12},
                                  runs=runs, seed=seed, backend="serial")


def interrupted(folder: Path, cfg: ExperimentConfig, done: list[int]) -> Path:
    """The folder an interrupted `run_to_folder` leaves: the runs `done` written and merged,
    marked incomplete (what Ctrl-C leaves; a killed process leaves the same, unmerged)."""
    for r in done:
        write_run(run_one(cfg, r), cfg, folder)
    (folder / "config.toml").write_text("")  # replaced by merge_runs' config
    merge_runs(folder, cfg, stopped_by="KeyboardInterrupt")
    return folder


def _run(*args: str):
    return CliRunner().invoke(app, ["run", *args])


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reference")
    result = _run(*ARGS, "--backend", "serial", "--no-progress", "--out", str(out))
    assert result.exit_code == 0, result.output
    return out


def _numbers(folder: Path) -> dict:
    summary = json.loads((folder / "summary.json").read_text())
    for est in summary["estimators"].values():
        est.pop("steps_per_second")
    return summary


@pytest.fixture
def ran(monkeypatch) -> list[int]:
    """The runs simulated from now on (serial backend: in this process)."""
    runs: list[int] = []
    real = cooploc.experiment.run_one

    def counting(cfg, run, *args, **kwargs):
        runs.append(run)
        return real(cfg, run, *args, **kwargs)

    monkeypatch.setattr(cooploc.experiment, "run_one", counting)
    return runs


def test_resume_runs_only_the_missing_runs(tmp_path, reference, ran):
    folder = interrupted(tmp_path / "study", config(), [0, 2])
    assert json.loads((folder / "summary.json").read_text())["complete"] is False
    assert finished_runs(folder, config()) == {0, 2}
    ran.clear()
    result = _run(*ARGS, "--backend", "serial", "--no-progress", "--resume", "--out", str(folder))
    assert result.exit_code == 0, result.output
    assert sorted(ran) == [1, 3]
    assert (folder / "errors.parquet").read_bytes() == (reference / "errors.parquet").read_bytes()
    assert _numbers(folder) == _numbers(reference)
    assert not (folder / RUNS_FOLDER).exists()


def test_resume_of_a_killed_study_with_processes(tmp_path, reference):
    folder = tmp_path / "killed"
    cfg = config()
    for r in (1, 3):  # killed before merging: parts only, and config.toml
        write_run(run_one(cfg, r), cfg, folder)
    from cooploc.results import _write_config

    _write_config(cfg, folder)
    result = _run("--config", str(folder / "config.toml"), "--backend", "processes", "--workers", "2",
                  "--no-progress", "--resume")
    assert result.exit_code == 0, result.output
    assert (folder / "errors.parquet").read_bytes() == (reference / "errors.parquet").read_bytes()


def test_resume_of_a_complete_study_runs_nothing(reference, ran, tmp_path):
    import shutil

    folder = tmp_path / "copy"
    shutil.copytree(reference, folder)
    ran.clear()
    run_to_folder(config(), folder, resume=True)
    assert ran == []
    assert _numbers(folder) == _numbers(reference)


def test_resume_without_a_study_starts_one(tmp_path, reference):
    folder = run_to_folder(config(), tmp_path / "new", resume=True)
    assert (folder / "errors.parquet").read_bytes() == (reference / "errors.parquet").read_bytes()


def test_without_resume_the_finished_runs_are_done_again(tmp_path, ran):
    folder = interrupted(tmp_path / "study", config(), [0, 2])
    ran.clear()
    run_to_folder(config(), folder)
    assert sorted(ran) == [0, 1, 2, 3]


@pytest.mark.parametrize(("other", "what"), [
    (["--runs", "4", "--seed", "4", "--set", "n_steps=12"], "seed is 3 there and 4 here"),
    (["--runs", "5", "--seed", "3", "--set", "n_steps=12"], "runs is 4 there and 5 here"),
    (["--runs", "4", "--seed", "3", "--set", "n_steps=13"],
     "scenario_params.n_steps is 12 there and 13 here"),
])
def test_resume_refuses_another_experiment(tmp_path, other, what, ran):
    folder = interrupted(tmp_path / "study", config(), [0])
    ran.clear()
    result = _run(*STUDY, *other, "--backend", "serial", "--no-progress", "--resume", "--out", str(folder))
    assert result.exit_code == 2, result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert f"--resume: {folder} holds another experiment ({what})" in result.output
    assert ran == []
    assert finished_runs(folder, config()) == {0}  # untouched


def test_resume_with_overwrite_is_refused(tmp_path):
    result = _run(*ARGS, "--resume", "--overwrite", "--out", str(tmp_path / "x"), "--no-progress")
    assert result.exit_code == 2 and "give one" in result.output
    assert not (tmp_path / "x").exists()


def test_finished_runs_refuses_another_experiment_in_python(tmp_path):
    folder = interrupted(tmp_path / "study", config(), [1])
    with pytest.raises(ConfigError, match="holds another experiment"):
        run_to_folder(config(seed=9), folder, resume=True)
