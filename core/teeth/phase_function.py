"""Two-lobe Henyey-Greenstein phase function (eq. 5.4) and its analytic derivatives (eq. 5.11-5.14).

``mu`` is the cosine between the propagation directions before and after scattering (mu = 1 is
forward scattering; the thesis writes cos(theta) = omega_i . omega_o with omega_i pointing back
towards the previous vertex, i.e. cos(theta) = -mu).

``hg``, ``hg_dlog_dg`` and ``two_lobe`` are the one implementation both tracers use: numpy arrays in the
reference tracer, scalars in the compiled one (``numba_kernels.numba_callable``). Sampling has a vector form
(``sample_hg_mu``, ``direction_from_mu``: masks and stacked frames) and a scalar one for the compiled tracer
(``sample_hg_mu_scalar``, ``direction_from_mu_into``); ``test_teeth_numba_kernels`` pins each pair to each other.
"""

from __future__ import annotations

import numpy as np

from .numba_kernels import numba_callable

INV_4PI = 1.0 / (4.0 * np.pi)


@numba_callable
def hg(mu, g):
    """Henyey-Greenstein phase function f_HG(mu, g) = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2)) (normalised
    over the sphere). Arrays or scalars; callable from numba code."""
    denom = 1.0 + g * g - 2.0 * g * mu
    return INV_4PI * (1.0 - g * g) / (denom * np.sqrt(denom))


@numba_callable
def hg_dlog_dg(mu, g):
    """d log f_HG / d g = -(2g / (1 - g^2) + 3 (g - mu) / (1 + g^2 - 2 g mu)) (eq. 5.13 / f_HG). Arrays or
    scalars; callable from numba code."""
    return -(2.0 * g / (1.0 - g * g) + 3.0 * (g - mu) / (1.0 + g * g - 2.0 * g * mu))


@numba_callable
def two_lobe(mu, g1, g2, beta):
    """f_p = beta f_HG(mu, g1) + (1 - beta) f_HG(mu, g2) (eq. 5.4). Arrays or scalars; callable from numba code."""
    return beta * hg(mu, g1) + (1.0 - beta) * hg(mu, g2)


def sample_hg_mu(g: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Inverse-CDF sample of mu for f_HG(mu, g)."""
    g = np.asarray(g, dtype=np.float64) * np.ones_like(u)
    small = np.abs(g) < 1e-4
    gs = np.where(small, 0.5, g)
    s = (1.0 - gs * gs) / (1.0 - gs + 2.0 * gs * u)
    mu = (1.0 + gs * gs - s * s) / (2.0 * gs)
    return np.clip(np.where(small, 1.0 - 2.0 * u, mu), -1.0, 1.0)


@numba_callable
def sample_hg_mu_scalar(g: float, u: float) -> float:
    """``sample_hg_mu`` for one g and u: s = (1 - g^2) / (1 - g + 2 g u), mu = (1 + g^2 - s^2) / (2 g) clipped
    to [-1, 1]; mu = 1 - 2u (isotropic) where |g| < 1e-4. Callable from numba code."""
    if abs(g) < 1e-4:
        return 1.0 - 2.0 * u
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return min(max((1.0 + g * g - s * s) / (2.0 * g), -1.0), 1.0)


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


@numba_callable
def direction_from_mu_into(d, mu: float, phi: float, out) -> None:
    """``direction_from_mu`` for one unit direction ``d`` (3,): the unit vector d mu + (t cos phi + s sin phi)
    sqrt(1 - mu^2) in the frame (t, s) of ``orthonormal_frame``, written into ``out`` (3,). Callable from numba
    code."""
    sign = 1.0 if d[2] >= 0.0 else -1.0
    a = -1.0 / (sign + d[2])
    b = d[0] * d[1] * a
    t0, t1, t2 = 1.0 + sign * d[0] * d[0] * a, sign * b, -sign * d[0]
    s0, s1, s2 = b, sign + d[1] * d[1] * a, -d[1]
    st = np.sqrt(max(1.0 - mu * mu, 0.0))
    cp, sp = np.cos(phi), np.sin(phi)
    x = d[0] * mu + (t0 * cp + s0 * sp) * st
    y = d[1] * mu + (t1 * cp + s1 * sp) * st
    z = d[2] * mu + (t2 * cp + s2 * sp) * st
    n = np.sqrt(x * x + y * y + z * z)
    out[0], out[1], out[2] = x / n, y / n, z / n


def sample_two_lobe(d: np.ndarray, g1, g2, beta, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample a scattered direction from the two-lobe phase function; returns (directions, mu).

    ``u`` is ``(N, 3)`` uniform: lobe choice, cosine, azimuth. The pdf equals ``two_lobe(mu, ...)``.
    """
    first = u[:, 0] < beta
    g = np.where(first, g1, g2)
    mu = sample_hg_mu(g, u[:, 1])
    return direction_from_mu(d, mu, 2.0 * np.pi * u[:, 2]), mu
