"""Post-processing of fitted SGGX bases (thesis section 3.4.3).

All operations use symmetries of eq. 3.9 (a common scale of ``S_v``, permutations of the basis
axes with their deviations, and negating axes), so the BRDF of every texel is unchanged:

1. :func:`sort_basis` orders the axes by standard deviation (``sigma_x <= sigma_y <= sigma_z = 1``),
   keeps the frame right-handed and turns the ``z`` axis to the upper hemisphere.
2. :func:`label_flip_regions` finds the outlines where neighbouring tangents point in opposite
   directions and labels the regions they enclose.
3. :func:`reorient_regions` turns every region toward the dominant one (the region covering most
   area), region by region across the outlines, and optionally the dominant direction toward a
   preferred one.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from .quaternion import matrix_to_quat, quat_to_matrix


def sort_basis(quat: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Canonical basis: axes sorted by deviation, normalised so the largest is 1 (..., 4), (..., 2)."""
    shape = np.shape(quat)[:-1]
    r = quat_to_matrix(np.reshape(quat, (-1, 4)))
    s3 = np.concatenate([np.reshape(sigma, (-1, 2)), np.ones((r.shape[0], 1))], axis=1)
    order = np.argsort(s3, axis=1, kind="stable")
    s3 = np.take_along_axis(s3, order, axis=1)
    r = np.take_along_axis(r, order[:, None, :], axis=2)
    s3 /= s3[:, 2:3]
    det = np.linalg.det(r)
    r[:, :, 1] *= np.where(det < 0, -1.0, 1.0)[:, None]
    # z axis up: rotate by pi about x (negate y and z)
    down = r[:, 2, 2] < 0
    r[down, :, 1:] *= -1.0
    return matrix_to_quat(r).reshape(shape + (4,)), s3[:, :2].reshape(shape + (2,))


def _tangents(quat: np.ndarray) -> np.ndarray:
    return quat_to_matrix(quat)[..., :, 0]


def _edges(x: np.ndarray):
    """4-neighbour edges (a, b) of an (H, W) grid with the tangent dot products across them."""
    h, w = x.shape[:2]
    idx = np.arange(h * w).reshape(h, w)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    dots = np.concatenate([np.sum(x[:, :-1] * x[:, 1:], -1).ravel(), np.sum(x[:-1] * x[1:], -1).ravel()])
    return a, b, dots


def label_flip_regions(quat: np.ndarray) -> tuple[np.ndarray, int]:
    """Label the regions enclosed by sign-flip outlines of the tangent field: (H, W) -> (labels, count).

    Outlines are the neighbour pairs whose tangents point in opposite directions (``x . x' < 0``);
    regions are the connected components of the grid without those edges (labels start at 1).
    """
    x = _tangents(quat)
    h, w = x.shape[:2]
    a, b, dots = _edges(x)
    keep = dots >= 0
    graph = coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(h * w, h * w))
    count, labels = connected_components(graph, directed=False)
    return labels.reshape(h, w) + 1, int(count)


def flip_tangent(quat: np.ndarray) -> np.ndarray:
    """Rotate the basis by pi about its z axis (negates x and y): the same BRDF."""
    q = np.asarray(quat, dtype=np.float64)
    # q * (0, 0, 0, 1)
    return np.stack([-q[..., 3], q[..., 2], -q[..., 1], q[..., 0]], axis=-1)


def reorient_regions(quat: np.ndarray, labels: np.ndarray, preferred: np.ndarray | None = None
                     ) -> np.ndarray:
    """Reorient every region toward the dominant one (the region covering most area): regions are
    visited breadth-first from it across the flip outlines, each one flipped to agree with the region
    it was reached from. Regions not connected to it are flipped if their mean tangent opposes the
    dominant mean. If ``preferred`` (3-vector) is given, everything is then flipped so the dominant
    direction points toward it. Quaternion signs are aligned with the dominant region's mean."""
    x = _tangents(quat)
    n = int(labels.max())
    flat = labels.ravel()
    counts = np.bincount(flat, minlength=n + 1)
    counts[0] = 0
    dom = int(np.argmax(counts))
    sums = np.stack([np.bincount(flat, weights=x[..., i].ravel(), minlength=n + 1) for i in range(3)], -1)
    d = sums[dom] / max(np.linalg.norm(sums[dom]), 1e-300)
    a, b, dots = _edges(x)
    cross = (dots < 0) & (flat[a] != flat[b])
    adj = coo_matrix((np.ones(int(cross.sum())), (flat[a][cross], flat[b][cross])), shape=(n + 1, n + 1)).tocsr()
    flip = np.zeros(n + 1, dtype=bool)
    seen = np.zeros(n + 1, dtype=bool)
    seen[0] = True
    seeds = [dom] + [int(r) for r in np.argsort(-counts) if counts[r] > 0 and r != dom]
    for seed in seeds:
        if seen[seed]:
            continue
        flip[seed] = seed != dom and float(sums[seed] @ d) < 0
        order, pred = breadth_first_order(adj, seed, directed=False, return_predecessors=True)
        seen[order] = True
        for r in order[1:]:
            flip[r] = not flip[pred[r]]
    texel_flip = flip[labels]
    if preferred is not None and float(np.dot(d, preferred)) < 0:
        texel_flip = ~texel_flip
    out = np.where(texel_flip[..., None], flip_tangent(quat), quat)
    ref = out[labels == dom].mean(axis=0)
    sign = np.where(np.sum(out * ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return out * sign


def postprocess_basis(quat: np.ndarray, sigma: np.ndarray, preferred: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort, label and reorient (H, W) maps. Returns ``(quat, sigma, labels)``."""
    q, s = sort_basis(quat, sigma)
    labels, _ = label_flip_regions(q)
    return reorient_regions(q, labels, preferred), s, labels
