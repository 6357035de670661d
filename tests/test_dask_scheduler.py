"""Monte Carlo on an existing Dask cluster (issue 17 item 3): a real `dask scheduler` and two
`dask worker` processes on 127.0.0.1 (random ports, nothing listening elsewhere) take the
runs of `cooploc run --backend dask --scheduler ADDRESS` (or of ``DASK_SCHEDULER_ADDRESS``);
the results are byte for byte those of the serial backend, and the workers run one thread."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

import cooploc.backends
from cooploc.backends import completed, scheduler_address
from cooploc.cli import app
from cooploc.errors import ConfigError
from cooploc.experiment import ExperimentConfig
from test_resume import config, interrupted
from thread_probe import thread_report

distributed = pytest.importorskip("distributed", reason="dask extra not installed")

TESTS = Path(__file__).parent
SRC = Path(cooploc.backends.__file__).parents[1]
LOCAL = "127.0.0.1"
STARTUP_SECONDS = 90


def _dask_command() -> list[str]:
    # the `dask` script of this interpreter's environment (not another one on PATH)
    script = Path(sys.executable).with_name("dask")
    return [str(script)] if script.exists() else [shutil.which("dask") or "dask"]


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):  # the tests that use it are slow: starting a cluster takes seconds
    """The address of a scheduler with two single-thread workers, all on 127.0.0.1; every
    process is stopped at the end, whatever happened."""
    folder = tmp_path_factory.mktemp("dask")
    file = folder / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), str(TESTS)]),
           "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    common = ["--dashboard-address", f"{LOCAL}:0"]  # the web servers on this machine only, free ports
    processes: list[subprocess.Popen] = []
    log = (folder / "cluster.log").open("w")
    try:
        processes.append(subprocess.Popen(
            [*_dask_command(), "scheduler", "--host", LOCAL, "--port", "0", "--scheduler-file", str(file),
             *common], env=env, stdout=log, stderr=subprocess.STDOUT, cwd=folder))
        deadline = time.monotonic() + STARTUP_SECONDS
        while not file.exists():
            assert processes[0].poll() is None, (folder / "cluster.log").read_text()
            assert time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.2)
        for i in range(2):
            processes.append(subprocess.Popen(
                [*_dask_command(), "worker", "--scheduler-file", str(file), "--host", LOCAL,
                 "--nthreads", "1", "--nworkers", "1", "--no-dashboard", *common,
                 "--local-directory", str(folder / f"worker-{i}")],
                env=env, stdout=log, stderr=subprocess.STDOUT, cwd=folder))
        address = json.loads(file.read_text())["address"]
        with distributed.Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=STARTUP_SECONDS)
        yield address
    finally:
        for process in reversed(processes):
            _stop(process)
        log.close()


def _run(*args: str, env: dict[str, str] | None = None):
    return CliRunner().invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "-e", "oracle-kf", "--runs", "4",
                                    "--seed", "3", "--set", "n_steps=12", *args], env=env)


def _numbers(folder: Path) -> dict:
    summary = json.loads((folder / "summary.json").read_text())
    for est in summary["estimators"].values():
        est.pop("steps_per_second")
    return summary


@pytest.fixture(scope="module")
def serial(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    result = _run("--backend", "serial", "--no-progress", "--out", str(out))
    assert result.exit_code == 0, result.output
    return out


@pytest.mark.slow
def test_runs_on_the_scheduler_equal_serial(cluster, serial, tmp_path):
    out = tmp_path / "dask"
    result = _run("--backend", "dask", "--scheduler", cluster, "--out", str(out))
    assert result.exit_code == 0, result.output
    assert f"Dask scheduler {cluster}: 2 worker threads; dashboard: http://{LOCAL}:" in result.output
    assert (out / "errors.parquet").read_bytes() == (serial / "errors.parquet").read_bytes()
    assert _numbers(out) == _numbers(serial)
    with distributed.Client(cluster) as client:  # the runs went to the cluster's workers
        prefixes = client.run_on_scheduler(lambda dask_scheduler: list(dask_scheduler.task_prefixes))
    assert "one_thread_call" in prefixes  # dask drops the leading underscore of the task name


@pytest.mark.slow
def test_environment_variable_names_the_scheduler(cluster, serial, tmp_path, monkeypatch):
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", cluster)
    assert scheduler_address() == cluster
    out = tmp_path / "env"
    result = _run("--backend", "dask", "--out", str(out), env={"DASK_SCHEDULER_ADDRESS": cluster})
    assert result.exit_code == 0, result.output
    assert f"Dask scheduler {cluster}" in result.output  # not a local cluster
    assert (out / "errors.parquet").read_bytes() == (serial / "errors.parquet").read_bytes()


@pytest.mark.slow
def test_dask_workers_run_one_thread(cluster):
    lines: list[str] = []
    reports = [r for _, r in completed(thread_report, range(4), "dask", scheduler=cluster,
                                       announce=lines.append)]
    assert len(reports) == 4 and lines and cluster in lines[0]
    for report in reports:
        assert report["pools"] and all(n == 1 for _, n in report["pools"]), report
        assert report["numba"] == 1, report


@pytest.mark.slow
def test_resume_on_the_scheduler(cluster, serial, tmp_path):
    folder = interrupted(tmp_path / "resumed", config(), [0, 3])
    result = _run("--backend", "dask", "--scheduler", cluster, "--no-progress", "--resume", "--out",
                  str(folder))
    assert result.exit_code == 0, result.output
    assert (folder / "errors.parquet").read_bytes() == (serial / "errors.parquet").read_bytes()
    assert _numbers(folder) == _numbers(serial)


def test_an_unreachable_scheduler_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setattr(cooploc.backends, "CONNECT_TIMEOUT", "1s")
    with pytest.raises(ConfigError, match=r"cannot reach a Dask scheduler at 'tcp://127.0.0.1:9'"):
        list(completed(thread_report, range(2), "dask", scheduler="tcp://127.0.0.1:9"))
    # on the command line: --scheduler alone means --backend dask; one line, no folder left
    out = tmp_path / "out"
    result = _run("--scheduler", "tcp://127.0.0.1:9", "--no-progress", "--out", str(out))
    assert result.exit_code == 2, result.output
    assert result.output.strip().splitlines() == [
        "error: scheduler: cannot reach a Dask scheduler at 'tcp://127.0.0.1:9' " + result.output.split(
            "'tcp://127.0.0.1:9' ", 1)[1].strip()]
    assert not out.exists()


def _config(**kwargs) -> ExperimentConfig:
    return ExperimentConfig.build("froehle2018", ["gnss-kf"], **kwargs)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"backend": "processes", "scheduler": "tcp://h:1"}, "a scheduler address applies to the dask backend, "
                                                          "not processes; got scheduler = 'tcp://h:1'"),
    ({"backend": "dask", "scheduler": "tcp://h:1", "workers": 2},
     "the cluster at tcp://h:1 has its own workers"),
    ({"backend": "dask", "scheduler": ""}, "scheduler must be the address of a Dask scheduler"),
    ({"backend": "dask", "scheduler": "tcp://h :1"}, "scheduler must be the address of a Dask scheduler"),
])
def test_scheduler_is_checked(kwargs, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        _config(**kwargs)


def test_scheduler_is_kept_in_config_toml_but_not_part_of_the_experiment():
    config = _config(backend="dask", scheduler="tcp://h:1")
    assert ExperimentConfig.from_dict(config.to_dict()) == config
    assert config.same_experiment(_config(backend="serial"))
    assert config.with_overrides(backend="processes").scheduler is None
    assert config.with_overrides(runs=3).scheduler == "tcp://h:1"
    assert _config(backend="dask", workers=2).with_overrides(scheduler="tcp://g:2").workers is None


@pytest.mark.slow
def test_a_worker_without_the_code_is_one_line(cluster, tmp_path, monkeypatch):
    (tmp_path / "only_here.py").write_text("def task(x):\n    return x\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import only_here  # importable here, not on the workers

    # the scheduler unpickles the task graph: there it fails first
    with pytest.raises(ConfigError, match=r"Dask scheduler .* cannot unpickle the runs .*: install cooploc"):
        list(completed(only_here.task, range(2), "dask", scheduler=cluster))


def test_scheduler_address_order(monkeypatch):
    import dask

    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    with dask.config.set({"scheduler-address": None}):
        assert scheduler_address() is None
    with dask.config.set({"scheduler-address": "tcp://from-config:1"}):
        assert scheduler_address() == "tcp://from-config:1"
        monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://from-env:2")
        assert scheduler_address() == "tcp://from-env:2"
        assert scheduler_address("tcp://given:3") == "tcp://given:3"


def _square_and_pid(x: int) -> tuple[int, int]:
    return x * x, os.getpid()


@pytest.mark.slow
def test_reproduce_map_runs_on_the_scheduler(cluster, tmp_path):
    """A paper experiment's own tasks (`ReproduceContext.map`, e.g. plbp's snapshots) go to
    the scheduler too, and come back in task order."""
    from cooploc.reproduce.base import ReproduceContext, ReproduceOptions

    options = ReproduceOptions(out=tmp_path, backend="dask", scheduler=cluster)
    context = ReproduceContext(options, tmp_path, runs=1, compared=[])
    results = context.map(_square_and_pid, list(range(7)), "squares")
    assert [r[0] for r in results] == [x * x for x in range(7)]
    assert os.getpid() not in {r[1] for r in results}
