"""Batched Levenberg-Marquardt fit of eq. 3.9 to BTF samples (eq. 3.17-3.19), all texels at once.

Per texel the unknowns are the fibre basis (quaternion, updated by a local rotation vector ``r``:
``M <- M exp([r]x)``), ``u = log(sigma_x, sigma_y)`` and the RGB ``k_s``, ``k_d``. The model value of
a sample is ``k_s,c G_n + k_d,c E_n`` with ``G = w g`` (``g`` = specular term of eq. 3.9) and
``E = w / pi``, where ``w`` is the residual weight (``cos theta_i`` by default, i.e. residuals in the
stored BTF quantity ``f_r cos theta_i``; ``w = 1`` gives eq. 3.17 literally). Because ``k_s, k_d``
enter linearly, every trial point uses their optimal non-negative values (variable projection) and
the damped Gauss-Newton system for the 5 nonlinear unknowns is the Schur complement of the full
normal equations, assembled from 7x7 moment matrices with batched BLAS: no per-texel Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import specular_moments
from .parameter_maps import SIGMA_RANGE
from .quaternion import quat_from_rotvec, quat_multiply, quat_to_matrix
from .specular_moments import specular_term

# the compiled sums; without numba the numpy ones below
_compiled = specular_moments if specular_moments.HAVE_NUMBA else None

LOG_SIGMA_MIN = np.log(SIGMA_RANGE[0])
LOG_SIGMA_MAX = np.log(SIGMA_RANGE[1])


@dataclass
class Samples:
    """Shared directions of a BTF slice: ``wi, wo`` (N, 3), residual weights ``weight`` (N,)."""

    wi: np.ndarray
    wo: np.ndarray
    weight: np.ndarray

    @classmethod
    def make(cls, wi: np.ndarray, wo: np.ndarray, weighting: str = "radiance") -> Samples:
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        if weighting == "radiance":
            w = wi[:, 2].copy()
        elif weighting == "brdf":
            w = np.ones(wi.shape[0])
        else:
            raise ValueError(f"unknown weighting {weighting!r} (radiance or brdf)")
        return cls(wi, wo, w)

    def subset(self, idx: np.ndarray) -> Samples:
        return Samples(self.wi[idx], self.wo[idx], self.weight[idx])

    def targets(self, values: np.ndarray) -> np.ndarray:
        """Weighted targets ``Y = w f_BTF`` from stored values ``f_r cos(theta_i)`` (..., N, 3)."""
        return values * (self.weight / self.wi[:, 2])[:, None]

    def kernel_data(self, dtype=np.float32) -> dict:
        h = self.wi + self.wo
        n = self.wi.shape[0]
        return {
            "n": n,
            "dirs": np.ascontiguousarray(np.concatenate([h, self.wi, self.wo], 0).T.astype(dtype)),
            "inv_hh": (1.0 / np.sum(h * h, axis=-1)).astype(dtype),
            "ci": self.wi[:, 2].astype(dtype),
            "co": self.wo[:, 2].astype(dtype),
            "wt": (self.weight / (4.0 * np.pi)).astype(dtype),
            # the same samples for the compiled sums (left out of the dict: the numpy ones run)
            "compiled": self.compiled_data(),
        }

    def compiled_data(self) -> tuple:
        """The samples as ``specular_moments`` takes them: ``h, wi, wo`` (3, N), ``1 / |h|^2``, ``w / 4 pi``
        and ``E = w / pi`` (N,), float64."""
        h = self.wi + self.wo
        return (np.ascontiguousarray(h.T), np.ascontiguousarray(self.wi.T), np.ascontiguousarray(self.wo.T),
                1.0 / np.sum(h * h, axis=-1), self.weight / (4.0 * np.pi), self.weight / np.pi)


CHUNK = 16  # texels per kernel call: keeps the temporaries in cache


def _kernel(kd: dict, rt: np.ndarray, sx2: np.ndarray, sy2: np.ndarray, derivatives: bool):
    """``G = w g`` (c, N) and ``d ln g / d theta`` (c, N, 5) for a chunk of texels (float32; ``specular_term``).

    ``rt``: (c, 3, 3) transposed basis matrices; ``sx2, sy2``: (c, 1) squared deviations.
    """
    n = kd["n"]
    loc = np.matmul(rt, kd["dirs"])  # (c, 3, 3N)
    g, *dlog = specular_term(loc[:, 0, :n], loc[:, 1, :n], loc[:, 2, :n],
                             loc[:, 0, n:2 * n], loc[:, 1, n:2 * n], loc[:, 2, n:2 * n],
                             loc[:, 0, 2 * n:], loc[:, 1, 2 * n:], loc[:, 2, 2 * n:],
                             kd["ci"], kd["co"], kd["inv_hh"], kd["wt"], sx2, sy2)
    if not derivatives:
        return g, None
    return g, np.stack(dlog, axis=-1)


def _prepare(log_sigma: np.ndarray, quat: np.ndarray, dtype=np.float32):
    rt = np.ascontiguousarray(quat_to_matrix(quat).transpose(0, 2, 1)).astype(dtype)
    sx2 = np.exp(2.0 * log_sigma[:, 0:1]).astype(dtype)
    sy2 = np.exp(2.0 * log_sigma[:, 1:2]).astype(dtype)
    return rt, sx2, sy2


def specular_terms(s: Samples, log_sigma: np.ndarray, quat: np.ndarray, derivatives: bool = False,
                   dtype=np.float64):
    """``G = w g`` (T, N) of eq. 3.9 and, optionally, ``d ln g / d(u_x, u_y, r_x, r_y, r_z)`` (T, N, 5)."""
    kd = s.kernel_data(dtype)
    rt, sx2, sy2 = _prepare(np.asarray(log_sigma, dtype=np.float64), quat, dtype)
    t = rt.shape[0]
    g = np.empty((t, kd["n"]), dtype=dtype)
    dl = np.empty((t, kd["n"], 5), dtype=dtype) if derivatives else None
    for a in range(0, t, CHUNK):
        sl = slice(a, a + CHUNK)
        gc, dc = _kernel(kd, rt[sl], sx2[sl], sy2[sl], derivatives)
        g[sl] = gc
        if derivatives:
            dl[sl] = dc
    return g, dl


def target_moments(y: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``E.Y`` and ``Y.Y`` (T, 3) per texel and channel of the weighted targets ``y`` (T, N, 3)."""
    if _compiled is None:
        return np.einsum("n,tnc->tc", e, y), np.einsum("tnc,tnc->tc", y, y)
    ey, yy = np.empty((y.shape[0], 3)), np.empty((y.shape[0], 3))
    _compiled.target_moments(np.ascontiguousarray(y), np.ascontiguousarray(e, dtype=np.float64), ey, yy)
    return ey, yy


