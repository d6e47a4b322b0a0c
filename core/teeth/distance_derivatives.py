"""Derivatives of distances w.r.t. triangle vertices (eq. 5.28-5.29 and appendix eq. 5.33-5.41).

* Ray-triangle distance t (eq. 5.27-5.28): moving vertex j by dv moves the hit plane at the hit
  point by w_j dv (w = barycentric weights of the hit), hence dt/dv_j = w_j n / (n . r_d). This is
  the closed form of the adjugate expression eq. 5.29 (both are the derivative of |D1| / |D2|).
* Point-triangle distance q (eq. 5.33-5.41): with the closest point p_c = sum_j w_j v_j on the closest
  primitive (vertex, edge or interior, Eberly 2015), dq/dv_j = -w_j (p_s - p_c) / |p_s - p_c|. For a
  vertex (w = 1) this is eq. 5.34; for an edge it equals eq. 5.38-5.39; for the interior it equals
  eq. 5.41 (-w_j n sgn(q)). As in the thesis the closest primitive is held fixed.
"""

from __future__ import annotations

import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (..., 3) arrays (faster than np.cross for many small vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def ray_triangle_distance(
    origin: np.ndarray, direction: np.ndarray, v0: np.ndarray, v1: np.ndarray, v2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """t of the ray/plane intersection (eq. 5.28) and barycentric weights ``(N, 3)``; float64."""
    e1 = v1 - v0
    e2 = v2 - v0
    p = cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    inv = 1.0 / np.where(np.abs(det) < 1e-300, 1e-300, det)
    s = origin - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    qv = cross(s, e1)
    v = np.einsum("ij,ij->i", direction, qv) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    return t, np.stack([1.0 - u - v, u, v], axis=1)


def ray_distance_vertex_derivative(
    direction: np.ndarray, v0: np.ndarray, v1: np.ndarray, v2: np.ndarray, bary: np.ndarray
) -> np.ndarray:
    """dt/dv_j for the three triangle vertices, ``(N, 3 vertices, 3 coords)`` (eq. 5.29)."""
    n = cross(v1 - v0, v2 - v0)
    nd = np.einsum("ij,ij->i", n, direction)
    g = n / nd[:, None]
    return bary[:, :, None] * g[:, None, :]


def closest_point_on_triangle(
    p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on triangles (a, b, c) to points p, vectorised; returns (points, bary (N, 3)).

    Region tests after Eberly (2015) / Ericson (2005): vertex, edge or interior.
    """
    n = p.shape[0]
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    bary = np.zeros((n, 3))
    done = np.zeros(n, dtype=bool)

    def assign(mask, w0, w1, w2):
        m = mask & ~done
        bary[m, 0] = np.broadcast_to(w0, n)[m]
        bary[m, 1] = np.broadcast_to(w1, n)[m]
        bary[m, 2] = np.broadcast_to(w2, n)[m]
        done[m] = True

    with np.errstate(divide="ignore", invalid="ignore"):
        assign((d1 <= 0) & (d2 <= 0), 1.0, 0.0, 0.0)
        assign((d3 >= 0) & (d4 <= d3), 0.0, 1.0, 0.0)
        assign((d6 >= 0) & (d5 <= d6), 0.0, 0.0, 1.0)
        v_ab = d1 / (d1 - d3)
        assign((vc <= 0) & (d1 >= 0) & (d3 <= 0), 1.0 - v_ab, v_ab, 0.0)
        w_ac = d2 / (d2 - d6)
        assign((vb <= 0) & (d2 >= 0) & (d6 <= 0), 1.0 - w_ac, 0.0, w_ac)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        assign((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), 0.0, 1.0 - w_bc, w_bc)
        denom = 1.0 / (va + vb + vc)
        vv = vb * denom
        ww = vc * denom
        assign(np.ones(n, dtype=bool), 1.0 - vv - ww, vv, ww)
    pts = bary[:, 0:1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c
    return pts, bary


def point_distance_vertex_derivative(
    p: np.ndarray, closest: np.ndarray, bary: np.ndarray, sign: np.ndarray | float = 1.0
) -> np.ndarray:
    """d(sign * |p - p_c|)/dv_j, ``(N, 3 vertices, 3 coords)`` (eq. 5.33-5.41)."""
    diff = p - closest
    dist = np.linalg.norm(diff, axis=1)
    unit = diff / np.maximum(dist, 1e-300)[:, None]
    return -(np.asarray(sign, dtype=np.float64) * np.ones(len(p)))[:, None, None] * bary[:, :, None] * unit[
        :, None, :
    ]
