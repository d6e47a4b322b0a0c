"""Per-scratch factors of the scratch iridescence model (thesis Sec. 4.3.1, after Werner et al. 2017).

Units: lengths (widths, depths, positions, sigma) in micrometres, wavelengths in micrometres inside
these functions (callers holding nm divide by 1000). Direction cosines xi = (wi + wo) . (t, b) are
taken in the frame of the scratch: t along the scratch, b across it (eq. 4.2 ff.).

* ``scratch_width_term``      W(xi2)      = Ws sinc(pi Ws xi2 / lambda)                    eq. 4.3
* ``scratch_depth_term``      D           = 1 - exp(i 4 pi Ds / lambda)                    eq. 4.4
* ``scratch_depth_term_sq``   |D|^2       = 2 - 2 cos(4 pi Ds / lambda)                    eq. 4.11
* ``scratch_phase_term``      eta(xi, x)  for a finite segment, complex erf                eq. 4.5
* ``scratch_phase_term_infinite``  eta    for an infinite scratch                           eq. 4.8
* ``scratch_phase_sq_angular``     |eta_a|^2 = exp(-sigma^2 k^2 xi1^2)                      eq. 4.10
* ``scratch_phase_sq_spatial``     |eta_s|^2 = 2 A_C exp(-sb^2 / sigma^2)                   eq. 4.10
* ``base_response_flat``      B(xi)       of an unscratched flat surface seen through the Gaussian
  window of radius sigma: 2 pi sigma^2 exp(-sigma^2 k^2 |xi|^2 / 2), which makes the base BRDF of
  eq. 4.1 integrate to exactly 1 over the xi plane.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

SIGMA_COHERENCE_UM = 60.0  # radius of the coherence area used in the thesis' main results


def wavenumber(lam_um: ArrayLike) -> np.ndarray:
    """k = 2 pi / lambda (1/um)."""
    return 2.0 * np.pi / np.asarray(lam_um, dtype=np.float64)


def coherence_area(sigma_um: float) -> float:
    """A_C = pi sigma^2 (um^2)."""
    return float(np.pi * sigma_um**2)


def scratch_width_term(xi2: ArrayLike, width_um: ArrayLike, lam_um: ArrayLike) -> np.ndarray:
    """Eq. 4.3: W = Ws sinc(pi Ws xi2 / lambda) with sinc(x) = sin(x)/x."""
    w = np.asarray(width_um, dtype=np.float64)
    return w * np.sinc(w * np.asarray(xi2, dtype=np.float64) / np.asarray(lam_um))  # np.sinc is sin(pi x)/(pi x)


def scratch_depth_term(depth_um: ArrayLike, lam_um: ArrayLike) -> np.ndarray:
    """Eq. 4.4: D = 1 - exp(i 4 pi Ds / lambda) (small-angle form used by the thesis)."""
    return 1.0 - np.exp(4j * np.pi * np.asarray(depth_um, dtype=np.float64) / np.asarray(lam_um))


def scratch_depth_term_sq(depth_um: ArrayLike, lam_um: ArrayLike) -> np.ndarray:
    """Eq. 4.11: |D|^2 = 2 - 2 cos(4 pi Ds / lambda)."""
    return 2.0 - 2.0 * np.cos(4.0 * np.pi * np.asarray(depth_um, dtype=np.float64) / np.asarray(lam_um))


def _erf_damped(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """exp(-a^2) erf(x + i a) for real x, a, without overflow (via the Faddeeva function)."""
    from scipy.special import wofz

    sx = np.where(x < 0, -1.0, 1.0)
    ax = np.abs(x)
    # erf(z) = 1 - exp(-z^2) w(i z) for Re z >= 0; odd symmetry for Re z < 0.
    w = wofz(-sx * a + 1j * ax)
    return sx * (np.exp(-(a**2)) - np.exp(-(ax**2) - 2j * ax * a * sx) * w)


def scratch_phase_term(
    xi1: ArrayLike,
    xi2: ArrayLike,
    s_t: ArrayLike,
    s_b: ArrayLike,
    length_um: ArrayLike,
    lam_um: ArrayLike,
    sigma_um: float = SIGMA_COHERENCE_UM,
) -> np.ndarray:
    """Eq. 4.5: eta of a straight scratch segment s(h) = s' + h t, h in [0, length].

    ``s_t``, ``s_b``: components of s' = s - x (segment start relative to the shaded point) along
    the scratch tangent and bitangent. Evaluated as
    d erf(((s_t + h)/sigma + i sigma k xi1)/sqrt 2) |_{h=0}^{length} with
    d = sqrt(pi/2) sigma exp(-s_b^2/(2 sigma^2) - sigma^2 k^2 xi1^2 / 2 - i k s_b xi2).
    """
    k = wavenumber(lam_um)
    xi1 = np.asarray(xi1, dtype=np.float64)
    s_t = np.asarray(s_t, dtype=np.float64)
    s_b = np.asarray(s_b, dtype=np.float64)
    a = sigma_um * k * xi1 / np.sqrt(2.0)
    x0 = s_t / (sigma_um * np.sqrt(2.0))
    x1 = (s_t + np.asarray(length_um, dtype=np.float64)) / (sigma_um * np.sqrt(2.0))
    diff = _erf_damped(x1, a) - _erf_damped(x0, a)
    pref = np.sqrt(np.pi / 2.0) * sigma_um * np.exp(-(s_b**2) / (2.0 * sigma_um**2) - 1j * k * s_b * xi2)
    return pref * diff


def scratch_phase_term_infinite(
    xi1: ArrayLike, xi2: ArrayLike, s_b: ArrayLike, lam_um: ArrayLike, sigma_um: float = SIGMA_COHERENCE_UM
) -> np.ndarray:
    """Eq. 4.8: eta of an infinite scratch, sqrt(2 pi) sigma exp(-sb^2/2s^2 - s^2k^2xi1^2/2 - i k sb xi2)."""
    k = wavenumber(lam_um)
    s_b = np.asarray(s_b, dtype=np.float64)
    return (
        np.sqrt(2.0 * np.pi)
        * sigma_um
        * np.exp(
            -(s_b**2) / (2 * sigma_um**2)
            - 0.5 * (sigma_um * k * np.asarray(xi1)) ** 2
            - 1j * k * s_b * np.asarray(xi2)
        )
    )


def scratch_phase_sq_angular(xi1: ArrayLike, lam_um: ArrayLike, sigma_um: float = SIGMA_COHERENCE_UM) -> np.ndarray:
    """Eq. 4.10, angular part: |eta_a|^2 = exp(-sigma^2 k^2 xi1^2)."""
    return np.exp(-((sigma_um * wavenumber(lam_um) * np.asarray(xi1, dtype=np.float64)) ** 2))


def scratch_phase_sq_spatial(s_b: ArrayLike, sigma_um: float = SIGMA_COHERENCE_UM) -> np.ndarray:
    """Eq. 4.10, spatial part: |eta_s|^2 = 2 A_C exp(-sb^2 / sigma^2)."""
    return 2.0 * coherence_area(sigma_um) * np.exp(-(np.asarray(s_b, dtype=np.float64) ** 2) / sigma_um**2)


def base_response_flat(xi1: ArrayLike, xi2: ArrayLike, lam_um: ArrayLike, sigma_um: float = SIGMA_COHERENCE_UM):
    """B(xi) of a flat unscratched surface under the Gaussian window (so that int f_base dxi = 1)."""
    k = wavenumber(lam_um)
    r2 = np.asarray(xi1, dtype=np.float64) ** 2 + np.asarray(xi2, dtype=np.float64) ** 2
    return 2.0 * np.pi * sigma_um**2 * np.exp(-0.5 * (sigma_um * k) ** 2 * r2)
