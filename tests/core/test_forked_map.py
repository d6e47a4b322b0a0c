"""core.forked_map: the forked map equals the plain one, inherits an unpicklable job, keeps order."""

from __future__ import annotations

import os
import threading
import warnings

import numpy as np
import pytest

from material_structures.core.forked_map import forked_map


def _weighted_sum(job, item):
    lock, data = job  # a lock cannot be pickled: the job must be inherited, not sent
    with lock:
        return float(data[item[0]:item[1]].sum() * item[2]), os.getpid()


def test_forked_map_matches_plain_map_and_keeps_item_order():
    data = np.random.default_rng(0).normal(size=10_000)
    items = [(k * 1000, (k + 1) * 1000, k + 1) for k in range(7)]
    job = (threading.Lock(), data)
    plain = forked_map(_weighted_sum, job, items, workers=1)
    assert {pid for _, pid in plain} == {os.getpid()}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fork DeprecationWarning reaches the caller
        forked = forked_map(_weighted_sum, job, items, workers=3)
    assert [v for v, _ in forked] == [v for v, _ in plain]
    assert [v for v, _ in plain] == [float(data[a:b].sum() * w) for a, b, w in items]
    pids = {pid for _, pid in forked}
    assert os.getpid() not in pids and 1 <= len(pids) <= 3


def _fail_on_three(job, item):
    if item == 3:
        raise ValueError(f"bad item {item}")
    return item


def test_forked_map_raises_the_workers_error():
    with pytest.raises(ValueError, match="bad item 3"):
        forked_map(_fail_on_three, None, [1, 2, 3, 4], workers=2)
    assert forked_map(_fail_on_three, None, [1, 2], workers=2) == [1, 2]


def _die(job, item):
    if item == 1:
        os._exit(3)  # as if killed (e.g. for memory)
    return item


def test_a_dying_worker_raises_instead_of_hanging():
    from concurrent.futures.process import BrokenProcessPool

    with pytest.raises(BrokenProcessPool):
        forked_map(_die, None, [0, 1, 2], workers=2)


def _nested(job, item):
    return forked_map(_weighted_sum, job, [item], workers=2)[0][0], forked_map(_square, None, [1, 2, 3], workers=2)


def _square(job, item):
    return item * item, os.getpid()


def test_a_map_inside_a_worker_runs_in_that_worker():
    data = np.arange(100.0)
    out = forked_map(_nested, (threading.Lock(), data), [(0, 10, 1), (10, 20, 2)], workers=2)
    assert [v for v, _ in out] == [45.0, 2 * 145.0]
    for _, inner in out:
        assert [v for v, _ in inner] == [1, 4, 9] and len({pid for _, pid in inner}) == 1  # in-process
