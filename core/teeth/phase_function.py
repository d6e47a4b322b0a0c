"""Two-lobe Henyey-Greenstein phase function (eq. 5.4) and its analytic derivatives (eq. 5.11-5.14).

``mu`` is the cosine between the propagation directions before and after scattering (mu = 1 is
forward scattering; the thesis writes cos(theta) = omega_i . omega_o with omega_i pointing back
towards the previous vertex, i.e. cos(theta) = -mu).
"""

from __future__ import annotations

import numpy as np

INV_4PI = 1.0 / (4.0 * np.pi)


def hg(mu: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Henyey-Greenstein phase function f_HG(mu, g) (normalised over the sphere)."""
    denom = 1.0 + g * g - 2.0 * g * mu
    return INV_4PI * (1.0 - g * g) / (denom * np.sqrt(denom))


def hg_dlog_dg(mu: np.ndarray, g: np.ndarray) -> np.ndarray:
    """d log f_HG / d g = -(2g / (1 - g^2) + 3 (g - mu) / (1 + g^2 - 2 g mu)) (eq. 5.13 / f_HG)."""
    return -(2.0 * g / (1.0 - g * g) + 3.0 * (g - mu) / (1.0 + g * g - 2.0 * g * mu))


def two_lobe(mu: np.ndarray, g1, g2, beta) -> np.ndarray:
    """f_p = beta f_HG(mu, g1) + (1 - beta) f_HG(mu, g2) (eq. 5.4)."""
    return beta * hg(mu, g1) + (1.0 - beta) * hg(mu, g2)


def sample_hg_mu(g: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Inverse-CDF sample of mu for f_HG(mu, g)."""
    g = np.asarray(g, dtype=np.float64) * np.ones_like(u)
    small = np.abs(g) < 1e-4
    gs = np.where(small, 0.5, g)
    s = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    mu = (1.0 + gs * gs - s * s) / (2.0 * gs)
    return np.clip(np.where(small, 1.0 - 2.0 * u, mu), -1.0, 1.0)


def orthonormal_frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to the unit vectors ``d`` (N, 3) (Duff et al. 2017)."""
    sign = np.where(d[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + d[:, 2])
    b = d[:, 0] * d[:, 1] * a
    t = np.stack([1.0 + sign * d[:, 0] ** 2 * a, sign * b, -sign * d[:, 0]], axis=1)
    s = np.stack([b, sign + d[:, 1] ** 2 * a, -d[:, 1]], axis=1)
    return t, s


def direction_from_mu(d: np.ndarray, mu: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit direction at cosine ``mu`` to ``d`` and azimuth ``phi``."""
    t, s = orthonormal_frame(d)
    sin_t = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    out = d * mu[:, None] + (t * np.cos(phi)[:, None] + s * np.sin(phi)[:, None]) * sin_t[:, None]
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def sample_two_lobe(d: np.ndarray, g1, g2, beta, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample a scattered direction from the two-lobe phase function; returns (directions, mu).

    ``u`` is ``(N, 3)`` uniform: lobe choice, cosine, azimuth. The pdf equals ``two_lobe(mu, ...)``.
    """
    first = u[:, 0] < beta
    g = np.where(first, g1, g2)
    mu = sample_hg_mu(g, u[:, 1])
    return direction_from_mu(d, mu, 2.0 * np.pi * u[:, 2]), mu
