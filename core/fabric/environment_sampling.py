"""Importance sampling of an equirectangular environment: the fabric's exact world light (issue 38).

The world's contribution to the fabric's reflected radiance is eq. 3.9 integrated against the
environment,

    L_o(wo) = int_H f_r(wi, wo) cos(theta_i) L_env(wi) V(wi) dwi,

and the shader (``cycles_osl/ms_sggx_fabric.osl``) estimates it with K directions per shading sample,

    L_o(wo) ~ (1 / K) sum_k f_r(wi_k, wo) cos(theta_k) L_env(wi_k) V(wi_k) / p(wi_k).

Directions are drawn from a density proportional to the environment's brightness: texel j is picked
with probability P_j = b_j Omega_j / sum_i b_i Omega_i (b = mean of the texel's RGB radiance, Omega_j
its solid angle) by Walker's alias method (a uniform index i, kept if u < q_i, else its alias a_i:
two or three table reads in the shader), then a direction uniform in solid angle inside the texel,
so p(w) = P_j / Omega_j for w in texel j. Every texel with any radiance has P_j > 0: the estimator is
unbiased for the piecewise-constant environment of the table: what Cycles reads with Closest
interpolation at the table's size (maps wider than MAX_WIDTH are box-filtered first; with Linear
interpolation Cycles blends neighbouring texels, a difference below a texel's width).

Layout (Blender's world Environment Texture): u = atan2(d_y, -d_x) / 2 pi (mod 1), v = elevation / pi
+ 1/2, row 0 = the bottom row (v = 0). Texel (column c, row r) of a W x H map spans azimuth 2 pi [c,
c + 1] / W and z = sin(elevation) in [sin e_r, sin e_{r+1}], e_r = (r / H - 1/2) pi, so Omega = 2 pi /
W (sin e_{r+1} - sin e_r) and z is uniform inside it. Flat index j = r W + c.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAX_WIDTH = 1024  # environments wider than this are box-filtered down (fabric lobes are far wider)


class EnvironmentMapError(ValueError):
    """The environment cannot be sampled (not finite, negative, or the wrong shape)."""


@dataclass(frozen=True)
class EnvironmentTable:
    """What the shader reads: radiance, the alias table and the density of each texel (H, W)."""

    radiance: np.ndarray  # (H, W, 3) float32, row 0 = bottom
    threshold: np.ndarray  # (H, W) q_j: keep texel j when u < q_j
    alias: np.ndarray  # (H, W) int64 flat index a_j taken otherwise
    density: np.ndarray  # (H, W) P_j / Omega_j, the directional pdf inside texel j

    @property
    def shape(self) -> tuple[int, int]:
        return self.radiance.shape[:2]

    def probabilities(self) -> np.ndarray:
        """P_j as the alias table realises it (H, W): q_j / N plus (1 - q_i) / N for every i aliased to j."""
        n = self.threshold.size
        q = self.threshold.ravel().astype(np.float64)
        p = q / n
        np.add.at(p, self.alias.ravel(), (1.0 - q) / n)
        return p.reshape(self.shape)


def texel_solid_angles(h: int, w: int) -> np.ndarray:
    """Omega of each row's texels (H,), row 0 = bottom."""
    z = np.sin((np.arange(h + 1) / h - 0.5) * np.pi)
    return 2.0 * np.pi / w * np.diff(z)


