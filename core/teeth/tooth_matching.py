"""Which tooth of a Blender scene a capture tooth is: matching the two sets of teeth by where they stand.

A capture's teeth carry names (``scene.json``) that teeth made in Blender need not share; the Teeth panel maps
each capture tooth to a tooth of the scene by name, or by position with :func:`match_by_position`. Positions are
the teeth's centres in millimetres (a Blender tooth's world centre times the scene's millimetres per unit); both
sets are moved so that their centres of mass coincide (a scene built where the capture's teeth stand, or the same
arch moved elsewhere), and the pairing minimises the sum of the distances between paired centres: the linear
assignment problem, solved exactly by :func:`min_cost_assignment` (the Hungarian method with potentials, O(n^3);
a smile has at most 32 teeth, and scipy is not among the modules a desktop Blender bundles).
"""

from __future__ import annotations

import numpy as np

__all__ = ["match_by_position", "min_cost_assignment"]


def min_cost_assignment(cost: np.ndarray) -> np.ndarray:
    """``col[i]`` for each row ``i`` of the ``(n, m)`` matrix ``cost`` (n <= m): distinct columns minimising
    ``sum_i cost[i, col[i]]``. Shortest augmenting paths with row and column potentials u, v kept feasible
    (``cost[i, j] - u[i] - v[j] >= 0``, equality on every assigned pair), one row added per round."""
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] > c.shape[1]:
        raise ValueError(f"cost must be an (n, m) matrix with n <= m, got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("cost has values that are NaN or infinite")
    n, m = c.shape
    u, v = np.zeros(n + 1), np.zeros(m + 1)
    row_of = np.zeros(m + 1, dtype=np.int64)  # row_of[j]: the row (1-based) assigned to column j; 0: none
    way = np.zeros(m + 1, dtype=np.int64)
    for i in range(1, n + 1):
        row_of[0] = i
        j0 = 0
        minv = np.full(m + 1, np.inf)
        used = np.zeros(m + 1, dtype=bool)
        while True:
            used[j0] = True
            i0 = row_of[j0]
            free = ~used[1:]
            reduced = c[i0 - 1] - u[i0] - v[1:]
            better = free & (reduced < minv[1:])
            minv[1:][better] = reduced[better]
            way[1:][better] = j0
            cand = np.where(free, minv[1:], np.inf)
            j1 = int(np.argmin(cand)) + 1
            delta = cand[j1 - 1]
            u[row_of[used]] += delta
            v[used] -= delta
            minv[1:][free] -= delta
            j0 = j1
            if row_of[j0] == 0:
                break
        while j0 != 0:  # augment along the path
            j1 = way[j0]
            row_of[j0] = row_of[j1]
            j0 = j1
    col = np.full(n, -1, dtype=np.int64)
    for j in range(1, m + 1):
        if row_of[j] > 0:
            col[row_of[j] - 1] = j - 1
    return col


def match_by_position(capture_centres: np.ndarray, scene_centres: np.ndarray) -> list[int | None]:
    """For each capture tooth (centres ``(n, 3)`` in mm), the index of the scene tooth (``(m, 3)`` in mm) at its
    place once both sets' centres of mass coincide; the pairing with the least total distance. With fewer scene
    teeth than capture teeth, the capture teeth left over get ``None``."""
    a = np.asarray(capture_centres, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(scene_centres, dtype=np.float64).reshape(-1, 3)
    if len(a) == 0 or len(b) == 0:
        return [None] * len(a)
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    dist = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    if len(a) <= len(b):
        return [int(j) for j in min_cost_assignment(dist)]
    out: list[int | None] = [None] * len(a)
    for j, i in enumerate(min_cost_assignment(dist.T)):  # every scene tooth gets a capture tooth
        out[int(i)] = j
    return out
