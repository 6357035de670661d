"""Backends that run independent tasks: `serial`, `processes` (standard library), `dask`.

`completed(fn, tasks, backend, workers)` yields (task index, `fn(task)`) as each task
finishes, in completion order; the caller puts results back in task order if it
needs to (`cooploc.experiment` does, so that numbers do not depend on the backend).
Tasks are taken lazily: at most `IN_FLIGHT_PER_WORKER` per worker are handed out
ahead, so a long task list is never materialised, and stopping the iteration (an
interrupt, an error in the caller) cancels the tasks not started.

Dask
----
`dask` sends the tasks to a running Dask scheduler when it has an address: the
`scheduler` argument (``--scheduler tcp://HOST:PORT``), else the environment variable
``DASK_SCHEDULER_ADDRESS``, else Dask's own configuration key ``scheduler-address``;
else to the current `dask.distributed.Client` of the process; else it starts a
`LocalCluster` of `workers` single-threaded processes for the experiment. Results are
taken as they complete (`distributed.as_completed`) and released at once, and the
tasks in flight follow the cluster's thread count as workers join or leave. Each task
is pickled on its own (for an experiment: the configuration and the run number, never
a recording), so the workers need cooploc installed, nothing else from this machine.

Threads
-------
A worker runs one BLAS/OpenMP/numba thread, so that n workers use n cores and no
more (`one_thread`): the environment variables ``OMP_NUM_THREADS``,
``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS`` and ``NUMBA_NUM_THREADS`` are set for the
libraries the worker loads later, and threadpoolctl limits the ones it has loaded
already (a forked worker inherits its parent's OpenBLAS, whose thread count was read
when it loaded). numba's pool, once started, cannot grow past the count it started
with, and numba refuses a changed ``NUMBA_NUM_THREADS`` at its next compilation once
the pool has started, so where numba is loaded already only `numba.set_num_threads` is
applied to it. The serial backend runs in
the calling process with the libraries' own defaults (every core), or with
`limit_threads(n)` around it (``--threads N``).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import sys
from collections.abc import Callable, Iterable, Iterator, Sized
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, TypeVar

from cooploc.errors import ConfigError

__all__ = ["BACKENDS", "IN_FLIGHT_PER_WORKER", "THREAD_VARIABLES", "completed", "limit_threads",
           "one_thread", "scheduler_address"]

BACKENDS: tuple[str, ...] = ("serial", "processes", "dask")
T = TypeVar("T")
R = TypeVar("R")

#: the environment variables that set the thread count of BLAS, OpenMP and numba at load time
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")

IN_FLIGHT_PER_WORKER = 2  # tasks handed out ahead per worker: busy workers, no big queue
CONNECT_TIMEOUT = "20s"  # to reach a Dask scheduler (a refused connection is retried until then)


def _set_threads(n: int) -> Callable[[], None]:
    """Limit BLAS/OpenMP/numba threads to `n` in this process; returns the undo."""
    from threadpoolctl import threadpool_limits

    numba_loaded = "numba" in sys.modules  # not imported for this: importing numba costs a second
    # numba reads NUMBA_NUM_THREADS again at every compilation and refuses a changed value
    # once its pool has started, so once it is loaded only set_num_threads limits it
    variables = [v for v in THREAD_VARIABLES if not (numba_loaded and v == "NUMBA_NUM_THREADS")]
    before = {var: os.environ.get(var) for var in variables}
    for var in variables:  # libraries loaded from now on read these
        os.environ[var] = str(n)
    limits = threadpool_limits(n)  # the libraries loaded already
    numba_before = None
    if numba_loaded:
        import numba

        numba_before = numba.get_num_threads()
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))

    def undo() -> None:
        limits.restore_original_limits()
        if numba_before is not None:
            import numba

            numba.set_num_threads(numba_before)
        for var, value in before.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value

    return undo


def one_thread() -> None:
    """Make this worker process single-threaded (BLAS, OpenMP, numba), for good (see
    "Threads" in the module docstring): the initializer of the process pool, and run
    once in each dask worker before its first task."""
    global _ONE_THREAD_PID
    if _ONE_THREAD_PID != os.getpid():
        _set_threads(1)
        _ONE_THREAD_PID = os.getpid()


# The process in which `one_thread` ran: a pid, not a flag, because a forked worker
# inherits the parent's globals, and a parent that ran it once must not excuse its children.
_ONE_THREAD_PID: int | None = None


@contextlib.contextmanager
def limit_threads(n: int | None) -> Iterator[None]:
    """At most `n` BLAS/OpenMP/numba threads in this process inside the block (the serial
    backend's ``--threads``); None leaves the libraries' defaults. A library first loaded
    inside the block keeps `n` threads afterwards (it reads the count when it loads)."""
    if n is None:
        yield
        return
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"threads must be a positive integer, got {n!r}")
    undo = _set_threads(n)
    try:
        yield
    finally:
        undo()


def scheduler_address(scheduler: str | None = None) -> str | None:
    """The Dask scheduler to send work to: `scheduler`, else ``DASK_SCHEDULER_ADDRESS``,
    else Dask's configuration key ``scheduler-address`` (None: no existing cluster)."""
    if scheduler:
        return scheduler
    if os.environ.get("DASK_SCHEDULER_ADDRESS"):
        return os.environ["DASK_SCHEDULER_ADDRESS"]
    if "dask" in sys.modules or _module_exists("dask"):
        import dask

        return dask.config.get("scheduler-address", None) or None
    return None


def _module_exists(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None


def completed(fn: Callable[[T], R], tasks: Iterable[T], backend: str = "processes",
              workers: int | None = None, *, scheduler: str | None = None,
              announce: Callable[[str], None] | None = None) -> Iterator[tuple[int, R]]:
    """(task index, `fn(task)`) of every task as it finishes (completion order).

    `fn` is a module-level function (it is pickled by reference for the workers).

    `tasks` is consumed lazily: at most IN_FLIGHT_PER_WORKER tasks per worker are
    submitted ahead. Closing the generator (the caller stopped or was interrupted)
    cancels the tasks not started yet. `scheduler` is the address of a running Dask
    scheduler (dask backend only; see `scheduler_address` for the default);
    `announce` is called with one line saying where a dask backend runs (cluster,
    workers, dashboard link).
    """
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if scheduler is not None and backend != "dask":
        raise ConfigError(f"a scheduler address applies to the dask backend, not {backend}; "
                          f"got scheduler = {scheduler!r}")
    n_workers = workers or os.cpu_count() or 1
    if isinstance(tasks, Sized):
        if len(tasks) == 0:  # e.g. a resumed experiment with every run done: no cluster to reach
            return
        n_workers = min(n_workers, len(tasks))
        if len(tasks) == 1 and (backend == "processes" or scheduler_address(scheduler) is None):
            backend = "serial"  # one task: no pool or local cluster to start (a named cluster gets it)
    numbered = enumerate(tasks)
    if backend == "serial" or (backend == "processes" and n_workers == 1):
        for i, task in numbered:
            yield i, fn(task)
    elif backend == "processes":
        yield from _process_results(fn, numbered, n_workers)
    else:
        yield from _dask_results(fn, numbered, n_workers, scheduler_address(scheduler), announce)


def _process_results(fn: Callable[[T], R], numbered: Iterator[tuple[int, T]], workers: int
                     ) -> Iterator[tuple[int, R]]:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=one_thread)
    pending: dict[Future[R], int] = {}
    try:
        for i, task in itertools.islice(numbered, IN_FLIGHT_PER_WORKER * workers):
            pending[pool.submit(fn, task)] = i
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in sorted(done, key=pending.__getitem__):  # a stable order among ties
                for i, task in itertools.islice(numbered, 1):
                    pending[pool.submit(fn, task)] = i
                yield pending.pop(future), future.result()
    finally:
        pool.shutdown(wait=not pending, cancel_futures=True)


def _one_thread_call(fn: Callable[[T], R], task: T) -> R:
    """`fn(task)` in a single-threaded dask worker (`one_thread` on its first task)."""
    one_thread()
    return fn(task)


def _dask_results(fn: Callable[[T], R], numbered: Iterator[tuple[int, T]], workers: int,
                  address: str | None, announce: Callable[[str], None] | None
                  ) -> Iterator[tuple[int, R]]:
    """Run tasks on the scheduler at `address`, the current client, or a local cluster of
    `workers`; see "Dask" in the module docstring."""
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:
        raise ConfigError(
            "backend 'dask' needs the dask extra: pip install 'cooploc[dask]'"
        ) from exc
    cluster = None
    if address is not None:
        try:
            client = Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            first_line = (str(exc).strip().splitlines() or [""])[0]
            raise ConfigError(f"scheduler: cannot reach a Dask scheduler at {address!r} "
                              f"({type(exc).__name__}: {first_line})") from None
        where, own_client = f"Dask scheduler {address}", True
    else:
        try:
            client, own_client = Client.current(), False
            where = f"the current Dask client's scheduler {client.scheduler.address}"
        except ValueError:  # no client yet: start a local one for this experiment
            # reachable from this machine only; the scheduler's web server (the dashboard
            # where bokeh is installed) at a free port, never a fixed one that may be taken
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address="127.0.0.1:0")
            client, own_client = Client(cluster, set_as_default=False), True
            where = f"a local Dask cluster of {workers} workers"
    pending: dict[str, tuple[int, Any]] = {}  # future key: (task index, future)
    queue = dask_completed(loop=client.loop)
    threads = _Threads(client, minimum=workers if cluster is not None else 1)
    try:
        if announce is not None:
            link = client.dashboard_link if _has_dashboard(client) else "none"
            if cluster is not None and not _module_exists("bokeh"):  # the page would only say so
                link = "none (it needs bokeh: pip install bokeh)"
            threads.now()
            announce(f"{where}: {threads.found} worker threads; dashboard: {link}")

        def top_up() -> None:
            # as many tasks ahead as the cluster has threads (workers may join or leave)
            ahead = IN_FLIGHT_PER_WORKER * threads.now() - len(pending)
            for i, task in itertools.islice(numbered, max(ahead, 0)):
                future = client.submit(_one_thread_call, fn, task, pure=False)
                pending[future.key] = (i, future)
                queue.add(future)

        top_up()
        for future in queue:  # futures added while iterating are waited for too
            try:
                result = future.result()
            except (ModuleNotFoundError, RuntimeError) as exc:
                _raise_if_not_installed(exc, where)
                raise
            i, _ = pending.pop(future.key)
            future.release()  # its result is ours now: the cluster may forget it
            top_up()
            yield i, result
    finally:
        if pending:  # stopped early: what is queued or running is not wanted any more
            with contextlib.suppress(Exception):
                client.cancel([f for _, f in pending.values()])
        if own_client:
            client.close()
        if cluster is not None:
            cluster.close()


