"""Starting points for hand-made fabrics (constants for the SGGX Fabric group).

sigma_z = 1 is the projected standard deviation along the basis' z axis; sigma_x = sigma_y > 1 makes
the flakes fibre-like around z (standing pile: velvet's grazing sheen), < 1 surface-like.
"""

import math

import numpy as np

from ...core.fabric.quaternion import quat_from_axis_angle, quat_multiply


def tilted_quat(tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """Fibre basis whose z axis leans ``tilt`` degrees from the normal towards ``azimuth`` (from +x)."""
    yaw = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(math.radians(azimuth_deg)))
    lean = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(math.radians(tilt_deg)))
    return quat_multiply(yaw, lean)


PRESETS = {
    "VELVET": dict(kd=(0.035, 0.004, 0.008), ks=(0.75, 0.07, 0.11), sigma=(2.5, 2.5), tilt=(0.0, 0.0)),
    "CORDUROY": dict(kd=(0.06, 0.035, 0.015), ks=(0.55, 0.36, 0.18), sigma=(2.2, 0.9), tilt=(10.0, 90.0)),
    "PLUSH": dict(kd=(0.10, 0.07, 0.04), ks=(0.6, 0.5, 0.35), sigma=(1.8, 1.8), tilt=(30.0, 270.0)),
}

PRESET_ITEMS = [
    ("VELVET", "Velvet", "Short dense upright pile: strong grazing sheen"),
    ("CORDUROY", "Corduroy", "Anisotropic pile along the wales"),
    ("PLUSH", "Plush", "Long pile combed over by 30 degrees"),
]
