"""SGGX covariance matrix from a fibre basis and projected standard deviations (eq. 3.5-3.8).

``S_GGX = M S_sigma S_sigma^T M^T`` (eq. 3.6) with ``M`` the rotation of the fibre basis and
``S_sigma = diag(S_v)`` (eq. 3.7), where ``S_v^(k) = sigma(omega_k)`` is the projected area along
basis axis ``k`` (eq. 3.8). The model fixes ``sigma_z = 1`` (the BRDF of eq. 3.9 is invariant to a
common scale of ``S_v``), so a texel is described by ``sigma = (sigma_x, sigma_y)`` and a quaternion.
"""

from __future__ import annotations

import numpy as np

from .quaternion import quat_to_matrix


def full_sigma(sigma: np.ndarray) -> np.ndarray:
    """``(..., 2)`` -> ``(..., 3)`` projected standard deviations ``(sigma_x, sigma_y, 1)``."""
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.shape[-1] == 3:
        return sigma
    if sigma.shape[-1] != 2:
        raise ValueError(f"sigma must have 2 (sigma_x, sigma_y) or 3 entries, got shape {sigma.shape}")
    return np.concatenate([sigma, np.ones(sigma.shape[:-1] + (1,))], axis=-1)


def sggx_matrix(quat: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """SGGX matrix ``S_GGX`` (..., 3, 3) of eq. 3.6 from the basis quaternion and ``S_v`` (eq. 3.7-3.8)."""
    m = quat_to_matrix(quat)
    sv = full_sigma(sigma)
    return np.einsum("...ik,...k,...jk->...ij", m, sv * sv, m)


def projected_area(w: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``sigma(w) = sqrt(w^T S w)``: projected area of the microflakes seen from unit ``w`` (eq. 3.8)."""
    w = np.asarray(w, dtype=np.float64)
    return np.sqrt(np.maximum(np.einsum("...i,...ij,...j->...", w, s, w), 0.0))
