"""The default spread of the enamel/dentin sigmoid blend (eq. 5.15), apart from ``sigmoid_blend`` so that code
which only needs the number (the Blender add-on) does not import the compiled kernels' machinery (numba)."""

from __future__ import annotations

import math

# the weight goes from 5 % to 95 % over 2 mm across the dentin surface: 1 / s_l = ln(19) per mm
DEFAULT_SPREAD_MM = 1.0 / math.log(19.0)
