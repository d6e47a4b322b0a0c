"""Spectral to linear sRGB: CIE 1931 2-degree colour matching functions and band quadrature.

The matching functions are the analytic multi-lobe piecewise-Gaussian fit of Wyman, Sloan and
Shirley, "Simple Analytic Approximations to the CIE XYZ Color Matching Functions", JCGT 2(2), 2013:

    g(l; mu, s1, s2) = exp(-(l - mu)^2 / (2 s^2)),  s = s1 if l < mu else s2
    xbar = 1.056 g(599.8, 37.9, 31.0) + 0.362 g(442.0, 16.0, 26.7) - 0.065 g(501.1, 20.4, 26.2)
    ybar = 0.821 g(568.8, 46.9, 40.5) + 0.286 g(530.9, 16.3, 31.1)
    zbar = 1.217 g(437.0, 11.8, 36.0) + 0.681 g(459.0, 26.0, 13.8)

Spectral samples are turned into colour by band quadrature: the visible range is split into bands,
each band is represented by one wavelength (the shader evaluates the scratch model there) and
weighted by the integral of the matching functions over the band. Weights are normalised so that
an equal-energy spectrum of value 1 has Y = 1. XYZ -> linear sRGB uses the IEC 61966-2-1 matrix
(D65 white). Two quadratures are provided (thesis Sec. 4.A compares them):

* ``"rgb"``: 3 representative wavelengths 630, 532, 465 nm; bands split at the midpoints.
* ``"16"``: 16 equal bands over 380-780 nm, sampled at the band centres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

VISIBLE_NM = (380.0, 780.0)
RGB_WAVELENGTHS_NM = (630.0, 532.0, 465.0)

_LOBES = {
    "x": ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    "y": ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    "z": ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
}

XYZ_TO_LINEAR_SRGB = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)


def cie1931_cmf(wavelength_nm: ArrayLike) -> np.ndarray:
    """CIE 1931 2-degree (xbar, ybar, zbar) at the given wavelengths (nm); shape (..., 3)."""
    lam = np.asarray(wavelength_nm, dtype=np.float64)
    out = []
    for key in ("x", "y", "z"):
        acc = np.zeros_like(lam)
        for a, mu, s1, s2 in _LOBES[key]:
            s = np.where(lam < mu, s1, s2)
            acc = acc + a * np.exp(-0.5 * ((lam - mu) / s) ** 2)
        out.append(acc)
    return np.stack(out, axis=-1)


def band_edges(mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(representative wavelengths, band edges) in nm for ``"rgb"`` or ``"16"``, ascending."""
    lo, hi = VISIBLE_NM
    if mode == "rgb":
        lam = np.sort(np.asarray(RGB_WAVELENGTHS_NM))
        mids = 0.5 * (lam[1:] + lam[:-1])
        edges = np.concatenate([[lo], mids, [hi]])
        return lam, edges
    if mode == "16":
        edges = np.linspace(lo, hi, 17)
        return 0.5 * (edges[1:] + edges[:-1]), edges
    raise ValueError(f"unknown spectral mode {mode!r}; use 'rgb' or '16'")


def band_xyz_weights(edges_nm: ArrayLike, samples_per_nm: float = 2.0) -> np.ndarray:
    """(3, n_bands) integrals of the matching functions over each band, normalised so sum(Y) = 1."""
    from scipy.integrate import trapezoid

    edges = np.asarray(edges_nm, dtype=np.float64)
    w = np.zeros((3, edges.size - 1))
    for i in range(edges.size - 1):
        n = max(8, int((edges[i + 1] - edges[i]) * samples_per_nm) + 1)
        lam = np.linspace(edges[i], edges[i + 1], n)
        w[:, i] = trapezoid(cie1931_cmf(lam), lam, axis=0)
    return w / w[1].sum()


def spectral_to_srgb_matrix(mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths_nm (n,), M (3, n)) with linear sRGB = M @ spectral samples.

    The wavelengths are ascending; an equal-energy spectrum (all ones) maps to Y = 1.
    """
    lam, edges = band_edges(mode)
    return lam, XYZ_TO_LINEAR_SRGB @ band_xyz_weights(edges)


def spectrum_to_xyz(wavelength_nm: ArrayLike, values: ArrayLike) -> np.ndarray:
    """XYZ of a densely sampled spectrum (trapezoid rule), normalised so equal energy has Y = 1."""
    from scipy.integrate import trapezoid

    lam = np.asarray(wavelength_nm, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    cmf = cie1931_cmf(lam)
    xyz = trapezoid(v[..., None] * cmf, lam, axis=-2)
    return xyz / trapezoid(cmf[:, 1], lam)


def xyz_to_linear_srgb(xyz: ArrayLike) -> np.ndarray:
    """Linear sRGB (D65) from CIE XYZ, shape (..., 3)."""
    return np.asarray(xyz, dtype=np.float64) @ XYZ_TO_LINEAR_SRGB.T
