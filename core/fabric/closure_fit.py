"""Per-texel fit of a small mix of Cycles closures to eq. 3.9 (for world and indirect light).

Cycles' OSL can only return its built-in closures, whose weights cannot depend on the light
direction. The fabric shader keeps its exact lamp path (eq. 3.9 through ``emission()``); everything
else (HDRI, indirect light, Fast Preview) sees a closure mix. This module chooses that mix per texel.

Mix (all in the texel's tangent frame, n = shading normal, a0/a2 = fibre x/z axes of the SGGX
basis, a2 flipped into the upper hemisphere)::

    kd * diffuse(n) + ks * ( w_d diffuse(n) + w_s sheen(n, r_s)
                             + w_v ashikhmin_velvet(N_v, s_v) + w_g microfacet("ggx", N_g, a0, ax, ay)
                             + w_v2 ashikhmin_velvet(N_v2, s_v2) )
    N_v = normalize((1 - k_v) n + k_v a2),  N_g = normalize((1 - k_g) n + k_g a2), N_v2 likewise
    (ax, ay) = clip(c_g (sigma_x, sigma_y), 0, 1)

Eq. 3.9 is linear in k_d and k_s, so the fit is of the k_s = 1 specular term alone, a scalar function
of (sigma, basis); k_d is carried by the diffuse closure exactly, and both colours stay the texel's
own maps: only scalars are fitted. The fitted quantities are frame-free (built from n, a0, a2), so a
fit depends only on (sigma_x, sigma_y, tilt of a2, twist of a0 about a2): texels are reduced to that
canonical key (quantised), each distinct key is fitted once, vectorised over all keys at once.

The fit: weighted least squares of ``closure_eval(wi, wo) - f_spec(wi, wo) cos_i`` over a stratified
set of light and view directions (both cosine-distributed: the renderer's view of the texel),
residuals divided by ``f_spec cos_i + m(wo)``, ``m(wo)`` = the mean of ``f_spec cos_i`` over the lights
at that view (about the radiance under a uniform sky): half relative (the peak under a sun-like
source), half absolute per view (what an environment integrates). Measured against 0.05 x the global
mean (relative) and per-view absolute weights in docs/accuracy.md: this one has the lowest HDRI errors
that keep the point-lamp figures within target. Nonlinear shape parameters (r_s, s_v, k_v, k_g,
c_g) are chosen from a small grid; for each grid combination the non-negative weights are solved
exactly (all active sets of the normal equations), all keys at once: first one velvet (sheen, velvet,
GGX combinations), then, keeping that sheen and GGX, every pair of velvets. The second velvet is what
a tilted fibre-like lobe needs (a fibre at 30 degrees under the point lamp: 5.5 % median error with
one velvet, 2.9 % with two; docs/accuracy.md).

Stored maps (``ClosureMaps``): ``closure_weights`` (w_d, w_s, w_v, w_g, w_v2), ``closure_shape``
(r_s, s_v, k_v, k_g, s_v2, k_v2) and ``closure_ggx_scale`` (c_g), all per texel. Maps written before
the second velvet have no w_v2: it is 0 there, which is the mix they were fitted as.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from .cycles_closures import diffuse_eval, ggx_eval, sheen_eval, velvet_eval
from .quaternion import quat_to_matrix
from .sggx_brdf import sggx_specular

SHEEN_ROUGHNESS = (0.5, 1.0)
VELVET_SIGMA = (0.25, 0.4, 0.6, 1.0)
VELVET_TILT = (0.0, 0.5, 1.0)
GGX_TILT = (0.5, 1.0)
GGX_SCALE = (1.0, 1.4)
REL_FLOOR = 1.0  # residual / (target + REL_FLOOR x the view's mean target): see fit_keys
FLOOR_PER_VIEW = True
TIE_TOLERANCE = 1e-9  # relative residual difference below which stage-1 combinations tie (first kept)
FIT_LIGHTS = (14, 28)  # cosine-stratified light directions of the fit (theta rings, azimuths)
FIT_VIEWS = (6, 12)  # ... and view directions


@dataclasses.dataclass(frozen=True)
class ClosureMaps:
    """Fitted closure parameters per texel (float32): ``weights`` (H, W, 5, 4) = view-basis coefficients
    of (w_d, w_s, w_v, w_g, w_v2) multiplying k_s; ``shape`` (H, W, 6) = (sheen roughness, velvet sigma,
    velvet tilt k_v, GGX tilt k_g, second velvet's sigma and tilt); ``ggx_scale`` (H, W, 1) = c_g (GGX
    alphas = clip(c_g sigma, 0, 1))."""

    weights: np.ndarray
    shape: np.ndarray
    ggx_scale: np.ndarray


def _norm(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def fibre_axes(quat):
    """Fibre axes (a0, a2) of the basis quaternion(s), a2 flipped into the upper hemisphere."""
    rot = quat_to_matrix(np.asarray(quat, float))
    a0, a2 = rot[..., :, 0], rot[..., :, 2]
    s = np.where(a2[..., 2:3] < 0, -1.0, 1.0)
    return a0, a2 * s


def lobe_evals(wi, wo, sigma, quat, shape, ggx_scale):
    """The five unit closures (diffuse, sheen, velvet, GGX, second velvet) of the mix, ``(..., 5)``, as
    Cycles evaluates them (BSDF x cosine, see ``cycles_closures``). Parameters broadcast against the
    directions with a trailing vector axis (e.g. sigma (..., 2), quat (..., 4), shape (..., 6))."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    shape = np.asarray(shape, float)
    a0, a2 = fibre_axes(quat)
    n = np.array([0.0, 0.0, 1.0])
    kv, kg, kv2 = shape[..., 2:3], shape[..., 3:4], shape[..., 5:6]
    nv = _norm((1 - kv) * n + kv * a2)
    nga = _norm((1 - kg) * n + kg * a2)
    nv2 = _norm((1 - kv2) * n + kv2 * a2)
    alpha = np.clip(np.asarray(ggx_scale, float) * np.asarray(sigma, float), 1e-4, 1.0)
    out = [
        np.broadcast_to(diffuse_eval(wi), np.broadcast_shapes(wi.shape, wo.shape)[:-1]),
        sheen_eval(wi, wo, shape[..., 0]),
        velvet_eval(wi, wo, shape[..., 1], nv),
        ggx_eval(wi, wo, nga, a0, alpha[..., 0], alpha[..., 1]),
        velvet_eval(wi, wo, shape[..., 4], nv2),
    ]
    shp = np.broadcast_shapes(*(o.shape for o in out))
    return np.stack([np.broadcast_to(o, shp) for o in out], axis=-1)