def _rows(u: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    return np.arange(len(u)) if rows is None else np.asarray(rows, dtype=np.int64)


def _trial_moments(kd: dict, u: np.ndarray, quat: np.ndarray, y: np.ndarray, rows: np.ndarray | None = None
                   ) -> LinearMoments:
    """Moments ``G.G, G.E, G.Y`` (float64) for the optimal albedos at a trial point: texel k has parameters
    ``u[k], quat[k]`` and targets ``y[rows[k]]`` (``rows``: all of ``y`` in order where None)."""
    rows = _rows(u, rows)
    t = len(rows)
    if _compiled is not None and "compiled" in kd:
        rt, sx2, sy2 = _prepare(u, quat, np.float64)
        gg, ge, gy = np.empty(t), np.empty(t), np.empty((t, 3))
        _compiled.trial_moments(*kd["compiled"], rt, sx2[:, 0].copy(), sy2[:, 0].copy(), y, rows, gg, ge, gy)
        return LinearMoments(gg=gg, ge=ge, gy=gy)
    rt, sx2, sy2 = _prepare(u, quat)
    e = kd["e64"]
    gg, ge, gy = np.empty(t), np.empty(t), np.empty((t, 3))
    for a in range(0, t, CHUNK):
        sl = slice(a, a + CHUNK)
        g, _ = _kernel(kd, rt[sl], sx2[sl], sy2[sl], False)
        g = g.astype(np.float64)
        gg[sl] = np.einsum("tn,tn->t", g, g)
        ge[sl] = g @ e
        gy[sl] = np.matmul(g[:, None, :], y[rows[sl]])[:, 0]
    return LinearMoments(gg=gg, ge=ge, gy=gy)


def _normal_moments(kd: dict, u: np.ndarray, quat: np.ndarray, y: np.ndarray, rows: np.ndarray | None = None):
    """``B^T B`` (T, 7, 7) and ``B^T Y`` (T, 7, 3) for ``B = [dG/dtheta (5), G, E]`` (float64); texels as in
    ``_trial_moments``."""
    rows = _rows(u, rows)
    t = len(rows)
    m = np.empty((t, 7, 7))
    by = np.empty((t, 7, 3))
    if _compiled is not None and "compiled" in kd:
        rt, sx2, sy2 = _prepare(u, quat, np.float64)
        _compiled.normal_moments(*kd["compiled"], rt, sx2[:, 0].copy(), sy2[:, 0].copy(), y, rows, m, by)
        return m, by
    rt, sx2, sy2 = _prepare(u, quat)
    n = kd["n"]
    basis = np.empty((CHUNK, n, 7))
    basis[:, :, 6] = kd["e64"]
    for a in range(0, t, CHUNK):
        sl = slice(a, a + CHUNK)
        g, dl = _kernel(kd, rt[sl], sx2[sl], sy2[sl], True)
        c = g.shape[0]
        bc = basis[:c]
        np.multiply(g[..., None], dl, out=bc[:, :, :5])
        bc[:, :, 5] = g
        bt = bc.transpose(0, 2, 1)
        m[sl] = np.matmul(bt, bc)
        by[sl] = np.matmul(bt, y[rows[sl]])
    return m, by


@dataclass
class LinearMoments:
    """Sums over samples needed for the optimal ``k_s, k_d`` and the cost."""

    gg: np.ndarray  # (T,)
    ge: np.ndarray  # (T,)
    gy: np.ndarray  # (T, 3)


def optimal_albedos(mom: LinearMoments, ee: float, ey: np.ndarray, yy: np.ndarray):
    """Non-negative least-squares ``k_s, k_d`` (T, 3) for fixed geometry, and the cost (T,)."""
    det = mom.gg[:, None] * ee - mom.ge[:, None] ** 2
    ok = det > 1e-12 * np.maximum(mom.gg[:, None] * ee, 1e-300)
    safe = np.where(ok, det, 1.0)
    ks = np.where(ok, (ee * mom.gy - mom.ge[:, None] * ey) / safe, 0.0)
    kd = np.where(ok, (mom.gg[:, None] * ey - mom.ge[:, None] * mom.gy) / safe, ey / ee)
    # active set: one of them clipped at zero -> 1-D solution for the other
    ks_only = np.maximum(mom.gy / np.maximum(mom.gg[:, None], 1e-300), 0.0)
    kd_only = np.maximum(ey / ee, 0.0)
    bad = (ks < 0) | (kd < 0)

    def cost_of(a, c):
        return (a * a * mom.gg[:, None] + c * c * ee + 2 * a * c * mom.ge[:, None]
                - 2 * a * mom.gy - 2 * c * ey + yy)

    c1 = cost_of(ks_only, np.zeros_like(ks_only))
    c2 = cost_of(np.zeros_like(kd_only), kd_only)
    use1 = c1 <= c2
    ks = np.where(bad, np.where(use1, ks_only, 0.0), ks)
    kd = np.where(bad, np.where(use1, 0.0, kd_only), kd)
    cost = np.maximum(cost_of(ks, kd), 0.0).sum(axis=1)
    return ks, kd, cost


@dataclass
class LmResult:
    quat: np.ndarray  # (T, 4)
    sigma: np.ndarray  # (T, 2)
    ks: np.ndarray  # (T, 3)
    kd: np.ndarray  # (T, 3)
    cost: np.ndarray  # (T,) 0.5 * sum of squared weighted residuals (eq. 3.18)
    iterations: int
    lam: np.ndarray  # (T,) final damping (to continue a fit)


def levenberg_marquardt(s: Samples, values: np.ndarray, quat: np.ndarray, sigma: np.ndarray,
                        max_iter: int = 40, tol: float = 1e-8, lam0: np.ndarray | None = None,
                        rows: np.ndarray | None = None) -> LmResult:
    """Fit all texels of a tile at once. ``values`` (T, N, 3) stored BTF values; initial ``quat``
    (T, 4) and ``sigma`` (T, 2). Returns the fitted parameters and eq. 3.18 costs. With ``rows`` (T,),
    fitted texel k is row ``rows[k]`` of ``values`` (several starts of one texel share its row)."""
    y = np.ascontiguousarray(s.targets(np.asarray(values, dtype=np.float64)))
    kd = s.kernel_data()
    e = s.weight / np.pi
    kd["e64"] = e
    ee = float(e @ e)
    ey, yy = target_moments(y, e)
    rows = np.arange(y.shape[0]) if rows is None else np.asarray(rows, dtype=np.int64)
    ey, yy = ey[rows], yy[rows]
    t = len(rows)
    quat = np.array(quat, dtype=np.float64)
    u = np.log(np.clip(np.asarray(sigma, dtype=np.float64), 0.011, 9.9))
    ks, kd_, cost = optimal_albedos(_trial_moments(kd, u, quat, y, rows), ee, ey, yy)
    lam = np.full(t, 1e-2) if lam0 is None else np.array(lam0, dtype=np.float64)
    active = np.ones(t, dtype=bool)
    # converged to the precision floor of the float32 model (the numpy sums'; the compiled float64 ones stop there
    # too, so that both paths stop alike)
    floor = 1e-12 * yy.sum(axis=1)
    # B^T B and B^T Y only change where a step was accepted: cache them per texel
    m_all, by_all = np.empty((t, 7, 7)), np.empty((t, 7, 3))
    stale = np.ones(t, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        upd = idx[stale[idx]]
        if upd.size:
            m_all[upd], by_all[upd] = _normal_moments(kd, u[upd], quat[upd], y, rows[upd])
            stale[upd] = False
        m, by = m_all[idx], by_all[idx]
        ksa, kda = ks[idx], kd_[idx]
        # gradient of 0.5 * sum r^2 w.r.t. theta: sum_c ks_c (ks_c M_tG + kd_c M_tE - (B^T Y)_tc)
        grad = (np.sum(ksa * ksa, 1)[:, None] * m[:, :5, 5] + np.sum(ksa * kda, 1)[:, None] * m[:, :5, 6]
                - np.einsum("ac,ajc->aj", ksa, by[:, :5]))
        # Schur complement of the linear block: (sum_c ks_c^2) (M_tt - M_tL M_LL^-1 M_Lt)
        mll = m[:, 5:, 5:] + np.eye(2) * 1e-12 * (m[:, 5, 5] + m[:, 6, 6])[:, None, None]
        schur = m[:, :5, :5] - m[:, :5, 5:] @ np.linalg.solve(mll, m[:, 5:, :5])
        hess = np.sum(ksa * ksa, axis=1)[:, None, None] * schur
        diag = np.diagonal(hess, axis1=1, axis2=2)
        scale = np.maximum(diag, 1e-9 * np.maximum(diag.max(axis=1, keepdims=True), 1e-300))
        la = lam[idx]
        lhs = hess + (la[:, None] * scale)[:, :, None] * np.eye(5)
        try:
            step = -np.linalg.solve(lhs, grad[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = -grad / np.maximum(la[:, None] * scale, 1e-300)
        step = np.where(np.isfinite(step), step, 0.0)
        # keep rotation steps modest (the linearisation of exp([r]x) is local)
        rn = np.linalg.norm(step[:, 2:], axis=1, keepdims=True)
        step[:, 2:] *= np.minimum(1.0, 0.5 / np.maximum(rn, 1e-300))
        u_new = np.clip(u[idx] + step[:, :2], LOG_SIGMA_MIN, LOG_SIGMA_MAX)
        q_new = quat_multiply(quat[idx], quat_from_rotvec(step[:, 2:]))
        ks_new, kd_new, cost_new = optimal_albedos(_trial_moments(kd, u_new, q_new, y, rows[idx]), ee, ey[idx], yy[idx])
        old = cost[idx]
        acc = cost_new < old
        ai = idx[acc]
        u[ai], quat[ai], ks[ai], kd_[ai], cost[ai] = (u_new[acc], q_new[acc], ks_new[acc], kd_new[acc],
                                                      cost_new[acc])
        stale[ai] = True
        lam[idx] = np.where(acc, np.maximum(la * 0.3, 1e-7), la * 4.0)
        rel = (old - cost_new) / np.maximum(old, 1e-300)
        done = (acc & (rel < tol)) | (lam[idx] > 1e8) | (cost[idx] <= floor[idx])
        active[idx[done]] = False
    return LmResult(quat=quat, sigma=np.exp(u), ks=ks, kd=kd_, cost=0.5 * cost, iterations=it, lam=lam)
