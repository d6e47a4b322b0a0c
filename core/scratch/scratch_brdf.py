"""Point-evaluated scratch BRDFs in direction-cosine space: coherent (eq. 4.1-4.5) and incoherent
(eq. 4.6-4.11). Used as references and for directional/point lights.

Both take global direction cosines xi = (wi + wo)_perp (..., 2) in the scratch plane's frame, the
shaded point x (2,) um, straight segments (M, 4) um with widths/depths (M,) um and one wavelength
lam_um. The BRDF is in the measure d xi (L = int f L_i d xi, eq. 4.24), i.e. it includes cos(theta_i).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .scratch_model_terms import (
    base_response_flat,
    coherence_area,
    scratch_depth_term,
    scratch_depth_term_sq,
    scratch_phase_term,
    scratch_phase_term_infinite,
    scratch_width_term,
)


def _segment_frames(segments: np.ndarray, x: np.ndarray):
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    d = seg[:, 2:] - seg[:, :2]
    length = np.linalg.norm(d, axis=1)
    t = d / length[:, None]
    b = np.stack([-t[:, 1], t[:, 0]], 1)
    rel = seg[:, :2] - np.asarray(x, dtype=np.float64)
    return t, b, length, np.einsum("mi,mi->m", rel, t), np.einsum("mi,mi->m", rel, b)


def scratch_responses(
    xi: ArrayLike,
    x: ArrayLike,
    segments: ArrayLike,
    width_um: ArrayLike,
    depth_um: ArrayLike,
    lam_um: float,
    sigma_um: float = 60.0,
    infinite: bool = False,
) -> np.ndarray:
    """S^(m)(xi^(m), x) = W D eta (eq. 4.2-4.5) for every segment: complex array (..., M)."""
    xi = np.asarray(xi, dtype=np.float64)
    t, b, length, s_t, s_b = _segment_frames(np.asarray(segments), np.asarray(x))
    xi1 = xi[..., None, 0] * t[:, 0] + xi[..., None, 1] * t[:, 1]
    xi2 = xi[..., None, 0] * b[:, 0] + xi[..., None, 1] * b[:, 1]
    if infinite:
        eta = scratch_phase_term_infinite(xi1, xi2, s_b, lam_um, sigma_um)
    else:
        eta = scratch_phase_term(xi1, xi2, s_t, s_b, length, lam_um, sigma_um)
    return scratch_width_term(xi2, width_um, lam_um) * scratch_depth_term(depth_um, lam_um) * eta


def coherent_brdf(
    xi: ArrayLike,
    x: ArrayLike,
    segments: ArrayLike,
    width_um: ArrayLike,
    depth_um: ArrayLike,
    lam_um: float,
    sigma_um: float = 60.0,
    phases: ArrayLike | None = None,
) -> np.ndarray:
    """Eq. 4.1: |B - sum_m e^{i phi_m} S^(m)|^2 / (pi sigma^2 lambda^2) with the flat-surface base B.

    ``phases`` (..., M) optionally multiplies each scratch response by e^{i phi_m} (random-phase tests).
    """
    xi = np.asarray(xi, dtype=np.float64)
    S = scratch_responses(xi, x, segments, width_um, depth_um, lam_um, sigma_um)
    if phases is not None:
        S = S * np.exp(1j * np.asarray(phases))
    B = base_response_flat(xi[..., 0], xi[..., 1], lam_um, sigma_um)
    return np.abs(B - S.sum(axis=-1)) ** 2 / (np.pi * sigma_um**2 * lam_um**2)


def incoherent_brdf(
    xi: ArrayLike,
    x: ArrayLike,
    segments: ArrayLike,
    width_um: ArrayLike,
    depth_um: ArrayLike,
    lam_um: float,
    sigma_um: float = 60.0,
    rho_c: float = 0.0,
    infinite: bool = False,
) -> np.ndarray:
    """Eq. 4.6-4.7: ((1 - rho_c) |B|^2 + sum_m |S^(m)|^2) / (A_C lambda^2)."""
    xi = np.asarray(xi, dtype=np.float64)
    S = scratch_responses(xi, x, segments, width_um, depth_um, lam_um, sigma_um, infinite)
    B = base_response_flat(xi[..., 0], xi[..., 1], lam_um, sigma_um)
    return ((1.0 - rho_c) * B**2 + (np.abs(S) ** 2).sum(axis=-1)) / (coherence_area(sigma_um) * lam_um**2)


def scratch_brdf_separable(
    xi1: ArrayLike, xi2: ArrayLike, eta_sq_spatial: ArrayLike, width_um: ArrayLike, depth_um: ArrayLike,
    lam_um: ArrayLike, sigma_um: float = 60.0,
) -> np.ndarray:
    """|S^(m)|^2 / (A_C lambda^2) with the separable |eta|^2 = |eta_s|^2 |eta_a|^2 (eq. 4.9-4.11)."""
    k = 2 * np.pi / np.asarray(lam_um, dtype=np.float64)
    w = np.asarray(width_um, dtype=np.float64)
    return (
        w**2 * np.sinc(w * np.asarray(xi2) / lam_um) ** 2 * scratch_depth_term_sq(depth_um, lam_um)
        * np.asarray(eta_sq_spatial) * np.exp(-((sigma_um * k * np.asarray(xi1)) ** 2))
        / (coherence_area(sigma_um) * np.asarray(lam_um) ** 2)
    )
