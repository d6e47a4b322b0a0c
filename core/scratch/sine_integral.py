"""Sine integral Si(x) (eq. 4.28) and the GPU-friendly approximation of eq. 4.29.

The approximation is a sigmoid plus a hyperbolically decaying oscillation,

    Si(x) ~ pi/2 tanh(x) - a0 x / (1 + (x - sgn(x) b0)^2) + sgn(x) (1 - cos x) / (1 + |x|),

with a0 = 0.66142739 and b0 = 0.38272292 (thesis, eq. 4.29). It is odd, exact at 0 and tends to
+-pi/2 for |x| -> inf, like Si itself; its largest absolute error is about 0.05 (near |x| = 3.6).

``sine_integral_series`` is an equally branch-light GPU form with an absolute error below 2e-6:
the Maclaurin series (24 terms, Horner in x^2) for |x| <= 12 and the asymptotic expansion
Si(x) = pi/2 - f(x) cos x - g(x) sin x with 6 terms of f and g beyond. ``sine_integral(x, mode)``
selects ``"thesis"`` (eq. 4.29), ``"series"`` or ``"exact"`` (scipy).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

SI_A0 = 0.66142739
SI_B0 = 0.38272292


def sine_integral_approx(x: ArrayLike) -> np.ndarray:
    """Eq. 4.29: the closed-form approximation of Si(x) used by the shader."""
    x = np.asarray(x, dtype=np.float64)
    s = np.sign(x)
    return (
        0.5 * np.pi * np.tanh(x)
        - SI_A0 * x / (1.0 + (x - s * SI_B0) ** 2)
        + s * (1.0 - np.cos(x)) / (1.0 + np.abs(x))
    )


def sine_integral_exact(x: ArrayLike) -> np.ndarray:
    """Eq. 4.28 evaluated with ``scipy.special.sici`` (reference)."""
    from scipy.special import sici

    return sici(np.asarray(x, dtype=np.float64))[0]


_SERIES = tuple((-1) ** n / ((2 * n + 1) * math.factorial(2 * n + 1)) for n in range(24))
_F_ASYM = (1.0, -2.0, 24.0, -720.0, 40320.0, -3628800.0)
_G_ASYM = (1.0, -6.0, 120.0, -5040.0, 362880.0, -39916800.0)
SERIES_SPLIT = 12.0
SI_MODES = ("thesis", "series", "exact")


def sine_integral_series(x: ArrayLike) -> np.ndarray:
    """Si(x) to ~1e-6: Maclaurin series for |x| <= 12, asymptotic expansion beyond."""
    x = np.asarray(x, dtype=np.float64)
    ax = np.abs(x)
    small = np.minimum(ax, SERIES_SPLIT)
    x2 = small * small
    acc = np.zeros_like(x2)
    for c in reversed(_SERIES):
        acc = acc * x2 + c
    near = acc * small
    big = np.maximum(ax, SERIES_SPLIT)
    y = 1.0 / (big * big)
    f = np.zeros_like(y)
    g = np.zeros_like(y)
    for cf, cg in zip(reversed(_F_ASYM), reversed(_G_ASYM), strict=True):
        f = f * y + cf
        g = g * y + cg
    far = 0.5 * np.pi - f / big * np.cos(big) - g * y * np.sin(big)
    return np.sign(x) * np.where(ax <= SERIES_SPLIT, near, far)


def sine_integral(x: ArrayLike, mode: str = "series") -> np.ndarray:
    """Si(x) by ``mode``: "thesis" (eq. 4.29), "series" (accurate GPU form) or "exact" (scipy)."""
    if mode == "thesis":
        return sine_integral_approx(x)
    if mode == "series":
        return sine_integral_series(x)
    if mode == "exact":
        return sine_integral_exact(x)
    raise ValueError(f"unknown Si mode {mode!r}; use one of {SI_MODES}")
