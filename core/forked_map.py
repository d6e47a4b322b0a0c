"""Map a function over work items in forked processes that inherit a shared job.

The job (large arrays, a compiled scene with its ray-casting structures, a closure) is set in a
module global just before the fork, so the workers inherit it instead of receiving it pickled; only
the items and the results cross the process boundary. POSIX only: where ``fork`` is not available
(Windows) the map runs in this process.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Sequence
from typing import Any

_JOB: tuple[Callable, Any] | None = None
_LOCK = threading.Lock()  # one forked map at a time per process (the job is a global)


def _call(item):
    fn, job = _JOB
    return fn(job, item)


def forked_map(fn: Callable[[Any, Any], Any], job: Any, items: Sequence, workers: int) -> list:
    """``[fn(job, item) for item in items]`` in up to ``workers`` forked processes, results in item
    order. Runs in this process when ``workers`` <= 1, there is at most one item, or fork is missing."""
    import multiprocessing

    workers = min(int(workers), len(items))
    if workers <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        return [fn(job, item) for item in items]
    global _JOB
    with _LOCK:
        _JOB = (fn, job)
        try:
            with warnings.catch_warnings():
                # numpy's OpenBLAS thread pool makes every process "multi-threaded"; OpenBLAS
                # re-initialises in the child (pthread_atfork) and the workers take no lock that
                # another thread of this process could hold
                warnings.filterwarnings("ignore", message=r".*use of fork\(\) may lead to deadlocks",
                                        category=DeprecationWarning)
                with multiprocessing.get_context("fork").Pool(workers) as pool:
                    return pool.map(_call, items, chunksize=1)
        finally:
            _JOB = None
