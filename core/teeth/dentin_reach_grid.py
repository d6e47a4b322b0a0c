"""Which points may lie within the blend's reach of a tooth's dentin: a conservative voxel mask.

A scattering vertex in a tooth needs the signed distance q to the dentin surface for the blend
l(q) = (1 + tanh(q / 2 s)) / 2 (eq. 5.15). Beyond ``BLEND_REACH`` spreads, l(q) is 0 or 1 to the last
bit and dl/dq = 0, so the tracer searches the dentin only that far (``path_tracer_compiled._dentin_query``).
With a sharp boundary (s of 1e-5 mm, as in captures from renderers with a sharp interface) that reach is
micrometres and almost no vertex finds a triangle, yet the closest-point search still walks every tree
node whose box holds the point. This grid answers "no dentin triangle within reach" in one lookup for
most points.

Cell (i, j, k) of tooth t covers [lo + i h, lo + (i + 1) h) per axis (h the cell size) and is marked when
the distance from its centre c to some dentin triangle is below R + h sqrt(3) / 2 (R the reach, plus a
relative margin for rounding). For a point p in the cell, |p - c| <= h sqrt(3) / 2, so by the triangle
inequality dist(p, T) < R implies dist(c, T) < R + h sqrt(3) / 2: a point whose cell is unmarked, or
that lies outside the grid (the dentin's bounding box grown by more than R), has no triangle within R,
exactly the case in which the search would find none. The mask never changes what the tracer computes,
only how often it searches.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import numba_kernels as _numba_kernels
from .bvh import closest_point_triangle

_numba_kernels.activate()  # before any cached njit: the kernel cache locator, then numba_callable's overloads

CELLS_LONGEST_AXIS = 96  # cells along the longest axis of a tooth's dentin box
MAX_REACH_CELLS = 2.0  # no grid where the reach spans more cells than this: nearly every cell would be marked
MARGIN = 1e-6  # relative slack on the marking radius (distances are float64; the test must stay conservative)


def dentin_reach_grid(tris: np.ndarray, dentin_tooth: np.ndarray, n_teeth: int, reach: float) -> tuple:
    """The mask of every tooth for the search radius ``reach``: (lo (n, 3), inverse cell size (n,),
    cells per axis (n, 3), offset of each tooth's cells in ``flags`` (n,), flags uint8). A tooth gets no
    grid (0 cells: every point is searched) when the reach spans more than ``MAX_REACH_CELLS`` cells."""
    lo = np.zeros((n_teeth, 3))
    inv = np.zeros(n_teeth)
    dims = np.zeros((n_teeth, 3), dtype=np.int64)
    offs = np.zeros(n_teeth, dtype=np.int64)
    parts = []
    n = 0
    for t in range(n_teeth):
        ids = np.flatnonzero(dentin_tooth == t)
        offs[t] = n
        if len(ids) == 0 or not np.isfinite(reach):
            continue
        pts = tris[ids].reshape(-1, 3)
        size = float((pts.max(axis=0) - pts.min(axis=0)).max())
        h = size / CELLS_LONGEST_AXIS
        if not h > 0 or reach > MAX_REACH_CELLS * h:
            continue
        radius = (reach + 0.5 * np.sqrt(3.0) * h) * (1.0 + MARGIN)
        box_lo = pts.min(axis=0) - radius - h
        dim = np.ceil((pts.max(axis=0) + radius + h - box_lo) / h).astype(np.int64)
        flags = np.zeros(int(np.prod(dim)), dtype=np.uint8)
        _mark(tris, ids.astype(np.int64), box_lo, h, dim, radius, flags)
        lo[t], inv[t], dims[t] = box_lo, 1.0 / h, dim
        parts.append(flags)
        n += len(flags)
    flat = np.concatenate(parts) if parts else np.zeros(1, dtype=np.uint8)
    return lo, inv, dims, offs, flat


@njit(cache=True)
def _mark(tris, ids, lo, h, dim, radius, flags) -> None:
    """Mark every cell whose centre lies within ``radius`` of one of the triangles ``ids``."""
    c = np.empty(3)
    bary = np.empty(3)
    lo_i = np.empty(3, dtype=np.int64)
    hi_i = np.empty(3, dtype=np.int64)
    for k in ids:
        for a in range(3):
            mn = min(tris[k, 0, a], min(tris[k, 1, a], tris[k, 2, a])) - radius
            mx = max(tris[k, 0, a], max(tris[k, 1, a], tris[k, 2, a])) + radius
            # cells whose centre lo + (i + 1/2) h lies in [mn, mx]
            lo_i[a] = max(int(np.floor((mn - lo[a]) / h - 0.5)), 0)
            hi_i[a] = min(int(np.ceil((mx - lo[a]) / h - 0.5)), dim[a] - 1)
        for i in range(lo_i[0], hi_i[0] + 1):
            c[0] = lo[0] + (i + 0.5) * h
            for j in range(lo_i[1], hi_i[1] + 1):
                c[1] = lo[1] + (j + 0.5) * h
                base = (i * dim[1] + j) * dim[2]
                for m in range(lo_i[2], hi_i[2] + 1):
                    if flags[base + m]:
                        continue
                    c[2] = lo[2] + (m + 0.5) * h
                    if closest_point_triangle(tris, k, c, bary) <= radius:
                        flags[base + m] = 1


@njit(cache=True, forceinline=True, error_model="numpy")
def may_be_within_reach(grid, tooth, p) -> bool:
    """False only where no dentin triangle of ``tooth`` lies within the grid's reach of point p."""
    lo, inv, dims, offs, flags = grid
    if dims[tooth, 0] == 0:
        return True
    i = np.floor((p[0] - lo[tooth, 0]) * inv[tooth])
    j = np.floor((p[1] - lo[tooth, 1]) * inv[tooth])
    m = np.floor((p[2] - lo[tooth, 2]) * inv[tooth])
    if not (0.0 <= i < dims[tooth, 0] and 0.0 <= j < dims[tooth, 1] and 0.0 <= m < dims[tooth, 2]):
        return not (i == i and j == j and m == m)  # outside the grown box: none within reach (NaN: search)
    return flags[offs[tooth] + (int(i) * dims[tooth, 1] + int(j)) * dims[tooth, 2] + int(m)] != 0
