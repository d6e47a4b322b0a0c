"""``core.teeth.work_queue.take_next``: every part is taken exactly once when threads share the counter."""

import numpy as np
import pytest
from numba import get_num_threads, njit, prange

from material_structures.core.teeth.work_queue import take_next


@njit(parallel=True, cache=False)
def _take_all(n_parts, counter, taken, per_worker):
    for w in prange(get_num_threads()):
        while True:
            part = take_next(counter)
            if part >= n_parts:
                break
            taken[part] += 1  # only the thread that took ``part`` writes here
            per_worker[w] += 1


def test_every_part_is_taken_once_by_some_thread():
    if get_num_threads() < 2:
        pytest.skip("needs two threads to share the counter")
    n_parts = 2_000_000
    counter = np.zeros(1, dtype=np.int64)
    taken = np.zeros(n_parts, dtype=np.int64)
    per_worker = np.zeros(get_num_threads(), dtype=np.int64)
    _take_all(n_parts, counter, taken, per_worker)
    assert np.all(taken == 1)
    assert per_worker.sum() == n_parts
    assert (per_worker > 0).sum() >= 2  # the threads did share the counter
    # each worker stops after one take past the end
    assert counter[0] == n_parts + get_num_threads()


def test_take_next_returns_the_old_value():
    c = np.array([41], dtype=np.int64)

    @njit(cache=False)
    def once(c):
        return take_next(c)

    assert once(c) == 41 and c[0] == 42
