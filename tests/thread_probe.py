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

    # libsumo (the sumo extra) bundles its own libgomp and an OpenMP-built OpenBLAS, loaded
    # once a SUMO scenario ran in this process; those copies serve SUMO's simulation, not
    # cooploc's arithmetic, and threadpoolctl cannot reliably set or restore them (OpenMP's
    # thread count is per calling thread), so they are reported apart.
    pools = threadpool_info()
    ours = [p for p in pools if "libsumo" not in p["filepath"]]
    return {"pools": [(p["internal_api"], p["num_threads"]) for p in ours],
            "libraries": [p["filepath"] for p in ours],
            "sumo_pools": [(p["internal_api"], p["num_threads"]) for p in pools if p not in ours],
            "numba": numba.get_num_threads(),
            "env": {var: os.environ.get(var) for var in THREAD_VARIABLES},
            "pid": os.getpid()}
