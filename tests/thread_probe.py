"""A task that reports the threads of the process it runs in (for tests/test_threads.py and
tests/test_dask_scheduler.py; a module of its own so that worker processes can import it)."""

from __future__ import annotations

import os
from typing import Any

from cooploc.backends import THREAD_VARIABLES


def thread_report(_task: Any = None) -> dict[str, Any]:
    """BLAS/OpenMP pools (threadpoolctl), numba's thread count and the thread variables of
    this process, after loading what a run loads (numpy, scipy.linalg, numba)."""
    import numba
    import scipy.linalg  # noqa: F401  (scipy's own BLAS, if it bundles one, loads here)
    from threadpoolctl import threadpool_info

    return {"pools": [(p["internal_api"], p["num_threads"]) for p in threadpool_info()],
            "libraries": [p["filepath"] for p in threadpool_info()],
            "numba": numba.get_num_threads(),
            "env": {var: os.environ.get(var) for var in THREAD_VARIABLES},
            "pid": os.getpid()}
