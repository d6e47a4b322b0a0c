"""Post-processing of fitted SGGX bases (thesis section 3.4.3).

All operations use symmetries of eq. 3.9 (a common scale of ``S_v``, permutations of the basis
axes with their deviations, and negating axes), so the BRDF of every texel is unchanged:

1. :func:`sort_basis` orders the axes by standard deviation (``sigma_x <= sigma_y <= sigma_z = 1``),
   keeps the frame right-handed and turns the ``z`` axis to the upper hemisphere.
2. :func:`label_flip_regions` finds the outlines where neighbouring tangents point in opposite
   directions and labels the regions they enclose.
3. :func:`reorient_regions` turns every region toward the dominant direction (the region covering
   most area) and optionally the dominant direction toward a preferred one.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

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


def dominant_direction(quat: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray:
    """Principal axis of the tangents ``x`` (sign-free: eigenvector of ``sum w x x^T``)."""
    x = _tangents(quat).reshape(-1, 3)
    w = np.ones(x.shape[0]) if weight is None else np.reshape(weight, -1)
    _, vecs = np.linalg.eigh(np.einsum("n,ni,nj->ij", w, x, x))
    return vecs[:, 2]


def label_flip_regions(quat: np.ndarray, reference: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Label regions separated by sign-flip outlines of the tangent field (H, W) -> (labels, count).

    A texel's side is ``sign(x . reference)`` (reference: the dominant direction); connected texels
    on the same side form one region (4-neighbourhood), so region borders are exactly where
    neighbouring tangents turn from one side to the other.
    """
    if reference is None:
        reference = dominant_direction(quat)
    side = np.einsum("hwi,i->hw", _tangents(quat), reference) >= 0
    lab_pos, n_pos = ndimage.label(side)
    lab_neg, n_neg = ndimage.label(~side)
    labels = np.where(side, lab_pos, np.where(lab_neg > 0, lab_neg + n_pos, 0))
    return labels, n_pos + n_neg


def flip_tangent(quat: np.ndarray) -> np.ndarray:
    """Rotate the basis by pi about its z axis (negates x and y): the same BRDF."""
    q = np.asarray(quat, dtype=np.float64)
    # q * (0, 0, 0, 1)
    return np.stack([-q[..., 3], -q[..., 2], q[..., 1], q[..., 0]], axis=-1)


def reorient_regions(quat: np.ndarray, labels: np.ndarray, preferred: np.ndarray | None = None
                     ) -> np.ndarray:
    """Flip regions whose mean tangent opposes the dominant (largest) region's; then, if
    ``preferred`` (3-vector) is given, flip all so the dominant direction points toward it. Finally
    quaternion signs are aligned with the dominant region's mean so neighbours interpolate smoothly."""
    x = _tangents(quat)
    n = int(labels.max())
    counts = np.bincount(labels.ravel(), minlength=n + 1)
    counts[0] = 0
    dom = int(np.argmax(counts))
    flat = labels.ravel()
    sums = np.stack([np.bincount(flat, weights=x[..., i].ravel(), minlength=n + 1) for i in range(3)], -1)
    d = sums[dom] / max(np.linalg.norm(sums[dom]), 1e-300)
    flip_region = (sums @ d) < 0
    flip = flip_region[labels]
    if preferred is not None and float(np.dot(d, preferred)) < 0:
        flip = ~flip
    out = np.where(flip[..., None], flip_tangent(quat), quat)
    ref = out[labels == dom].mean(axis=0)
    sign = np.where(np.sum(out * ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return out * sign


def postprocess_basis(quat: np.ndarray, sigma: np.ndarray, preferred: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort, label and reorient (H, W) maps. Returns ``(quat, sigma, labels)``."""
    q, s = sort_basis(quat, sigma)
    labels, _ = label_flip_regions(q)
    return reorient_regions(q, labels, preferred), s, labels
