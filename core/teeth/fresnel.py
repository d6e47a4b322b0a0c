"""Fresnel reflectance of the thin dielectric enamel/gum boundary (eq. 5.1).

The boundary is a *thin* layer (transmitted light does not bend, eq. 5.2), so the reflectance is
evaluated as for light arriving from air, F(|omega . n|, eta), on either side of the boundary: no
total internal reflection occurs in a thin layer.

``fresnel_dielectric`` is the one implementation both tracers use: numpy arrays in the reference tracer,
scalars in the compiled one (``numba_kernels.numba_callable``).
"""

from __future__ import annotations

import numpy as np

from .numba_kernels import numba_callable

ETA_ENAMEL = 1.631  # Meng et al. 2009, thesis Sec. 5.5.1
ETA_GUMS = 1.33  # thesis Sec. 5.5.3


@numba_callable
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance F(cos_i, eta) of an air/dielectric interface (eq. 5.1):
    with c = min(|cos_i|, 1), cos_t = sqrt(max(1 - (1 - c^2) / eta^2, 0)),
    r_s = (c - eta cos_t) / (c + eta cos_t), r_p = (eta c - cos_t) / (eta c + cos_t), F = (r_s^2 + r_p^2) / 2.

    ``cos_i`` may have either sign; its magnitude is used (thin-layer, symmetric boundary). Arrays or scalars
    (float64); callable from numba code.
    """
    c = np.minimum(np.abs(cos_i), 1.0)
    sin_t2 = (1.0 - c * c) / (eta * eta)
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    rs = (c - eta * cos_t) / (c + eta * cos_t)
    rp = (eta * c - cos_t) / (eta * c + cos_t)
    return 0.5 * (rs * rs + rp * rp)
