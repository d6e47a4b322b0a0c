"""Initial SGGX basis and standard deviations from an extracted NDF (eq. 3.13-3.16).

``w_2 = argmax D_BTF`` (3.13); ``w_0`` = the direction of largest spread of ``D_BTF`` perpendicular
to ``w_2`` (3.14, found by PCA of the NDF's tangent-plane projection, which also works where the
measured half vectors do not reach the great circle); ``w_1 = w_2 x w_0`` (3.15, right-handed);
``S_v^(k) = int_{Omega+} |w_k . w_h| D_BTF(w_h) dw_h`` (3.16), normalised so ``S_v^(2) = 1``.
"""

from __future__ import annotations

import numpy as np

from .ndf_extraction import NdfOperator
from .quaternion import matrix_to_quat


def initial_basis(ndf: np.ndarray, op: NdfOperator, floor_quantile: float | None = 0.1
                  ) -> tuple[np.ndarray, np.ndarray]:
    """From NDFs ``(cells, T)`` return ``(quat (T, 4), sigma (T, 2))`` following eq. 3.13-3.16.

    The diffuse part of the BTF adds a constant to ``D_BTF``; it is removed by subtracting the
    ``floor_quantile`` of each texel's NDF over the valid cells before the PCA (None: keep it).
    """
    valid = op.valid
    d = ndf[valid]  # (V, T)
    h = op.directions[valid]  # (V, 3)
    dw = op.solid_angle[valid][:, None]
    if floor_quantile is not None:
        d = np.maximum(d - np.quantile(d, floor_quantile, axis=0)[None], 0.0)
    # eq. 3.13 (argmax, refined by the NDF-weighted mean of the cells above 70 % of the peak)
    peak = d.max(axis=0)
    top = d >= 0.7 * peak[None]
    w2 = np.einsum("vt,vi->ti", np.where(top, d, 0.0), h)
    w2 = np.where(peak[:, None] > 0, w2, np.array([0.0, 0.0, 1.0]))
    w2 /= np.linalg.norm(w2, axis=-1, keepdims=True)
    # eq. 3.14: principal direction of the NDF in the plane perpendicular to w2
    p = h[None, :, :] - np.einsum("vi,ti->tv", h, w2)[:, :, None] * w2[:, None, :]  # (T, V, 3)
    wts = (d * dw).T  # (T, V)
    cov = np.einsum("tv,tvi,tvj->tij", wts, p, p)
    _, vecs = np.linalg.eigh(cov)
    w0 = vecs[..., 2]
    w0 -= np.sum(w0 * w2, -1, keepdims=True) * w2
    n0 = np.linalg.norm(w0, axis=-1, keepdims=True)
    fallback = np.cross(w2, np.array([0.0, 1.0, 0.0]))
    degenerate = np.linalg.norm(fallback, axis=-1, keepdims=True) < 1e-6
    fallback = np.where(degenerate, np.array([1.0, 0, 0]), fallback)
    fallback /= np.linalg.norm(fallback, axis=-1, keepdims=True)
    w0 = np.where(n0 > 1e-9, w0 / np.maximum(n0, 1e-300), fallback)
    w1 = np.cross(w2, w0)  # eq. 3.15 (right-handed order)
    m = np.stack([w0, w1, w2], axis=-1)  # columns
    # eq. 3.16
    sv = np.einsum("vt,tvk->tk", d * dw, np.abs(np.einsum("vi,tik->tvk", h, m)))
    sv = np.where(sv[:, 2:3] > 0, sv / np.maximum(sv[:, 2:3], 1e-300), 0.5)
    sigma = np.clip(sv[:, :2], 0.02, 5.0)
    sigma = np.where(np.isfinite(sigma), sigma, 0.5)
    return matrix_to_quat(m), sigma
