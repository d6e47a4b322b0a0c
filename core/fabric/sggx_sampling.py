"""Importance sampling of the specular lobe by visible-normal sampling of the SGGX distribution.

Visible normals ``D_wo(m) = <wo, m> D(m) / sigma(wo)`` (Heitz et al. 2015) are the normals of the
ellipsoid ``x^T S^-1 x = 1`` seen from ``wo``: a point drawn uniformly on the projected disk maps to a
normal. Reflecting ``wo`` about ``m`` gives ``wi`` with density ``D(m) / (4 sigma(wo))``, i.e. exactly
the phase function of eq. 3.4, which integrates to one over the whole sphere. Samples that land
below the horizon carry zero BRDF (the caller treats them as absorbed).
"""

from __future__ import annotations

import numpy as np

from .sggx_matrix import projected_area, sggx_matrix
from .sggx_ndf import sggx_ndf


def _orthonormal_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``n`` (..., 3) to a right-handed orthonormal frame."""
    a = np.where(np.abs(n[..., :1]) > 0.9, np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    t = np.cross(a, n)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(n, t)
    return t, b


def sample_visible_normal(wo: np.ndarray, s: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Draw microflake normals ``m`` (..., 3) from ``D_wo`` for SGGX matrices ``s`` (..., 3, 3).

    ``u1, u2`` are uniform numbers in [0, 1). ``m . wo >= 0`` always.
    """
    wo = np.asarray(wo, dtype=np.float64)
    wk, wj = _orthonormal_basis(wo)
    frame = np.stack([wk, wj, wo], axis=-2)  # rows = (w_k, w_j, w_i)
    sk = np.einsum("...ai,...ij,...bj->...ab", frame, s, frame)
    s_jj, s_ii = sk[..., 1, 1], sk[..., 2, 2]
    s_kj, s_ki, s_ji = sk[..., 0, 1], sk[..., 0, 2], sk[..., 1, 2]
    det = np.abs(np.linalg.det(sk))
    inv_sqrt_ii = 1.0 / np.sqrt(s_ii)
    tmp = np.sqrt(np.maximum(s_jj * s_ii - s_ji * s_ji, 1e-300))
    # rows of the linear map from the unit-disk / hemisphere sample to the normal (in k, j, i coords)
    mk = np.stack([np.sqrt(det) / tmp, np.zeros_like(tmp), np.zeros_like(tmp)], axis=-1)
    mj = np.stack([-inv_sqrt_ii * (s_ki * s_ji - s_kj * s_ii) / tmp, inv_sqrt_ii * tmp,
                   np.zeros_like(tmp)], axis=-1)
    mi = inv_sqrt_ii[..., None] * np.stack([s_ki, s_ji, s_ii], axis=-1)
    r = np.sqrt(np.asarray(u1, dtype=np.float64))
    phi = 2.0 * np.pi * np.asarray(u2, dtype=np.float64)
    x = r * np.cos(phi)
    y = r * np.sin(phi)
    z = np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0))
    m_kji = x[..., None] * mk + y[..., None] * mj + z[..., None] * mi
    m_kji /= np.linalg.norm(m_kji, axis=-1, keepdims=True)
    return np.einsum("...a,...ai->...i", m_kji, frame)


def sample_specular(
    wo: np.ndarray, sigma: np.ndarray, quat: np.ndarray, u1: np.ndarray, u2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Sample a light direction ``wi`` for the specular lobe of eq. 3.9 given the view ``wo``.

    Returns ``(wi, pdf)`` with ``pdf = D(w_h) / (4 sigma(wo))`` per unit solid angle (eq. 3.4). ``wi``
    may be below the horizon (``wi[..., 2] <= 0``); the BRDF is zero there.
    """
    s = sggx_matrix(quat, sigma)
    m = sample_visible_normal(wo, s, u1, u2)
    wo = np.asarray(wo, dtype=np.float64)
    wi = 2.0 * np.sum(wo * m, axis=-1, keepdims=True) * m - wo
    return wi, specular_pdf(wi, wo, sigma, quat)


def specular_pdf(wi: np.ndarray, wo: np.ndarray, sigma: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Solid-angle density of :func:`sample_specular`: the SGGX phase function ``D(w_h)/(4 sigma(wo))``."""
    s = sggx_matrix(quat, sigma)
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    return sggx_ndf(h, s) / (4.0 * projected_area(wo, s))
