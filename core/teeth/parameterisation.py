"""Dual-domain parameterisations used by the optimiser (eq. 5.22 and 5.24).

* extinction: sigma_t = exp(xi)          d sigma_t / d xi = exp(xi)                (eq. 5.24)
* albedo:     alpha = 1 - 10^kappa       d alpha / d kappa = -10^kappa log(10)     (eq. 5.22)

(The printed eq. 5.22 writes the factor as 10^-kappa log 10; differentiating alpha = 1 - 10^kappa
gives -10^kappa log 10, which is what is used here and verified by finite differences.)
Other parameters (a_t, g, beta, dentin coefficients c, cavity albedo) are optimised directly and
clamped to their valid ranges.
"""

from __future__ import annotations

import numpy as np


def sigma_from_xi(xi: np.ndarray) -> np.ndarray:
    return np.exp(xi)


def xi_from_sigma(sigma: np.ndarray) -> np.ndarray:
    return np.log(sigma)


def dsigma_dxi(xi: np.ndarray) -> np.ndarray:
    return np.exp(xi)


def albedo_from_kappa(kappa: np.ndarray) -> np.ndarray:
    return 1.0 - np.power(10.0, kappa)


def kappa_from_albedo(albedo: np.ndarray) -> np.ndarray:
    return np.log10(1.0 - np.asarray(albedo))


def dalbedo_dkappa(kappa: np.ndarray) -> np.ndarray:
    return -np.power(10.0, kappa) * np.log(10.0)