def view_basis(wo, quat):
    """Non-negative view-dependent weight basis (..., 4): Bernstein ``((1 - mu)^2, 2 mu (1 - mu), mu^2)``
    in mu = cos(theta_o) and ``(1 - mu) (1 + <wo, t>) / 2`` with t the unit tangential direction the
    fibre axis leans towards (0 for an upright fibre). With non-negative coefficients every weight is
    non-negative for every view. A closure weight may depend on the view (the shader knows it), never
    on the light."""
    wo = np.asarray(wo, float)
    _, a2 = fibre_axes(quat)
    t = a2 * np.array([1.0, 1.0, 0.0])
    tl = np.linalg.norm(t, axis=-1, keepdims=True)
    t = np.where(tl > 1e-6, t / np.maximum(tl, 1e-12), 0.0)
    mu = wo[..., 2]
    tw = np.sum(wo * t, axis=-1)
    mu, tw = np.broadcast_arrays(mu, tw)
    return np.stack([(1 - mu) ** 2, 2 * mu * (1 - mu), mu * mu, (1 - mu) * (1 + tw) / 2], axis=-1)


def closure_weights(wo, quat, coeffs):
    """Per-view closure weights ``max(coeffs @ view_basis, 0)`` (..., 5) from coefficients (..., 5, 4)
    [closure, basis]."""
    phi = view_basis(wo, quat)
    return np.maximum(np.einsum("...jb,...b->...j", np.asarray(coeffs, float), phi), 0.0)


