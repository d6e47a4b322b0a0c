"""The pile-fabric BRDF of eq. 3.9, vectorised over texels and direction batches.

``f_r(wi, wo) = k_s D(w_h) / (4 cos_i cos_o (sigma(wo)/cos_o + sigma(wi)/cos_i)) + k_d / pi``

equivalently (eq. 3.10 / 3.3) ``k_s D(w_h) / (4 (sigma(wo) cos_i + sigma(wi) cos_o)) + k_d / pi``.
Directions are unit vectors in the tangent frame (z = surface normal). All inputs broadcast
against each other: e.g. directions ``(N, 3)`` with parameter maps ``(H, W, 1, C)`` give ``(H, W, N, 3)``.
"""

from __future__ import annotations

import numpy as np

from .quaternion import quat_to_matrix
from .sggx_matrix import full_sigma


def to_local(w: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Express world/tangent-frame vectors ``w`` (..., 3) in the fibre basis ``rot`` (..., 3, 3)."""
    return np.einsum("...ji,...j->...i", rot, w)


def sggx_specular(wi: np.ndarray, wo: np.ndarray, sigma: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """Specular term of eq. 3.9 with ``k_s = 1``; zero where either direction is below the horizon."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    s3 = full_sigma(sigma)
    rot = quat_to_matrix(quat)
    ci = wi[..., 2]
    co = wo[..., 2]
    h = wi + wo
    hl = to_local(h, rot)
    il = to_local(wi, rot)
    ol = to_local(wo, rot)
    hh = np.sum(h * h, axis=-1)
    q = np.sum((hl / s3) ** 2, axis=-1) / np.maximum(hh, 1e-300)
    d = 1.0 / (np.pi * np.prod(s3, axis=-1) * q * q)  # eq. 3.5 in the fibre basis
    sig_i = np.sqrt(np.sum((il * s3) ** 2, axis=-1))
    sig_o = np.sqrt(np.sum((ol * s3) ** 2, axis=-1))
    denom = 4.0 * (sig_o * ci + sig_i * co)
    valid = (ci > 0) & (co > 0)
    return np.where(valid, d / np.where(valid, denom, 1.0), 0.0)


def sggx_brdf(
    wi: np.ndarray,
    wo: np.ndarray,
    kd: np.ndarray,
    ks: np.ndarray,
    sigma: np.ndarray,
    quat: np.ndarray,
) -> np.ndarray:
    """BRDF of eq. 3.9 (RGB).

    wi, wo: unit light/view directions (..., 3), z = normal. kd, ks: (..., 3) diffuse and specular
    albedo. sigma: (..., 2) projected standard deviations (sigma_x, sigma_y), sigma_z = 1.
    quat: (..., 4) fibre basis (w, x, y, z). Returns (..., 3); zero below the horizon.
    """
    g = sggx_specular(wi, wo, sigma, quat)[..., None]
    ci = np.asarray(wi)[..., 2:3]
    co = np.asarray(wo)[..., 2:3]
    diffuse = np.where((ci > 0) & (co > 0), np.asarray(kd, dtype=np.float64) / np.pi, 0.0)
    return np.asarray(ks, dtype=np.float64) * g + diffuse


def sggx_btf_value(wi, wo, kd, ks, sigma, quat) -> np.ndarray:
    """What a BTF texel stores: ``f_r(wi, wo) * cos(theta_i)`` (RGB)."""
    return sggx_brdf(wi, wo, kd, ks, sigma, quat) * np.maximum(np.asarray(wi)[..., 2:3], 0.0)
