"""`cooploc reproduce --resume`: an interrupted paper experiment keeps its finished runs and
tasks (OUT/runs/) and goes on with the others, with the numbers of an uninterrupted one."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

import cooploc.experiment
from cooploc.cli import app
from cooploc.reproduce import PaperExperiment, ReproduceContext, ReproduceOptions
from cooploc.reproduce.checkpoint import FOLDER, Checkpoint


def _square(x: int) -> int:
    return x * x


class Stop(Exception):
    pass


def _compute(ctx: ReproduceContext) -> dict:
    base = ctx.config("froehle2018", ["gnss-kf"], scenario_overrides={"n_steps": 6})
    first = ctx.run(base)
    if (ctx.out / "stop-after-first").exists():
        raise Stop
    sweep = ctx.sweep(base, "n_features", [1, 2])
    squares = ctx.map(_square, [1, 2, 3], "squares")
    rmse = [[float(r.errors["gnss-kf"].err_pos.sum()) for r in result.runs]
            for result in [first] + [res for _, res in sweep]]
    return {"rmse": rmse, "squares": squares}


TOY = PaperExperiment(name="toy", title="toy", paper="none.txt", compute=_compute,
                      report=lambda data: ["# toy"], compared=("gnss-kf",), runs=3)


@pytest.fixture
def count_runs(monkeypatch):
    """How many (config, run) tasks run in this process (serial backend)."""
    calls = []
    original = cooploc.experiment._run_task

    def counted(task):
        calls.append(task[1])
        return original(task)

    monkeypatch.setattr(cooploc.experiment, "_run_task", counted)
    return calls


def test_resume_skips_finished_runs_and_gives_the_same_numbers(tmp_path, count_runs) -> None:
    whole = TOY.run(ReproduceOptions(tmp_path / "whole", backend="serial"))
    assert len(count_runs) == 9 and not (whole / FOLDER).exists()  # finished: nothing to resume
    count_runs.clear()

    out = tmp_path / "cut"
    out.mkdir()
    (out / "stop-after-first").touch()
    with pytest.raises(Stop):
        TOY.run(ReproduceOptions(out, backend="serial"))
    assert len(count_runs) == 3 and len(list((out / FOLDER).glob("*.pkl"))) == 3
    (out / "stop-after-first").unlink()
    count_runs.clear()

    TOY.run(ReproduceOptions(out, backend="serial", resume=True))
    assert len(count_runs) == 6  # the sweep's runs only
    assert json.loads((out / "data.json").read_text()) == json.loads((whole / "data.json").read_text())
    assert not (out / FOLDER).exists()


def test_without_resume_the_folder_starts_afresh(tmp_path, count_runs) -> None:
    out = tmp_path / "cut"
    out.mkdir()
    (out / "stop-after-first").touch()
    with pytest.raises(Stop):
        TOY.run(ReproduceOptions(out, backend="serial"))
    with pytest.raises(Stop):
        TOY.run(ReproduceOptions(out, backend="serial"))
    assert len(count_runs) == 6


def test_map_tasks_are_kept(tmp_path) -> None:
    checkpoint = Checkpoint(tmp_path, resume=False)
    options = ReproduceOptions(tmp_path, backend="serial")
    ctx = ReproduceContext(options, tmp_path, 1, [], checkpoint)
    assert ctx.map(_square, [4, 5], "squares") == [16, 25]
    assert len(list(checkpoint.folder.glob("*.pkl"))) == 2
    broken = sorted(checkpoint.folder.glob("*.pkl"))[0]
    broken.write_bytes(b"not a pickle")  # e.g. killed mid-write by another tool: computed again
    assert ctx.map(_square, [4, 5], "squares") == [16, 25]


def test_cli_resume_option(tmp_path) -> None:
    result = CliRunner().invoke(app, ["reproduce", "--help"])
    assert "--resume" in result.output


def test_map_takes_partial_functions(tmp_path) -> None:
    import functools

    checkpoint = Checkpoint(tmp_path, resume=False)
    ctx = ReproduceContext(ReproduceOptions(tmp_path, backend="serial"), tmp_path, 1, [], checkpoint)
    assert ctx.map(functools.partial(_power, exponent=3), [2, 3], "cubes") == [8, 27]
    assert ctx.map(functools.partial(_power, exponent=2), [2, 3], "squares") == [4, 9]  # another key


def _power(x: int, exponent: int) -> int:
    return x ** exponent
