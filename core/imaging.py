"""Display conversions for previews and contact sheets (the numbers stay linear elsewhere)."""

from __future__ import annotations

import numpy as np


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function applied to linear values clipped to [0, 1]."""
    x = np.clip(np.nan_to_num(np.asarray(linear, dtype=np.float64)), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def to_display_uint8(linear_rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB(A) float image -> 8-bit sRGB RGB, after ``2**exposure`` scaling."""
    rgb = np.asarray(linear_rgb)[..., :3] * (2.0**exposure)
    return np.round(linear_to_srgb(rgb) * 255.0).astype(np.uint8)