def closure_eval(wi, wo, kd, ks, sigma, quat, fit: ClosureMaps | tuple):
    """RGB radiance per unit incident radiance of the fitted closure mix (compare with
    ``sggx_brdf(...) * cos_i``). ``fit``: ClosureMaps or (coeffs, shape, ggx_scale) that broadcast
    against the directions (coeffs with two trailing axes (5, 4))."""
    coeffs, shape, scale = (fit.weights, fit.shape, fit.ggx_scale) if isinstance(fit, ClosureMaps) else fit
    lobes = lobe_evals(wi, wo, sigma, quat, shape, scale)
    w = closure_weights(wo, quat, coeffs)
    spec = np.sum(lobes * w, axis=-1, keepdims=True)
    return np.asarray(kd, float) * lobes[..., :1] + np.asarray(ks, float) * spec


def legacy_closure_eval(wi, wo, kd, ks, sigma, quat):
    """The shader's previous fixed approximation (before issue 38), for comparison: k_d diffuse plus
    k_s/2 GGX along the fibre axis with alpha = sigma when sigma_x, sigma_y <= 1, else k_s sheen(n)
    with roughness clip(1 / sigma_max, 0.05, 1)."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    sigma = np.asarray(sigma, float)
    a0, a2 = fibre_axes(quat)
    smax = np.max(sigma, axis=-1)
    ggx = 0.5 * ggx_eval(wi, wo, a2, a0, np.minimum(sigma[..., 0], 1.0), np.minimum(sigma[..., 1], 1.0))
    sh = sheen_eval(wi, wo, np.clip(1.0 / smax, 0.05, 1.0))
    spec = np.where(smax <= 1.0, ggx, sh)[..., None]
    return np.asarray(kd, float) * diffuse_eval(wi)[..., None] + np.asarray(ks, float) * spec


def hemisphere_grid(n_theta: int, n_phi: int, offset: float = 0.0) -> np.ndarray:
    """Cosine-stratified directions: cos(theta) = sqrt((i + 1/2) / n_theta), even azimuths."""
    mu = np.sqrt((np.arange(n_theta) + 0.5) / n_theta)
    th = np.arccos(mu)
    ph = (np.arange(n_phi) + offset) / n_phi * 2.0 * np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)


def canonical_keys(sigma, quat, quantum=(0.005, 0.25, 1.0)):
    """Rotation-about-n invariant description (sigma_x, sigma_y, tilt deg, twist deg) of each texel,
    quantised (relative sigma step, tilt step in degrees, twist step in degrees)."""
    sigma = np.asarray(sigma, float).reshape(-1, 2)
    rot = quat_to_matrix(np.asarray(quat, float).reshape(-1, 4))
    a0, a2 = rot[:, :, 0], rot[:, :, 2]
    a2 = a2 * np.where(a2[:, 2:3] < 0, -1.0, 1.0)
    tilt = np.degrees(np.arccos(np.clip(a2[:, 2], -1.0, 1.0)))
    phi = np.where(tilt > 1e-6, np.arctan2(a2[:, 1], a2[:, 0]), np.arctan2(a0[:, 1], a0[:, 0]))
    ex = np.stack([np.cos(phi) * a2[:, 2], np.sin(phi) * a2[:, 2], -np.sqrt(np.maximum(1 - a2[:, 2] ** 2, 0))], -1)
    ey = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], -1)
    twist = np.degrees(np.arctan2(np.sum(a0 * ey, -1), np.sum(a0 * ex, -1))) % 180.0
    qs, qt, qw = quantum
    lsig = np.round(np.log(np.maximum(sigma, 1e-6)) / qs) * qs
    key = np.stack([lsig[:, 0], lsig[:, 1], np.round(tilt / qt) * qt, (np.round(twist / qw) * qw) % 180.0], -1)
    return key


def _canonical_params(keys):
    """sigma (K, 2) and quaternion (K, 4) of canonical keys (a2 in the x-z plane)."""
    from .quaternion import matrix_to_quat

    sigma = np.exp(keys[:, :2])
    t, w = np.radians(keys[:, 2]), np.radians(keys[:, 3])
    a2 = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    ex = np.stack([np.cos(t), np.zeros_like(t), -np.sin(t)], -1)
    ey = np.broadcast_to([0.0, 1.0, 0.0], ex.shape)
    a0 = np.cos(w)[:, None] * ex + np.sin(w)[:, None] * ey
    a1 = np.cross(a2, a0)
    return sigma, matrix_to_quat(np.stack([a0, a1, a2], axis=-1))


def _nnls_exact(gram, rhs, tt):
    """Exact non-negative least squares with few (<= 5) unknowns, batched: every active set of the
    normal equations, the feasible one with the least residual. Returns (weights (B, m), residual (B,))."""
    b, m = rhs.shape
    best_w = np.zeros((b, m))
    best_r = tt.copy()
    eye = np.eye(m) * 1e-12
    for mask in itertools.product((0, 1), repeat=m):
        idx = [i for i in range(m) if mask[i]]
        if not idx:
            continue
        g = gram[:, idx][:, :, idx] + eye[: len(idx), : len(idx)] * np.trace(gram, axis1=1, axis2=2)[:, None, None]
        w = np.linalg.solve(g, rhs[:, idx][..., None])[..., 0]
        ok = np.all(w >= 0, axis=1)
        full = np.zeros((b, m))
        full[:, idx] = w
        r = tt - 2 * np.sum(full * rhs, 1) + np.einsum("bi,bij,bj->b", full, gram, full)
        better = ok & (r < best_r)
        best_w[better] = full[better]
        best_r[better] = r[better]
    return best_w, best_r


def _nnls_batched(gram, rhs, iters: int = 12):
    """Approximate batched non-negative least squares on normal equations: solve on the free set,
    fix the variables that went negative at 0, repeat (Lawson-Hanson without re-release)."""
    b, m = rhs.shape
    free = np.ones((b, m), bool)
    eye = np.eye(m)
    x = np.zeros((b, m))
    for _ in range(iters):
        f2 = free[:, :, None] & free[:, None, :]
        g = np.where(f2, gram, eye * np.diagonal(gram, axis1=1, axis2=2)[:, :, None])
        x = np.linalg.solve(g, np.where(free, rhs, 0.0)[..., None])[..., 0]
        neg = free & (x < 0)
        if not neg.any():
            break
        free &= ~neg
    return np.maximum(np.where(free, x, 0.0), 0.0)


def fit_keys(sigma, quat, n_light=FIT_LIGHTS, n_view=FIT_VIEWS, chunk=32):
    """Fit the mix for K texel geometries (sigma (K, 2), quat (K, 4)), vectorised over K.

    Returns (weights (K, 5, 4), shape (K, 6), ggx_scale (K, 1), rel_rms (K,)).
    """
    wi = hemisphere_grid(*n_light)[None, None, :, :]
    wo = hemisphere_grid(*n_view, offset=0.25)[None, :, None, :]
    combos = list(itertools.product(range(len(SHEEN_ROUGHNESS)), range(len(VELVET_SIGMA)), range(len(VELVET_TILT)),
                                    range(len(GGX_TILT)), range(len(GGX_SCALE))))
    velvets = list(itertools.product(range(len(VELVET_SIGMA)), range(len(VELVET_TILT))))
    k_all = len(sigma)
    out_w = np.zeros((k_all, 5, 4))
    out_idx = np.zeros((k_all, 5), int)
    out_s = np.zeros((k_all, 6))
    out_c = np.ones((k_all, 1))
    out_r = np.zeros(k_all)
    ns, nv = len(SHEEN_ROUGHNESS), len(VELVET_TILT)
    v0 = 1 + ns  # column of the first velvet
    for c0 in range(0, k_all, chunk):
        sg = np.asarray(sigma[c0:c0 + chunk], float)[:, None, None, :]
        qt = np.asarray(quat[c0:c0 + chunk], float)[:, None, None, :]
        target = sggx_specular(wi, wo, sg, qt) * wi[..., 2]
        scale = target.mean(axis=(1, 2), keepdims=True)
        if FLOOR_PER_VIEW:
            scale = target.mean(axis=2, keepdims=True) + 1e-9 * scale
        wts = 1.0 / (target + REL_FLOOR * scale)
        kk = target.shape[0]
        sl_all = np.arange(c0, c0 + kk)
        a0, a2 = fibre_axes(qt)
        n = np.array([0.0, 0.0, 1.0])
        cols = [diffuse_eval(wi) + 0 * target]
        cols += [sheen_eval(wi, wo, r) + 0 * target for r in SHEEN_ROUGHNESS]
        for s in VELVET_SIGMA:
            cols += [velvet_eval(wi, wo, s, _norm((1 - k) * n + k * a2)) for k in VELVET_TILT]
        for k in GGX_TILT:
            for c in GGX_SCALE:
                al = np.clip(c * sg, 1e-4, 1.0)
                cols.append(ggx_eval(wi, wo, _norm((1 - k) * n + k * a2), a0, al[..., 0], al[..., 1]))
        cmat = np.stack([np.broadcast_to(c, target.shape) for c in cols], -1).reshape(kk, -1, len(cols))
        cmat = cmat * wts.reshape(kk, -1, 1)
        y = (target * wts).reshape(kk, -1)
        gram = np.einsum("kmi,kmj->kij", cmat, cmat)
        rhs = np.einsum("kmi,km->ki", cmat, y)
        tt = np.sum(y * y, 1)
        best = np.full(kk, np.inf)
        # Stage 1: one closure of each kind (the sheen and GGX shapes are kept from here on).
        for i_s, i_v, i_k, i_g, i_c in combos:
            idx = [0, 1 + i_s, v0 + i_v * nv + i_k, v0 + len(VELVET_SIGMA) * nv + i_g * len(GGX_SCALE) + i_c]
            w, r = _nnls_exact(gram[:, idx][:, :, idx], rhs[:, idx], tt)
            # a later combination must be better by more than rounding: where NNLS leaves a closure at
            # weight 0, combinations that differ only in that closure tie exactly, and the BLAS kernel
            # of the machine (not the fit) would pick one of them
            better = r < best * (1.0 - TIE_TOLERANCE)
            sl = sl_all[better]
            best[better] = r[better]
            out_w[sl, :4, :3] = w[better][:, :, None]  # constant weight = sum of the Bernstein terms
            out_w[sl, 4] = 0.0
            out_idx[sl, :4] = idx
            out_idx[sl, 4] = idx[2]
            out_s[sl] = [SHEEN_ROUGHNESS[i_s], VELVET_SIGMA[i_v], VELVET_TILT[i_k], GGX_TILT[i_g],
                         VELVET_SIGMA[i_v], VELVET_TILT[i_k]]
            out_c[sl] = GGX_SCALE[i_c]
        # Stage 2: every pair of velvets beside stage 1's sheen and GGX.
        kidx = np.arange(kk)[:, None]
        for (j1, (i_v1, i_k1)), (j2, (i_v2, i_k2)) in itertools.combinations(enumerate(velvets), 2):
            idx = out_idx[c0:c0 + kk].copy()
            idx[:, 2], idx[:, 4] = v0 + j1, v0 + j2
            g5 = gram[kidx[:, :, None], idx[:, :, None], idx[:, None, :]]
            w, r = _nnls_exact(g5, rhs[kidx, idx], tt)
            better = r < best * (1.0 - TIE_TOLERANCE)
            sl = sl_all[better]
            best[better] = r[better]
            out_w[sl, :, :3] = w[better][:, :, None]
            out_idx[sl] = idx[better]
            out_s[sl, 1:3] = [VELVET_SIGMA[i_v1], VELVET_TILT[i_k1]]
            out_s[sl, 4:6] = [VELVET_SIGMA[i_v2], VELVET_TILT[i_k2]]
        # View-dependent weights: refit the chosen closures' coefficients of view_basis (ridge-damped
        # linear least squares towards the constant weights just found).
        sel = np.take_along_axis(cmat, out_idx[c0:c0 + kk][:, None, :], axis=2)  # (kk, M, 5)
        phi = np.broadcast_to(view_basis(wo, qt), target.shape + (4,)).reshape(kk, -1, 4)
        design = (sel[..., :, None] * phi[..., None, :]).reshape(kk, -1, 20)
        gram20 = np.einsum("kmi,kmj->kij", design, design)
        lam = 1e-4 * np.trace(gram20, axis1=1, axis2=2)[:, None, None] / 20
        prior = out_w[c0:c0 + kk].reshape(kk, 20)
        rhs20 = np.einsum("kmi,km->ki", design, y) + lam[:, 0] * prior
        coef = _nnls_batched(gram20 + lam * np.eye(20), rhs20).reshape(kk, 5, 4)
        wv = np.maximum(np.einsum("kmjb,kmb->kmj", coef[:, None], phi), 0.0)
        r20 = np.sum((np.sum(sel * wv, -1) - y) ** 2, 1)
        better = r20 < best
        out_w[c0:c0 + kk][better] = coef[better]
        best = np.minimum(best, r20)
        out_r[c0:c0 + kk] = np.sqrt(np.maximum(best, 0) / y.shape[1])
    return out_w, out_s, out_c, out_r


KEY_QUANTUM = (0.005, 0.25, 1.0)  # canonical_keys' default: log sigma, tilt (deg), twist (deg)


FIT_KEY_BUDGET = 128  # distinct fibre geometries fitted per map (about 0.15 s each); beyond: the closure table


def fit_closure_texels(sigma, basis, cache: dict | None = None, progress=None, max_keys: int | None = None,
                       info: dict | None = None, **kw):
    """Fit the closure mix for N texels (sigma (N, 2), basis (N, 4)); returns (weights (N, 5, 4),
    shape (N, 6), ggx_scale (N, 1)) float32.

    Texels are reduced to canonical quantised keys (``canonical_keys``) and each distinct key is fitted
    once (``fit_keys``, about 0.15 s per key on one core in batches). ``max_keys``: when the texels hold more
    distinct keys (a measured map varies continuously: every texel would be its own key), every texel's
    closures come from the precomputed table instead (``closure_table.lookup_closure_texels``, about
    3 us per texel, interpolated between fitted geometries), and ``info["table"]`` is True.
    ``cache``: a dict of key -> fitted row kept by the caller, so keys fitted before cost nothing.
    ``progress(done, total)`` is called between chunks of keys (or of texels, for the table; an
    import shows it).
    """
    sigma = np.asarray(sigma, float).reshape(-1, 2)
    basis = np.asarray(basis, float).reshape(-1, 4)
    keys = canonical_keys(sigma, basis, KEY_QUANTUM)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    if info is not None:
        info.update(keys=len(uniq), table=max_keys is not None and len(uniq) > max_keys)
    if max_keys is not None and len(uniq) > max_keys:
        from .closure_table import lookup_closure_texels

        n, step = len(sigma), 1 << 16
        out = (np.zeros((n, 5, 4), np.float32), np.zeros((n, 6), np.float32), np.zeros((n, 1), np.float32))
        for c0 in range(0, n, step):
            for dst, src in zip(out, lookup_closure_texels(sigma[c0:c0 + step], basis[c0:c0 + step]), strict=True):
                dst[c0:c0 + step] = src
            if progress is not None:
                progress(min(c0 + step, n), n)
        return out
    inverse = inverse.reshape(-1)
    k = len(uniq)
    wts = np.zeros((k, 5, 4))
    shp = np.zeros((k, 6))
    scl = np.ones((k, 1))
    tuples = [tuple(row) for row in uniq.tolist()]
    todo = [i for i, t in enumerate(tuples) if cache is None or t not in cache]
    for i, t in enumerate(tuples):
        if cache is not None and t in cache:
            wts[i], shp[i], scl[i] = cache[t]
    step = max(kw.pop("chunk", 32), 1)
    for c0 in range(0, len(todo), step):
        idx = todo[c0:c0 + step]
        sig, quat = _canonical_params(uniq[idx])
        w, s_, c, _ = fit_keys(sig, quat, chunk=step, **kw)
        wts[idx], shp[idx], scl[idx] = w, s_, c
        if cache is not None:
            for j, i in enumerate(idx):
                cache[tuples[i]] = (w[j], s_[j], c[j])
        if progress is not None:
            progress(min(c0 + step, len(todo)), len(todo))
    return (wts[inverse].astype(np.float32), shp[inverse].astype(np.float32), scl[inverse].astype(np.float32))


def fit_closure_maps(sigma_map, basis_map, cache: dict | None = None, progress=None, **kw) -> ClosureMaps:
    """Fit the closure mix for every texel of (H, W, 2) sigma and (H, W, 4) basis maps
    (``fit_closure_texels``: each distinct texel geometry once, so uniform regions cost one fit;
    ``max_keys`` and ``info`` as there)."""
    h, w = sigma_map.shape[:2]
    wts, shp, scl = fit_closure_texels(sigma_map, basis_map, cache=cache, progress=progress, **kw)
    return ClosureMaps(weights=wts.reshape(h, w, 5, 4), shape=shp.reshape(h, w, 6), ggx_scale=scl.reshape(h, w, 1))


CLOSURE_FILES = ("closure_w_diffuse.exr", "closure_w_sheen.exr", "closure_w_velvet.exr", "closure_w_ggx.exr",
                 "closure_w_velvet2.exr")
SHAPE_FILE, SHAPE2_FILE, GGX_SCALE_FILE = "closure_shape.exr", "closure_shape2.exr", "closure_ggx_scale.exr"
SHAPE_FILES = (SHAPE_FILE, SHAPE2_FILE, GGX_SCALE_FILE)


def save_closure_maps(out_dir, cm: ClosureMaps) -> None:
    """Write the fitted closures beside a parameter folder's maps: one RGBA EXR per closure holding its
    four view-basis coefficients, ``closure_shape.exr`` (RGBA: sheen roughness, velvet sigma, velvet
    tilt, GGX tilt), ``closure_shape2.exr`` (RG: the second velvet's sigma and tilt) and
    ``closure_ggx_scale.exr`` (R)."""
    import os

    from ..exr_io import write_exr

    os.makedirs(out_dir, exist_ok=True)
    for j, name in enumerate(CLOSURE_FILES):
        write_exr(os.path.join(out_dir, name), cm.weights[:, :, j, :])
    write_exr(os.path.join(out_dir, SHAPE_FILE), cm.shape[:, :, :4])
    write_exr(os.path.join(out_dir, SHAPE2_FILE), cm.shape[:, :, 4:6], channels=("R", "G"))
    write_exr(os.path.join(out_dir, GGX_SCALE_FILE), cm.ggx_scale, channels=("R",))


def load_closure_maps(params_dir) -> ClosureMaps:
    """Read what ``save_closure_maps`` wrote (``ExrError``, a ValueError, when a file is missing or bad)."""
    import os

    from ..exr_io import read_exr

    w = np.stack([read_exr(os.path.join(params_dir, n), channels=("R", "G", "B", "A")) for n in CLOSURE_FILES], 2)
    shape = read_exr(os.path.join(params_dir, SHAPE_FILE), channels=("R", "G", "B", "A"))
    shape2 = read_exr(os.path.join(params_dir, SHAPE2_FILE), channels=("R", "G"))
    scale = read_exr(os.path.join(params_dir, GGX_SCALE_FILE), channels=("R",))
    return ClosureMaps(weights=w.astype(np.float32), shape=np.concatenate([shape, shape2], 2).astype(np.float32),
                       ggx_scale=scale.reshape(scale.shape[0], scale.shape[1], 1).astype(np.float32))
