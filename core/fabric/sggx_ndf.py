"""The SGGX distribution of normals ``D(omega_h)`` (eq. 3.5)."""

from __future__ import annotations

import numpy as np


def sggx_ndf(wh: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``D(w) = 1 / (pi sqrt|S| (w^T S^-1 w)^2)`` for unit ``w`` (..., 3) and SGGX matrices (..., 3, 3).

    Normalised as in Heitz et al. 2015: ``int <w, w_m> D(w_m) dw_m = sigma(w)`` over the sphere with a
    clamped cosine. ``D`` is even (``D(-w) = D(w)``).
    """
    wh = np.asarray(wh, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    sinv = np.linalg.inv(s)
    det = np.linalg.det(s)
    q = np.einsum("...i,...ij,...j->...", wh, sinv, wh)
    return 1.0 / (np.pi * np.sqrt(det) * q * q)

