"""Fresnel reflectance of the thin dielectric enamel/gum boundary (eq. 5.1).

The boundary is a *thin* layer (transmitted light does not bend, eq. 5.2), so the reflectance is
evaluated as for light arriving from air, F(|omega . n|, eta), on either side of the boundary: no
total internal reflection occurs in a thin layer.
"""

from __future__ import annotations

import numpy as np

ETA_ENAMEL = 1.631  # Meng et al. 2009, thesis Sec. 5.5.1
ETA_GUMS = 1.33  # thesis Sec. 5.5.3


def fresnel_dielectric(cos_i: np.ndarray, eta: float | np.ndarray) -> np.ndarray:
    """Unpolarised Fresnel reflectance F(cos_i, eta) of an air/dielectric interface (eq. 5.1).

    ``cos_i`` may have either sign; its magnitude is used (thin-layer, symmetric boundary).
    """
    c = np.clip(np.abs(np.asarray(cos_i, dtype=np.float64)), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.float64)
    sin_t2 = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (rs * rs + rp * rp)
