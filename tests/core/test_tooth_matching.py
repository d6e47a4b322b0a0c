"""Matching capture teeth to a scene's teeth by position (``core/teeth/tooth_matching.py``): the assignment
against brute force over every permutation, and the matching of an arch moved and reordered."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from material_structures.core.teeth.tooth_matching import match_by_position, min_cost_assignment


@pytest.mark.parametrize("shape", [(1, 1), (3, 3), (4, 6), (6, 6), (5, 7)])
def test_assignment_costs_what_brute_force_finds(shape):
    """The least total over every injective choice of columns, to 1e-12, on 20 random matrices per shape
    (integer costs too: ties)."""
    rng = np.random.default_rng(sum(shape))
    n, m = shape
    for trial in range(20):
        cost = rng.random((n, m)) if trial % 2 else rng.integers(0, 4, (n, m)).astype(float)
        col = min_cost_assignment(cost)
        assert len(set(col.tolist())) == n and col.min() >= 0 and col.max() < m
        best = min(sum(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(m), n))
        assert cost[np.arange(n), col].sum() == pytest.approx(best, abs=1e-12)


def test_assignment_refuses_more_rows_than_columns_and_nan():
    with pytest.raises(ValueError, match="n <= m"):
        min_cost_assignment(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="NaN"):
        min_cost_assignment(np.array([[0.0, np.nan]]))


def _arch(n: int) -> np.ndarray:
    """n tooth centres on a parabolic arch (mm), 8 mm apart along x."""
    x = (np.arange(n) - (n - 1) / 2) * 8.0
    return np.stack([x, 0.02 * x**2, np.zeros(n)], axis=1)


def test_a_moved_and_reordered_arch_maps_back_tooth_by_tooth():
    """16 teeth, moved 40 mm and listed in another order, each jittered by up to 1 mm: every capture tooth finds
    its own tooth."""
    rng = np.random.default_rng(3)
    capture = _arch(16)
    order = rng.permutation(16)
    scene = capture[order] + np.array([40.0, -12.0, 5.0]) + rng.uniform(-1, 1, (16, 3))
    got = match_by_position(capture, scene)
    assert [order[j] for j in got] == list(range(16))


def test_unequal_counts_leave_the_extra_teeth_unmapped():
    """8 capture teeth, a scene with the middle 6: the 6 map to themselves, the two ends get nothing; and a scene
    with more teeth than the capture gives every capture tooth one."""
    capture = _arch(8)
    got = match_by_position(capture, capture[1:7])
    assert got == [None, 0, 1, 2, 3, 4, 5, None]
    assert match_by_position(capture[1:7], capture) == [1, 2, 3, 4, 5, 6]
    assert match_by_position(capture, np.zeros((0, 3))) == [None] * 8
