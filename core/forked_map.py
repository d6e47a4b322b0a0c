"""Map a function over work items in forked processes that inherit a shared job.

The job (large arrays, a compiled scene with its ray-casting structures, a closure) is set in a
module global just before the fork, so the workers inherit it instead of receiving it pickled; only
the items and the results cross the process boundary. POSIX only: where ``fork`` is not available
(Windows), and inside a worker (no nested pools), the map runs in the calling process.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

_JOB: tuple[Callable, Any] | None = None
_LOCK = threading.Lock()  # one forked map at a time per process (the job is a global)
_IN_WORKER = False


def _mark_worker() -> None:
    global _IN_WORKER
    _IN_WORKER = True


def _call(item):
    fn, job = _JOB
    return fn(job, item)


@contextmanager
def fork_warning_silenced() -> Iterator[None]:
    """Silence Python's "multi-threaded, use of fork() may lead to deadlocks" DeprecationWarning: numpy's
    OpenBLAS thread pool (and an executor's manager thread) make this process "multi-threaded";
    OpenBLAS re-initialises in the child (pthread_atfork) and our workers take no lock that another
    thread of this process could hold."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*use of fork\(\) may lead to deadlocks",
                                category=DeprecationWarning)
        yield


def forked_map(fn: Callable[[Any, Any], Any], job: Any, items: Sequence, workers: int) -> list:
    """``[fn(job, item) for item in items]`` in up to ``workers`` forked processes, results in item
    order. Runs in this process when ``workers`` <= 1, there is at most one item, fork is missing or
    this is itself a worker. A worker that dies (e.g. killed for memory) raises
    ``concurrent.futures.process.BrokenProcessPool`` instead of hanging."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    workers = min(int(workers), len(items))
    if workers <= 1 or _IN_WORKER or "fork" not in multiprocessing.get_all_start_methods():
        return [fn(job, item) for item in items]
    global _JOB
    with _LOCK:
        _JOB = (fn, job)
        try:
            with fork_warning_silenced():
                with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                         initializer=_mark_worker) as pool:
                    return list(pool.map(_call, items))
        finally:
            _JOB = None
