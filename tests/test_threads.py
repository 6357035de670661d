"""Thread discipline (issue 17 item 5): a worker process runs one BLAS/OpenMP/numba thread,
set before the libraries it loads later read their counts, and limited with threadpoolctl
for those loaded already; `limit_threads` (``--threads``) bounds the serial backend."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cooploc.backends import THREAD_VARIABLES, completed, limit_threads
from cooploc.cli import app
from cooploc.errors import ConfigError
from thread_probe import thread_report


def _single_threaded(report: dict) -> None:
    assert report["pools"], "threadpoolctl found no BLAS/OpenMP library"
    assert all(n == 1 for _, n in report["pools"]), report
    assert report["numba"] == 1, report
    # NUMBA_NUM_THREADS stays as it was where numba was loaded before (numba would refuse a
    # changed value at its next compilation); set_num_threads limits it instead
    assert all(report["env"][var] == "1" for var in THREAD_VARIABLES if var != "NUMBA_NUM_THREADS"), report


def test_process_workers_run_one_thread():
    thread_report()  # the parent has loaded numpy, scipy and numba (and their pools) before forking
    reports = [r for _, r in completed(thread_report, range(4), "processes", workers=2)]
    assert len(reports) == 4
    for report in reports:
        _single_threaded(report)


def test_limit_threads_bounds_this_process_and_restores():
    before = thread_report()
    with limit_threads(1):
        assert all(n == 1 for _, n in thread_report()["pools"])
    after = thread_report()
    # A library first loaded inside the block (numba's OpenMP layer, say, once set_num_threads
    # runs) is not in `before`; the promise is about the libraries that were there.
    threads_before = dict(zip(before["libraries"], (n for _, n in before["pools"]), strict=True))
    threads_after = dict(zip(after["libraries"], (n for _, n in after["pools"]), strict=True))
    assert {lib: threads_after[lib] for lib in threads_before} == threads_before, (before, after)
    assert after["env"] == before["env"]


def test_limit_threads_none_changes_nothing():
    before = thread_report()
    with limit_threads(None):
        assert thread_report() == before


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_limit_threads_refuses_a_bad_count(bad):
    with pytest.raises(ConfigError, match="threads must be a positive integer"), limit_threads(bad):
        pass


@pytest.mark.parametrize(("args", "message"), [
    (["--backend", "processes", "--threads", "2"], "--threads sets the threads of the serial backend"),
    (["--backend", "serial", "--threads", "0"], "--threads must be a positive integer, got 0"),
])
def test_cli_threads_is_for_the_serial_backend(tmp_path, args, message):
    result = CliRunner().invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "--runs", "1", *args,
                                      "--no-progress", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not (tmp_path / "out").exists()


def test_cli_threads_runs_the_serial_backend(tmp_path):
    result = CliRunner().invoke(app, ["run", "froehle2018", "-e", "gnss-kf", "--runs", "1", "--set",
                                      "n_steps=5", "--backend", "serial", "--threads", "1", "--no-progress",
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / "summary.json").is_file()


def test_a_worker_compiles_after_one_thread_where_numba_was_loaded(tmp_path):
    """numba reads NUMBA_NUM_THREADS again at each compilation and raises once its pool has
    started with another count: a worker that had numba loaded (forked from a parent that
    used it) must still compile new parallel kernels after `one_thread`."""
    import subprocess
    import sys

    code = (
        "import numba, numpy as np\n"
        "from cooploc.backends import one_thread\n"
        "one_thread()\n"
        "@numba.njit(parallel=True)\n"
        "def f(x):\n"
        "    s = 0.0\n"
        "    for i in numba.prange(x.size):\n"
        "        s += x[i]\n"
        "    return s\n"
        "print(f(np.ones(10)), numba.get_num_threads())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["10.0", "1"]
