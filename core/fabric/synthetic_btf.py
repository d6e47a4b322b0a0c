"""Synthetic BTFs of a known fabric model, for tests, demos and benchmarks.

Spatially varying ground truth (smooth fields plus patch boundaries), fibre bases tilted up to
``max_tilt_deg`` from the normal, optional multiplicative Gaussian noise; values are
``f_r cos(theta_i)`` of eq. 3.9, written with :func:`btf_io.save_btf`.
"""

from __future__ import annotations

import numpy as np

from .parameter_maps import FabricMaps, make_maps
from .quaternion import quat_from_axis_angle, quat_multiply
from .sggx_brdf import sggx_btf_value

GOLDEN = np.pi * (3.0 - np.sqrt(5.0))


def cap_directions(n: int, theta_max_deg: float = 75.0, rotation: float = 0.0) -> np.ndarray:
    """``n`` well-spread unit directions on the cap ``theta <= theta_max`` (Fibonacci spiral, equal area)."""
    k = np.arange(n) + 0.5
    zmin = np.cos(np.radians(theta_max_deg))
    z = 1.0 - k / n * (1.0 - zmin)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = k * GOLDEN + rotation
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def light_view_pairs(n_lights: int, n_views: int, theta_max_deg: float = 75.0,
                     rotation: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """All ``n_lights x n_views`` pairs ``(wi, wo)`` (light-major) of two interleaved spiral sets."""
    lights = cap_directions(n_lights, theta_max_deg, rotation)
    views = cap_directions(n_views, theta_max_deg, rotation + 0.5 * GOLDEN + 1.0)
    wi = np.repeat(lights, n_views, axis=0)
    wo = np.tile(views, (n_lights, 1))
    return wi, wo


def synthetic_maps(height: int, width: int, seed: int = 0, max_tilt_deg: float = 30.0) -> FabricMaps:
    """Ground-truth parameter maps: smooth fields with four brushing patches.

    sigma_x in [0.12, 0.45], sigma_y / sigma_x in [1, 3] (capped at 1), tilt of the z axis up to
    ``max_tilt_deg``, k_d in [0.02, 0.3], k_s in [0.25, 0.7] per channel.
    """
    rng = np.random.default_rng(seed)
    v, u = np.meshgrid((np.arange(height) + 0.5) / height, (np.arange(width) + 0.5) / width, indexing="ij")

    def field(lo, hi):
        a = rng.uniform(0.5, 2.0, 2)
        p = rng.uniform(0, 2 * np.pi, 2)
        s = 0.5 + 0.25 * np.sin(2 * np.pi * a[0] * u + p[0]) + 0.25 * np.sin(2 * np.pi * a[1] * v + p[1])
        return lo + (hi - lo) * s

    patch = (u > 0.5).astype(int) + 2 * (v > 0.5).astype(int)
    base_az = rng.uniform(0, 2 * np.pi, 4)[patch]
    azimuth = base_az + 0.6 * np.sin(2 * np.pi * (u + 0.3 * v))
    tilt = np.radians(max_tilt_deg) * field(0.0, 1.0)
    tilt_dir = azimuth + field(-0.5, 0.5)
    sx = field(0.12, 0.45)
    sy = np.minimum(sx * field(1.0, 3.0), 1.0)
    q_az = quat_from_axis_angle(np.broadcast_to([0.0, 0.0, 1.0], u.shape + (3,)), azimuth)
    tilt_axis = np.stack([-np.sin(tilt_dir), np.cos(tilt_dir), np.zeros_like(u)], axis=-1)
    q = quat_multiply(quat_from_axis_angle(tilt_axis, tilt), q_az)
    kd = np.stack([field(0.02, 0.3) for _ in range(3)], axis=-1)
    ks = np.stack([field(0.25, 0.7) for _ in range(3)], axis=-1)
    return make_maps(kd, ks, np.stack([sx, sy], axis=-1), q)


def render_btf(maps: FabricMaps, wi: np.ndarray, wo: np.ndarray, noise: float = 0.0, seed: int = 0,
               out: np.ndarray | None = None, chunk: int = 64, noise_kind: str = "relative") -> np.ndarray:
    """BTF values ``(N, H, W, 3)`` float32 = ``f_r cos(theta_i)`` of the maps.

    ``noise_kind="relative"``: multiplicative Gaussian noise, ``v (1 + noise * n)`` (0.05 = 5 %);
    ``"peak"``: additive Gaussian noise with standard deviation ``noise`` times the texel's largest
    value over the given directions. Results are clipped at zero."""
    if noise_kind not in ("relative", "peak"):
        raise ValueError(f"noise_kind must be 'relative' or 'peak', got {noise_kind!r}")
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    h, w = maps.shape
    n = wi.shape[0]
    if out is None:
        out = np.empty((n, h, w, 3), dtype=np.float32)
    rng = np.random.default_rng(seed)
    kd, ks = maps.kd[None].astype(np.float64), maps.ks[None].astype(np.float64)
    sg, bq = maps.sigma[None].astype(np.float64), maps.basis[None].astype(np.float64)
    rows = max(1, 2_000_000 // max(1, w * chunk))
    for k in range(0, n, chunk):
        dirs_i = wi[k:k + chunk, None, None, :]
        dirs_o = wo[k:k + chunk, None, None, :]
        for y in range(0, h, rows):
            sl = slice(y, y + rows)
            vals = sggx_btf_value(dirs_i, dirs_o, kd[:, sl], ks[:, sl], sg[:, sl], bq[:, sl])
            if noise > 0 and noise_kind == "relative":
                vals = np.maximum(vals * (1.0 + noise * rng.standard_normal(vals.shape)), 0.0)
            out[k:k + chunk, sl] = vals
    if noise > 0 and noise_kind == "peak":
        peak = np.zeros((h, w, 1), dtype=np.float32)
        for k in range(0, n, chunk):
            peak = np.maximum(peak, out[k:k + chunk].max(axis=(0, 3))[..., None])
        for k in range(0, n, chunk):
            blk = out[k:k + chunk]
            out[k:k + chunk] = np.maximum(blk + noise * peak * rng.standard_normal(blk.shape), 0.0)
    return out
