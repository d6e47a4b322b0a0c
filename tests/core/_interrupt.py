"""Interrupting a command with its worker processes, as Ctrl-C does (SIGTERM here: a background shell
ignores SIGINT), and checking that it stopped cleanly."""

from __future__ import annotations

import glob
import signal
import subprocess
import time
from collections.abc import Callable


def children(pid: int) -> list[int]:
    kids = []
    for f in glob.glob(f"/proc/{pid}/task/*/children"):
        kids += [int(k) for k in open(f).read().split()]
    return kids


def interrupt_when(proc: subprocess.Popen, ready: Callable[[], bool], timeout: float) -> None:
    """Wait until ``ready()`` (the command is working), then SIGTERM it: it must exit 130 with the one
    line "interrupted" (no traceback, no log of its Dask cluster) and leave none of its child processes
    (workers) running."""
    t0 = time.monotonic()
    while not ready() and time.monotonic() - t0 < timeout:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    kids = children(proc.pid)
    assert kids  # the worker processes
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "interrupted", err[-2000:]
    # nothing else: no traceback, no log of a Dask cluster's shutdown (distributed's errors, issue 64)
    assert "Traceback" not in err and "distributed" not in err and "ERROR" not in err, err[-2000:]
    # every worker gone within a second (polled: most are gone at once)
    t0 = time.monotonic()
    while (alive := [k for k in kids if _running(k)]) and time.monotonic() - t0 < 1.0:
        time.sleep(0.05)
    assert alive == []


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False