def downsample(img: np.ndarray, max_width: int = MAX_WIDTH) -> np.ndarray:
    """Box-filter ``img`` (H, W, C) by about an integer factor f until W <= max_width and H <=
    max_width / 2 (H // f x W // f blocks of nearly equal size where the size is not a multiple of f;
    plain texel averages, not weighted by solid angle). Accumulates in float64 without a full-size
    copy."""
    h, w = img.shape[:2]
    f = int(max(np.ceil(w / max_width), np.ceil(h / max(max_width // 2, 1))))
    if f <= 1:
        return img
    rows = np.linspace(0, h, max(h // f, 1) + 1).round().astype(int)
    cols = np.linspace(0, w, max(w // f, 1) + 1).round().astype(int)
    s = np.add.reduceat(np.add.reduceat(img, rows[:-1], axis=0, dtype=np.float64), cols[:-1], axis=1)
    area = np.diff(rows)[:, None, None] * np.diff(cols)[None, :, None]
    return (s / area).astype(np.float32)


def _alias_table(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vose's alias method for probabilities ``p`` (N,) summing to 1: (threshold q, alias a)."""
    n = p.size
    scaled = p * n
    q = np.ones(n)
    alias = np.arange(n)
    small = list(np.flatnonzero(scaled < 1.0))
    large = list(np.flatnonzero(scaled >= 1.0))
    while small and large:
        s, g = small.pop(), large.pop()
        q[s] = scaled[s]
        alias[s] = g
        scaled[g] -= 1.0 - scaled[s]
        (small if scaled[g] < 1.0 else large).append(g)
    # what is left holds ~1 up to rounding: kept with probability 1
    return q, alias


def build_environment_table(radiance: np.ndarray, max_width: int = MAX_WIDTH) -> EnvironmentTable | None:
    """The sampling table of an environment (H, W, 3 or 4) in Blender's layout, row 0 = bottom.

    Returns None for an environment that is black everywhere (nothing to sample). Refuses radiance
    that is not finite or is negative with a one-line :class:`EnvironmentMapError`.
    """
    img = np.asarray(radiance)
    if img.ndim != 3 or img.shape[2] < 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise EnvironmentMapError(f"an environment must be an (H, W, 3) image, got shape {img.shape}")
    img = img[..., :3]
    if not np.all(np.isfinite(img)):
        raise EnvironmentMapError("the environment holds NaN or infinite radiance")
    if np.any(img < 0):
        raise EnvironmentMapError(f"the environment holds negative radiance (down to {float(img.min()):.3g})")
    img = downsample(np.asarray(img, np.float32), max_width)
    h, w = img.shape[:2]
    omega = texel_solid_angles(h, w)[:, None]
    weight = img.astype(np.float64).mean(axis=2) * omega
    total = weight.sum()
    if not total > 0:
        return None
    p = (weight / total).ravel()
    q, alias = _alias_table(p)
    density = p.reshape(h, w) / omega
    return EnvironmentTable(img, q.reshape(h, w), alias.reshape(h, w), density)


def sample_directions(table: EnvironmentTable, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The shader's sampling, in numpy: uniforms ``u`` (N, 4) -> directions (N, 3), their radiance
    (N, 3) and pdf (N,) with respect to solid angle."""
    h, w = table.shape
    n = h * w
    u = np.asarray(u, np.float64)
    i = np.minimum((u[:, 0] * n).astype(np.int64), n - 1)
    keep = u[:, 1] < table.threshold.ravel()[i]
    j = np.where(keep, i, table.alias.ravel()[i])
    row, col = np.divmod(j, w)
    az = 2.0 * np.pi * (col + u[:, 2]) / w
    z0 = np.sin((row / h - 0.5) * np.pi)
    z1 = np.sin(((row + 1) / h - 0.5) * np.pi)
    z = z0 + u[:, 3] * (z1 - z0)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    d = np.stack([-r * np.cos(az), r * np.sin(az), z], axis=-1)
    return d, table.radiance.reshape(n, 3)[j].astype(np.float64), table.density.ravel()[j]


def texel_of(table: EnvironmentTable, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of the texel that directions ``d`` (N, 3) fall in (Blender's equirect map)."""
    h, w = table.shape
    d = np.asarray(d, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = (np.arctan2(d[:, 1], -d[:, 0]) / (2.0 * np.pi)) % 1.0
    v = np.arcsin(np.clip(d[:, 2], -1.0, 1.0)) / np.pi + 0.5
    return np.minimum((v * h).astype(int), h - 1), np.minimum((u * w).astype(int), w - 1)


def pdf(table: EnvironmentTable, d: np.ndarray) -> np.ndarray:
    """Directional density p(d) of :func:`sample_directions` (N,)."""
    row, col = texel_of(table, d)
    return table.density[row, col]


def shader_files(table: EnvironmentTable) -> dict[str, np.ndarray]:
    """The two images the shader reads, as arrays with row 0 = the file's top row:
    ``radiance.exr`` (RGB radiance) and ``alias.exr`` (R threshold, G alias index, B density)."""
    alias_rgb = np.stack([table.threshold, table.alias.astype(np.float64), table.density], axis=-1)
    if table.alias.size >= 2**24:
        raise EnvironmentMapError("environment table too large for float32 indices")
    return {"radiance.exr": table.radiance[::-1], "alias.exr": alias_rgb[::-1].astype(np.float32)}
