"""Logistic blending of enamel and dentin parameters by signed distance to the dentin (eq. 5.15-5.18).

q > 0 outside the dentin (in enamel), q < 0 inside it. ``l(q) = 1 / (1 + exp(-q / s_l))`` weights the
enamel parameters, ``1 - l`` the dentin ones. The default spread puts 90 % of the transition within
+-1 mm of the border ("major influence is 1 mm around the border"): l(1 mm) = 0.95.

``blend_weight`` is the one implementation both tracers use: numpy arrays in the reference tracer, scalars in
the compiled one (``numba_kernels.numba_callable``).
"""

from __future__ import annotations

import numpy as np

from .blend_spread import DEFAULT_SPREAD_MM
from .numba_kernels import numba_callable

__all__ = ["DEFAULT_SPREAD_MM", "blend_weight", "blend_weight_dq"]


@numba_callable
def blend_weight(q, spread=DEFAULT_SPREAD_MM):
    """l(q) = 1 / (1 + exp(-q / s)) = (1 + tanh(q / 2s)) / 2 of eq. 5.15, s = ``spread``. Arrays or scalars;
    callable from numba code."""
    return 0.5 * (1.0 + np.tanh(0.5 * q / spread))


@numba_callable
def blend_weight_dq(q, spread=DEFAULT_SPREAD_MM):
    """dl/dq = e^{q/s} / (s (1 + e^{q/s})^2) = l (1 - l) / s (eq. 5.16). Arrays or scalars; callable from numba
    code."""
    lw = blend_weight(q, spread)
    return lw * (1.0 - lw) / spread


def mix(enamel_value, dentin_value, lw: np.ndarray):
    """x_mix = x_e l + (1 - l) x_d (eq. 5.17-5.18, 5.21)."""
    return enamel_value * lw + (1.0 - lw) * dentin_value
