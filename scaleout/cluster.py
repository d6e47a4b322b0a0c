"""Connecting to a Dask cluster, or starting a local one sized to the machine."""

from __future__ import annotations

import contextlib
import logging
import os

from ..core.errors import UserError

SCHEDULER_TIMEOUT_S = 10  # an address that does not answer: a mistyped host or port, or a scheduler not started


def _connect(scheduler: str):
    from distributed import Client

    try:
        return Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
    except ValueError as exc:  # "missing port number", "unknown address scheme"
        raise UserError(f"--scheduler {scheduler!r} is not a Dask scheduler address ({exc}); give one like "
                        "tcp://HOST:8786") from None
    except OSError as exc:
        raise UserError(f"no Dask scheduler answers at {scheduler} within {SCHEDULER_TIMEOUT_S} s: start one "
                        "(dask scheduler) or leave out --scheduler to use this machine's cores") from exc


def check_scheduler(scheduler: str) -> None:
    """Refuse a --scheduler that is not an address or where no scheduler answers, before a fit writes
    anything (the fit connects again when it needs the cluster)."""
    _connect(scheduler).close()


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None, threads_per_worker: int = 1):
    """``Client`` for ``scheduler`` (``tcp://host:8786``) or a local cluster of ``n_workers`` processes.

    The local default has one single-threaded worker process per core, so numpy's own threads do
    not oversubscribe the machine; the compiled teeth tracer (numba) in each worker gets as many
    threads as the worker has (it would otherwise start one per core in every worker).
    """
    from distributed import Client, LocalCluster

    if scheduler:
        client = _connect(scheduler)
        try:
            with _quiet_on_interrupt():
                yield client
        finally:
            client.close()
        return
    n_workers = n_workers or os.cpu_count() or 1
    with LocalCluster(
        n_workers=n_workers,
        threads_per_worker=threads_per_worker,
        processes=True,
        env={"NUMBA_NUM_THREADS": str(threads_per_worker)},
        dashboard_address=None,
        silence_logs=logging.CRITICAL,  # a worker's errors reach the client as the task's exception
    ) as cluster, Client(cluster) as client, _quiet_on_interrupt():
        yield client


@contextlib.contextmanager
def _quiet_on_interrupt():
    """Ctrl-C (or SIGTERM) while the cluster works: the command says "interrupted" and nothing else. The
    cluster's shutdown under an interrupt logs lost connections and cancelled tasks as errors (distributed,
    tornado, asyncio): those loggers are silenced before it starts."""
    try:
        yield
    except (KeyboardInterrupt, SystemExit):
        for name in ("distributed", "tornado", "asyncio"):
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        raise
