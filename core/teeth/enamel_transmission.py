"""Transmission through the thin enamel (or gum) boundary layer, eq. 5.2 and its derivative eq. 5.10.

The transmitted weight of a non-bending crossing is ``a_t(chi) (1 - F)``; ``a_t`` is stored in a UV
texture of the outer mesh (``(H, W, 3)`` RGB, a 1 x 1 texture is the "homogeneous" case) and looked
up bilinearly (u wraps around, v is clamped). Per path, d log f / d a_t = 1 / a_t (eq. 5.10), so
the derivative w.r.t. texel i is ``w_i / a_t`` with ``w_i`` the bilinear weight.
"""

from __future__ import annotations

import numpy as np


def bilinear_texels(uv: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat texel indices ``(N, 4)`` and bilinear weights ``(N, 4)`` for UVs ``(N, 2)``.

    Texel (row i, column j) has its centre at u = (j + 0.5) / W, v = (i + 0.5) / H; row 0 is v = 0.
    """
    h, w = shape
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[:, 0] * w - 0.5
    y = np.clip(uv[:, 1] * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x)
    y0 = np.minimum(np.floor(y), max(h - 2, 0))
    fx = x - x0
    fy = y - y0 if h > 1 else np.zeros_like(y)
    j0 = np.mod(x0.astype(np.int64), w)
    j1 = np.mod(j0 + 1, w)
    i0 = y0.astype(np.int64)
    i1 = np.minimum(i0 + 1, h - 1)
    idx = np.stack([i0 * w + j0, i0 * w + j1, i1 * w + j0, i1 * w + j1], axis=1)
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return idx, wts


def lookup_a_t(texture: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bilinear ``a_t`` lookup: returns values ``(N, 3)``, texel indices and weights ``(N, 4)``."""
    tex = np.asarray(texture, dtype=np.float64)
    idx, wts = bilinear_texels(uv, tex.shape[:2])
    flat = tex.reshape(-1, tex.shape[2])
    vals = np.einsum("nk,nkc->nc", wts, flat[idx])
    return vals, idx, wts

