"""Per-tile fitting pipeline: NDF extraction (eq. 3.11-3.12) -> initial basis (3.13-3.16) ->
batched Levenberg-Marquardt (3.17-3.19). Everything is vectorised over the texels of the tile."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .initial_guess import initial_basis
from .levenberg_marquardt import (
    LmResult,
    Samples,
    _trial_moments,
    levenberg_marquardt,
    optimal_albedos,
    target_moments,
)
from .ndf_extraction import NdfOperator
from .quaternion import quat_from_axis_angle, quat_multiply


@dataclass
class FitOptions:
    """Knobs of the per-texel fit (defaults are the benchmarked configuration)."""

    weighting: str = "radiance"  # residual weight: "radiance" (f_r cos_i) or "brdf" (eq. 3.17 as printed)
    coarse_samples: int = 768  # samples used by the first LM stages (0 = all)
    starts: int = 3  # multi-start: the initial guess plus bases turned about their z axis
    start_iter: int = 12  # LM iterations run from every start before keeping the best
    coarse_iter: int = 20
    fine_iter: int = 8
    seed: int = 0


def _subset(n: int, k: int, seed: int) -> np.ndarray:
    if k <= 0 or k >= n:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=k, replace=False))


def initial_candidates(q0: np.ndarray, s0: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The eq. 3.13-3.16 estimate plus rescaled variants (the truncated hemisphere of measured half
    vectors biases eq. 3.16); the best one per texel seeds the LM."""
    iso = np.full_like(s0, 0.35)
    return [(q0, s0), (q0, s0 * 0.5), (q0, np.clip(s0 * 2.0, 0.02, 1.0)), (q0, iso),
            (q0, np.stack([s0[:, 0] * 0.5, s0[:, 1]], -1))]


def fit_tile(values: np.ndarray, samples: Samples, op: NdfOperator, options: FitOptions | None = None
             ) -> LmResult:
    """Fit the model to one tile. ``values``: (T, N, 3) stored BTF values ``f_r cos(theta_i)``."""
    opt = options or FitOptions()
    values = np.asarray(values, dtype=np.float64)
    t, n, _ = values.shape
    # eq. 3.11 on the luminance of the BRDF values
    f = (values @ np.full(3, 1.0 / 3.0)) / samples.wi[None, :, 2]
    ndf = op.apply(f.T)  # (cells, T)
    q0, s0 = initial_basis(ndf, op)
    sub = _subset(n, opt.coarse_samples, opt.seed)
    ss = samples.subset(sub)
    vs = np.ascontiguousarray(values[:, sub])
    y = np.ascontiguousarray(ss.targets(vs))
    kd = ss.kernel_data()
    e = ss.weight / np.pi
    kd["e64"] = e
    ee, (ey, yy) = float(e @ e), target_moments(y, e)
    best_cost = np.full(t, np.inf)
    best_q, best_s = q0.copy(), s0.copy()
    for qc, sc in initial_candidates(q0, s0):
        sc = np.clip(sc, 0.02, 5.0)
        _, _, c = optimal_albedos(_trial_moments(kd, np.log(sc), qc, y), ee, ey, yy)
        better = c < best_cost
        best_cost = np.where(better, c, best_cost)
        best_q[better], best_s[better] = qc[better], sc[better]
    # multi-start: near-isotropic or saddle starts (sigma_x ~ sigma_y) cannot find the tangent
    # direction by local descent, so also start from the basis turned about its z axis by
    # +-180/starts degrees with an anisotropic sigma, run a few LM iterations from every start
    # (one batch of starts x texels) and keep the best per texel.
    k = max(1, opt.starts)
    qs, sgs = [best_q], [best_s]
    gm = np.sqrt(best_s[:, 0] * best_s[:, 1])
    for j in range(1, k):
        ang = np.pi * j / k
        qs.append(quat_multiply(best_q, quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(ang))))
        sgs.append(np.stack([0.7 * gm, np.minimum(1.4 * gm, 1.0)], -1))
    res = levenberg_marquardt(ss, vs, np.concatenate(qs), np.concatenate(sgs), max_iter=opt.start_iter,
                              rows=np.tile(np.arange(t), k))
    pick = np.argmin(res.cost.reshape(k, t), axis=0) * t + np.arange(t)
    n_start = res.iterations
    res = levenberg_marquardt(ss, vs, res.quat[pick], res.sigma[pick], max_iter=opt.coarse_iter,
                              lam0=res.lam[pick])
    res.iterations += n_start
    if len(sub) < n:
        res2 = levenberg_marquardt(samples, values, res.quat, res.sigma, max_iter=opt.fine_iter,
                                   lam0=np.maximum(res.lam, 1e-4))
        res2.iterations += res.iterations
        res = res2
    return res
