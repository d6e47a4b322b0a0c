"""Parameter maps of the hand-made fabric presets (velvet, corduroy, plush): the starting point of a
new fabric material and of the sample library, so both look the same and both can be brushed.

sigma_z = 1 is the projected standard deviation along the basis' z axis; sigma_x = sigma_y > 1 makes
the flakes fibre-like around z (standing pile: velvet's grazing sheen), < 1 surface-like (eq. 3.5-3.8).
Corduroy's wales are ridges across u: the pile leans up to 25 degrees to either flank of each ridge
and the grooves between ridges are darker.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import UserError
from .parameter_maps import FabricMaps, make_maps
from .quaternion import quat_from_axis_angle, quat_multiply

PRESETS = {
    "VELVET": dict(kd=(0.035, 0.004, 0.008), ks=(0.75, 0.07, 0.11), sigma=(2.5, 2.5), tilt=(0.0, 0.0)),
    "CORDUROY": dict(kd=(0.06, 0.035, 0.015), ks=(0.55, 0.36, 0.18), sigma=(2.2, 0.9), tilt=(10.0, 90.0)),
    "PLUSH": dict(kd=(0.10, 0.07, 0.04), ks=(0.6, 0.5, 0.35), sigma=(1.8, 1.8), tilt=(30.0, 270.0)),
}
CORDUROY_WALES = 24  # ridges across the map
MAP_SIZE = 256


def tilted_quat(tilt_deg: float | np.ndarray, azimuth_deg: float | np.ndarray) -> np.ndarray:
    """Fibre basis whose z axis leans ``tilt`` degrees from the normal towards ``azimuth`` (from +x); arrays of
    angles (broadcast together) give an array of quaternions (..., 4)."""
    tilt, azimuth = np.broadcast_arrays(np.asarray(tilt_deg, dtype=np.float64),
                                        np.asarray(azimuth_deg, dtype=np.float64))
    yaw = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), azimuth * (math.pi / 180.0))
    lean = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), tilt * (math.pi / 180.0))
    return quat_multiply(yaw, lean)


def preset_maps(preset: str, size: int = MAP_SIZE, seed: int = 0) -> FabricMaps:
    """The maps of ``preset`` (``size`` x ``size`` texels, BTF frame), with a little texel-level
    variation of the colours (real pile is never uniform); corduroy with its wales."""
    if preset not in PRESETS:
        raise UserError(f"unknown fabric preset {preset!r}; one of {', '.join(PRESETS)}")
    p = PRESETS[preset]
    rng = np.random.default_rng(seed)
    jitter = 1.0 + 0.08 * rng.standard_normal((size, size, 1))
    kd = np.clip(np.asarray(p["kd"]) * jitter, 0, 1)
    ks = np.clip(np.asarray(p["ks"]) * jitter, 0, 1)
    sigma = np.broadcast_to(np.asarray(p["sigma"]), (size, size, 2))
    basis = np.broadcast_to(tilted_quat(*p["tilt"]), (size, size, 4))
    if preset == "CORDUROY":
        phase = ((np.arange(size) + 0.5) / size * CORDUROY_WALES) % 1.0
        lean = np.where(phase < 0.5, 1.0, -1.0) * 25.0 * np.abs(np.sin(np.pi * phase * 2.0))
        quats = tilted_quat(np.abs(lean), np.where(lean >= 0, 0.0, 180.0))
        basis = np.broadcast_to(quats[None, :, :], (size, size, 4))
        kd = np.where((np.abs(phase - 0.5) > 0.42)[None, :, None], kd * 0.5, kd)
    return make_maps(kd=kd, ks=ks, sigma=sigma, basis=basis)