def _raise_if_not_installed(exc: BaseException, where: str) -> None:
    """A `ConfigError` for a task that the scheduler or a worker could not unpickle (the code
    is not installed there); other exceptions are left alone."""
    if isinstance(exc, ModuleNotFoundError):
        what = f"a Dask worker of {where} cannot import {exc.name!r}"
    elif "deserializ" in str(exc):  # the scheduler unpickles the task graph too
        what = f"{where} cannot unpickle the runs ({str(exc).splitlines()[0].strip()})"
    else:
        return
    raise ConfigError(f"{what}: install cooploc, with the extras and plug-ins the experiment uses, "
                      f"on the scheduler and on every worker") from exc


class _Threads:
    """The worker threads of a client's cluster: `found` when last asked, `now()` at least
    `minimum`; the scheduler is asked at most once every `REFRESH_SECONDS` (a round trip)."""

    REFRESH_SECONDS = 2.0

    def __init__(self, client: Any, minimum: int) -> None:
        self.client, self.minimum = client, minimum
        self.count, self.found, self.asked = minimum, 0, -float("inf")

    def now(self) -> int:
        import time

        if time.monotonic() - self.asked >= self.REFRESH_SECONDS:
            try:
                info = self.client.scheduler_info(n_workers=-1)  # every worker, not the first few
            except TypeError:  # distributed before 2025 lists every worker anyway
                info = self.client.scheduler_info()
            self.found = sum(int(w.get("nthreads", 1)) for w in info.get("workers", {}).values())
            self.count, self.asked = max(self.found, self.minimum), time.monotonic()
        return self.count


def _has_dashboard(client: Any) -> bool:
    """Whether the scheduler serves a dashboard (it needs bokeh where the scheduler runs)."""
    return "dashboard" in client.scheduler_info().get("services", {})
