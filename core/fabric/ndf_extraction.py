"""NDF extraction from a BTF slice (eq. 3.11) stored in a parabolic map (eq. 3.12).

``D_BTF(w_h) = 1/(2 pi) int_{Omega+} f_BTF(w_i, 2 (w_h . w_i) w_h - w_i) dw_i``

is estimated per parabolic-map cell with stratified Monte Carlo over ``w_i`` (jittered strata of
equal solid angle). The BTF is only known at its measured pairs, so ``f_BTF`` at a Monte Carlo
pair is the measured sample nearest in ``(w_i, w_o)`` (reciprocity: ``(w_o, w_i)`` is used too);
pairs farther than ``max_distance`` from every sample count as missing. All texels share the
directions, so the estimator is one linear operator ``A`` (cells x samples) applied to every texel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import UserError


def parabolic_coords(w: np.ndarray) -> np.ndarray:
    """eq. 3.12: unit upper-hemisphere vectors -> ``(x', y')`` in [0, 1]^2."""
    w = np.asarray(w, dtype=np.float64)
    return np.stack([0.5 + 0.5 * w[..., 0] / (w[..., 2] + 1), 0.5 + 0.5 * w[..., 1] / (w[..., 2] + 1)], -1)


def parabolic_direction(xy: np.ndarray) -> np.ndarray:
    """Inverse of eq. 3.12 (valid inside the disk ``|2 xy - 1| <= 1``)."""
    a = 2.0 * np.asarray(xy, dtype=np.float64) - 1.0
    r2 = np.sum(a * a, axis=-1)
    return np.stack([2 * a[..., 0], 2 * a[..., 1], 1 - r2], axis=-1) / (1 + r2)[..., None]


def parabolic_solid_angle(xy: np.ndarray) -> np.ndarray:
    """Solid angle per unit area of the parabolic map, ``dw = 16 / (1 + r^2)^2 dx' dy'``."""
    a = 2.0 * np.asarray(xy, dtype=np.float64) - 1.0
    r2 = np.sum(a * a, axis=-1)
    return 16.0 / (1.0 + r2) ** 2


@dataclass
class NdfOperator:
    """Linear NDF estimator: ``D[cells, texels] = A @ f[samples, texels]`` (f = BRDF values)."""

    A: np.ndarray  # (cells, N) float64
    directions: np.ndarray  # (cells, 3) cell-centre half vectors
    solid_angle: np.ndarray  # (cells,) solid angle of each cell
    valid: np.ndarray  # (cells,) bool: cell inside the disk with measured coverage
    resolution: int

    def apply(self, f: np.ndarray) -> np.ndarray:
        """NDF per texel from BRDF values ``f`` of shape (N, ...) -> (cells, ...)."""
        return self.A @ f.reshape(f.shape[0], -1)

    def to_image(self, ndf: np.ndarray) -> np.ndarray:
        """One texel's NDF ``(cells,)`` as the parabolic map image ``(res, res)`` of eq. 3.12
        (row = y', column = x'); cells without data are 0."""
        img = np.where(self.valid, np.asarray(ndf, dtype=np.float64), 0.0)
        return img.reshape(self.resolution, self.resolution)


def ndf_operator(wi: np.ndarray, wo: np.ndarray, resolution: int = 24, strata: int = 12,
                 max_distance: float = 0.3, seed: int = 0) -> NdfOperator:
    """Build the stratified Monte Carlo estimator of eq. 3.11 on a ``resolution^2`` parabolic map.

    ``strata^2`` jittered ``w_i`` samples (uniform in ``cos theta`` and ``phi``, equal solid angle)
    per cell; the measured sample nearest to each Monte Carlo pair supplies ``f_BTF``.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    n = wi.shape[0]
    tree = cKDTree(np.concatenate([np.concatenate([wi, wo], 1), np.concatenate([wo, wi], 1)], 0))
    c = (np.arange(resolution) + 0.5) / resolution
    xy = np.stack(np.meshgrid(c, c, indexing="xy"), axis=-1).reshape(-1, 2)  # row-major: y then x
    inside = np.sum((2 * xy - 1) ** 2, axis=-1) <= 1.0
    h = parabolic_direction(np.where(inside[:, None], xy, 0.5))
    rng = np.random.default_rng(seed)
    s = strata
    ju = (np.arange(s)[:, None] + rng.random((s, s))) / s
    jv = (np.arange(s)[None, :] + rng.random((s, s))) / s
    cos_t = ju.reshape(-1)  # uniform in cos(theta) on the hemisphere = uniform solid angle
    phi = 2 * np.pi * jv.reshape(-1)
    sin_t = np.sqrt(1 - cos_t**2)
    mc_wi = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)  # (S, 3)
    cells = h.shape[0]
    A = np.zeros((cells, n))
    dot = h @ mc_wi.T  # (cells, S)
    mc_wo = 2 * dot[:, :, None] * h[:, None, :] - mc_wi[None]  # (cells, S, 3)
    above = mc_wo[..., 2] > 0
    pairs = np.concatenate([np.broadcast_to(mc_wi, mc_wo.shape), mc_wo], axis=-1).reshape(-1, 6)
    dist, idx = tree.query(pairs)
    idx = np.where(idx >= n, idx - n, idx).reshape(cells, -1)
    found = (dist.reshape(cells, -1) <= max_distance) & above
    # f = 0 where w_o is below the horizon; missing measured pairs are excluded and the mean renormalised
    usable = found | ~above
    n_use = usable.sum(axis=1)
    valid = inside & (found.sum(axis=1) >= max(3, s * s // 8))
    weight = np.where(n_use > 0, 1.0 / np.maximum(n_use, 1), 0.0)  # (1/2pi) * (2pi / S_eff) per hit
    rows = np.repeat(np.arange(cells), idx.shape[1]).reshape(cells, -1)
    np.add.at(A, (rows[found], idx[found]), np.broadcast_to(weight[:, None], found.shape)[found])
    A[~valid] = 0.0
    sa = parabolic_solid_angle(xy) / resolution**2
    return NdfOperator(A=A, directions=h, solid_angle=np.where(inside, sa, 0.0), valid=valid,
                       resolution=resolution)


MIN_NDF_CELLS = 3  # the initial basis (eq. 3.13-3.16) needs a peak and a spread around it


def check_ndf_coverage(op: NdfOperator, source: str, pairs: int) -> None:
    """Refuse a BTF whose light/view pairs cover too few half vectors for the NDF of eq. 3.11: the
    fit's initial basis (eq. 3.13-3.16) is undefined there. One line naming the file and the counts."""
    n_valid = int(op.valid.sum())
    if n_valid < MIN_NDF_CELLS:
        cells = int((op.solid_angle > 0).sum())
        raise UserError(f"{source}: its {pairs} light/view pairs cover {n_valid} of the {cells} half-vector cells "
                        f"of the fibre distribution, the fit needs at least {MIN_NDF_CELLS}: measure more "
                        "directions (e.g. 8 lights x 8 views or more)")
