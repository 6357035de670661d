"""Backends that run independent tasks: `serial`, `processes` (standard library), `dask`.

`completed(fn, tasks, backend, workers)` yields (task index, `fn(task)`) as each task
finishes, in completion order; the caller puts results back in task order if it
needs to (`cooploc.experiment` does, so that numbers do not depend on the backend).
Tasks are taken lazily: at most `IN_FLIGHT_PER_WORKER` per worker are handed out
ahead, so a long task list is never materialised, and stopping the iteration (an
interrupt, an error in the caller) cancels the tasks not started. Worker processes
are single-threaded (BLAS/OpenMP), so that n workers use n cores.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterable, Iterator, Sized
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import TypeVar

from cooploc.errors import ConfigError

__all__ = ["BACKENDS", "IN_FLIGHT_PER_WORKER", "completed"]

BACKENDS: tuple[str, ...] = ("serial", "processes", "dask")
T = TypeVar("T")
R = TypeVar("R")


def _worker_init() -> None:
    # Workers are single-threaded so that n workers use n cores, not n × BLAS threads.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


IN_FLIGHT_PER_WORKER = 2  # tasks handed out ahead per worker: busy workers, no big queue


def completed(fn: Callable[[T], R], tasks: Iterable[T], backend: str = "processes",
              workers: int | None = None) -> Iterator[tuple[int, R]]:
    """(task index, `fn(task)`) of every task as it finishes (completion order).

    `fn` is a module-level function (it is pickled by reference for the workers).

    `tasks` is consumed lazily: at most IN_FLIGHT_PER_WORKER tasks per worker are
    submitted ahead. Closing the generator (the caller stopped or was interrupted)
    cancels the tasks not started yet.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    n_workers = workers or os.cpu_count() or 1
    if isinstance(tasks, Sized):
        n_workers = max(min(n_workers, len(tasks)), 1)
        if len(tasks) == 1:
            backend = "serial"  # one task: no pool to start
    numbered = enumerate(tasks)
    if backend == "serial" or (backend == "processes" and n_workers == 1):
        for i, task in numbered:
            yield i, fn(task)
    elif backend == "processes":
        yield from _process_results(fn, numbered, n_workers)
    else:
        yield from _dask_results(fn, numbered, n_workers)


def _process_results(fn: Callable[[T], R], numbered: Iterator[tuple[int, T]], workers: int
                     ) -> Iterator[tuple[int, R]]:
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init)
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


def _dask_results(fn: Callable[[T], R], numbered: Iterator[tuple[int, T]], workers: int
                  ) -> Iterator[tuple[int, R]]:
    """Run tasks on the current dask.distributed client, or a local cluster of `workers`."""
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed
    except ImportError as exc:
        raise ConfigError(
            "backend 'dask' needs the dask extra: pip install 'cooploc[dask]'"
        ) from exc
    try:
        client, own = Client.current(), False
    except ValueError:  # no client yet: start a local one for this experiment
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client, own = Client(cluster), True
    try:
        index: dict[str, int] = {}
        queue = dask_completed()

        def submit(i: int, task: T) -> None:
            future = client.submit(fn, task, pure=False)
            index[future.key] = i
            queue.add(future)

        # a cluster of its own size may be bigger than `workers`: keep all of it busy
        workers = max(workers, len(client.scheduler_info().get("workers", {})))
        for i, task in itertools.islice(numbered, IN_FLIGHT_PER_WORKER * workers):
            submit(i, task)
        for future in queue:  # futures added while iterating are waited for too
            for i, task in itertools.islice(numbered, 1):
                submit(i, task)
            yield index.pop(future.key), future.result()
    finally:
        if own:
            client.close()
            cluster.close()
