"""Numpy models of the Cycles closures the fabric shader builds (what a Cycles render evaluates).

Each ``*_eval`` returns what Cycles' ``bsdf_eval`` returns for a closure of unit weight: the BSDF
times the cosine of the light direction, i.e. the reflected radiance per unit incident radiance.
That is the quantity to compare with ``f_r(wi, wo) cos(theta_i)`` of eq. 3.9. Naming follows this
package (``wi`` = towards the light, ``wo`` = towards the viewer); in Cycles' kernel the view
direction is ``sd->wi`` and the light direction ``wo``. All directions are unit vectors in the
tangent frame (z = shading normal = geometric normal of a flat patch) and broadcast.

Ported from blender/cycles (``src/kernel``, commit 97dbe6f5, Apache-2.0):

diffuse (``closure/bsdf_diffuse.h``, ``bsdf_diffuse_eval``)
    ``eval = max(<n, wi>, 0) / pi``.
microfacet("ggx", N, T, ax, ay, 0, 0) (``closure/bsdf_microfacet.h``, ``bsdf_microfacet_eval``,
``bsdf_microfacet_ggx_setup``: alphas clamped to [0, 1], no Fresnel)
    ``eval = D(h) / (4 <N, wo> (1 + Lambda(wo) + Lambda(wi)))`` for ``<N, wo> > 0``, ``<N, wi> >= 0``;
    ``D(h) = 1 / (pi ax ay |(h_x/ax, h_y/ay, h_z)|^4)`` (Heitz 2014, eq. 72 for Lambda)
    ``Lambda(v) = (sqrt(1 + (ax^2 v_x^2 + ay^2 v_y^2) / v_z^2) - 1) / 2``, local frame from
    ``make_orthonormals_tangent(N, T)``: ``Y = normalize(N x T)``, ``X = Y x N``.
    The OSL setup passes N through ``maybe_ensure_valid_specular_reflection``
    (``closure/bsdf_util.h``: a normal tilted so far that the mirror direction of the view falls below
    the surface is rotated towards Ng), and ``bump_shadowing_term`` (``closure/bsdf.h``) drops light
    from below the shading normal when N differs from it.
sheen(N, roughness) (``closure/bsdf_sheen.h``, Zeltner, Burley, Chiang 2022)
    roughness clamped to [1e-3, 1]; ``a, b, albedo`` read bilinearly from ``table_sheen_ltc`` at
    ``(cos_v = <N, wo>, roughness)``; frame ``B = normalize(N x wo)``, ``T = B x N``;
    ``x = (<wi,T>, <wi,B>, <wi,N>)``, ``eval = albedo * max(x_z, 0) / pi * (a / ((a x_x + b x_z)^2 +
    (a x_y)^2 + x_z^2))^2`` (a linearly transformed cosine: integrates to ``albedo`` over wi).
    The closure is skipped when ``|a| < 1e-5`` or ``albedo < 1e-5``.
"""

from __future__ import annotations

import numpy as np

from .cycles_sheen_table import SHEEN_LTC_TABLE

_SHEEN = np.asarray(SHEEN_LTC_TABLE, dtype=np.float64).reshape(3, 32, 32)  # (a | b | albedo, rough, cos)


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _normalize(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def diffuse_eval(wi, n=(0.0, 0.0, 1.0)):
    """Cycles ``diffuse(N)``: ``max(<N, wi>, 0) / pi``."""
    return np.maximum(_dot(np.asarray(wi, float), np.asarray(n, float)), 0.0) / np.pi


def lookup_table_2d(table, x, y):
    """Cycles ``lookup_table_read_2D`` on one 32 x 32 block: x along columns, y along rows, both
    clamped to [0, 1], bilinear."""
    ny, nx = table.shape
    x = np.clip(x, 0.0, 1.0) * (nx - 1)
    y = np.clip(y, 0.0, 1.0) * (ny - 1)
    ix = np.minimum(x.astype(int), nx - 1)
    iy = np.minimum(y.astype(int), ny - 1)
    tx, ty = x - ix, y - iy
    ix1, iy1 = np.minimum(ix + 1, nx - 1), np.minimum(iy + 1, ny - 1)
    r0 = (1 - tx) * table[iy, ix] + tx * table[iy, ix1]
    r1 = (1 - tx) * table[iy1, ix] + tx * table[iy1, ix1]
    return (1 - ty) * r0 + ty * r1


def sheen_ltc(cos_v, roughness):
    """``(a, b, albedo)`` of Cycles' sheen at view cosine ``cos_v`` and (clamped) ``roughness``."""
    cos_v = np.asarray(cos_v, float)
    r = np.clip(np.asarray(roughness, float), 1e-3, 1.0)
    cos_v, r = np.broadcast_arrays(cos_v, r)
    return tuple(lookup_table_2d(_SHEEN[k], cos_v, r) for k in range(3))


def _orthonormals(n):
    """Cycles ``make_orthonormals`` (fallback frame), vectorised."""
    use_x = (n[..., 0] != n[..., 1]) | (n[..., 0] != n[..., 2])
    a1 = np.stack([n[..., 2] - n[..., 1], n[..., 0] - n[..., 2], n[..., 1] - n[..., 0]], axis=-1)
    a2 = np.stack([-n[..., 2] - n[..., 1], n[..., 0], n[..., 0]], axis=-1)
    a = _normalize(np.where(use_x[..., None], a1, a2))
    return a, np.cross(n, a)


def sheen_eval(wi, wo, roughness, n=(0.0, 0.0, 1.0)):
    """Cycles ``sheen(N, roughness)`` of unit weight for light ``wi`` and view ``wo``."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    n = np.broadcast_to(np.asarray(n, float), np.broadcast_shapes(wi.shape, wo.shape))
    cos_v = _dot(n, wo)
    a, b, albedo = sheen_ltc(cos_v, roughness)
    bb = np.cross(n, wo)
    blen = np.linalg.norm(bb, axis=-1, keepdims=True)
    bb = bb / np.maximum(blen, 1e-30)
    tt = np.cross(bb, n)
    fa, fb = _orthonormals(n)
    bad = (blen[..., 0] ** 2) < 0.99 * 1e-12  # safe_normalize of a zero vector: fallback frame
    tt = np.where(bad[..., None], fa, tt)
    bb = np.where(bad[..., None], fb, bb)
    x, y, z = _dot(wi, tt), _dot(wi, bb), _dot(wi, n)
    len2 = (a * x + b * z) ** 2 + (a * y) ** 2 + z * z
    val = np.maximum(z, 0.0) / np.pi * (a / np.maximum(len2, 1e-30)) ** 2
    ok = (np.abs(a) >= 1e-5) & (albedo >= 1e-5)
    return np.where(ok, albedo * val, 0.0)


def ensure_valid_specular_reflection(ng, wo, n):
    """Cycles ``ensure_valid_specular_reflection(Ng, I, N)``: rotate ``n`` towards ``ng`` just enough
    that the mirror direction of the view ``wo`` lies above the surface (``closure/bsdf_util.h``)."""
    ng, wo, n = np.broadcast_arrays(*(np.asarray(v, float) for v in (ng, wo, n)))
    r = 2.0 * _dot(n, wo)[..., None] * n - wo
    iz = _dot(wo, ng)
    threshold = np.minimum(0.9 * iz, 0.01)
    keep = _dot(ng, r) >= threshold
    x = n - _dot(n, ng)[..., None] * ng
    xl = np.linalg.norm(x, axis=-1, keepdims=True)
    x = np.where(xl > 1e-30, x / np.maximum(xl, 1e-30), n)
    ix = _dot(wo, x)
    aa = ix * ix + iz * iz
    bq = 2.0 * (aa + iz * threshold)
    c = (threshold + iz) ** 2
    disc = np.sqrt(np.maximum(bq * bq - 4.0 * aa * c, 0.0))
    nz2 = np.where(ix < 0, 0.25 * (bq + disc) / aa, 0.25 * (bq - disc) / aa)
    nx = np.sqrt(np.maximum(1.0 - nz2, 0.0))
    nz = np.sqrt(np.maximum(nz2, 0.0))
    return np.where(keep[..., None], n, nx[..., None] * x + nz[..., None] * ng)


def _closure_setup(wi, wo, n, ng, bump_correction):
    """What the OSL setup of a Cycles microfacet-like closure does first: ``wi``, ``wo``, ``ng`` as float
    arrays and the closure normal ``n`` normalised and, with ``bump_correction``, passed through
    ``ensure_valid_specular_reflection`` (``osl/closures_setup.h``)."""
    wi = np.asarray(wi, float)
    wo = np.asarray(wo, float)
    ng = np.asarray(ng, float)
    n = _normalize(np.asarray(n, float))
    if bump_correction:
        n = ensure_valid_specular_reflection(ng, wo, n)
    return wi, wo, ng, n


def _bump_shadowed(ng, n, wi, cos_l):
    """Cycles ``bump_shadowing_term`` as a mask: light ``wi`` below the shading normal ``ng`` while above
    the closure normal ``n`` (``cos_l`` = <n, wi>)."""
    return (_dot(ng, wi) * _dot(ng, n) * cos_l) < 0.0


def ggx_eval(wi, wo, n, t, alpha_x, alpha_y, ng=(0.0, 0.0, 1.0), bump_correction=True):
    """Cycles ``microfacet("ggx", N=n, T=t, alpha_x, alpha_y, eta=0, refract=0)`` of unit weight.

    ``n`` may be tilted from the shading normal ``ng`` (z of the tangent frame; a flat patch has
    shading normal = geometric normal). ``bump_correction``: the material's "Bump Map Correction"
    (on by default), which enables Cycles' ``ensure_valid_specular_reflection`` of ``n``.
    """
    wi, wo, ng, n = _closure_setup(wi, wo, n, ng, bump_correction)
    ax = np.clip(np.asarray(alpha_x, float), 0.0, 1.0)
    ay = np.clip(np.asarray(alpha_y, float), 0.0, 1.0)
    cos_v = _dot(n, wo)
    cos_l = _dot(n, wi)
    h = _normalize(wi + wo)
    yy = _normalize(np.cross(n, np.asarray(t, float)))
    xx = np.cross(yy, n)
    hx, hy, hz = _dot(xx, h) / ax, _dot(yy, h) / ay, _dot(n, h)
    d = 1.0 / (np.pi * ax * ay * (hx * hx + hy * hy + hz * hz) ** 2)

    def lam(v, cz):
        s = ((ax * _dot(xx, v)) ** 2 + (ay * _dot(yy, v)) ** 2) / np.maximum(cz * cz, 1e-300)
        return 0.5 * (np.sqrt(1.0 + s) - 1.0)

    val = d / np.maximum(cos_v, 1e-300) * 0.25 / (1.0 + lam(wo, cos_v) + lam(wi, cos_l))
    shadow = _bump_shadowed(ng, n, wi, cos_l)
    valid = (cos_v > 0.0) & (cos_l >= 0.0) & ~shadow & (ax * ay > 2e-10)
    return np.where(valid, val, 0.0)


def velvet_eval(wi, wo, sigma, n=(0.0, 0.0, 1.0), ng=(0.0, 0.0, 1.0), bump_correction=True):
    """Cycles ``ashikhmin_velvet(N, sigma)`` of unit weight (``closure/bsdf_ashikhmin_velvet.h``).

    ``sigma`` clamped below at 0.01; ``D = exp(-cot^2(theta_h) / sigma^2) / (pi sigma^2 sin^4(theta_h))``,
    ``G = min(1, 2 <N,h> <N,wo> / <wo,h>, 2 <N,h> <N,wi> / <wo,h>)``, ``eval = D G / (4 <N, wo>)``.
    Like the GGX closure, the OSL setup passes N through ``maybe_ensure_valid_specular_reflection``
    (``bump_correction``, the material's default; ``osl/closures_setup.h``) and ``bump_shadowing_term``
    drops light below the shading normal ``ng`` while above N.
    """
    wi, wo, ng, n = _closure_setup(wi, wo, n, ng, bump_correction)
    inv_s2 = 1.0 / np.maximum(np.asarray(sigma, float), 0.01) ** 2
    cos_v, cos_l = _dot(n, wo), _dot(n, wi)
    h = _normalize(wi + wo)
    cos_nh = _dot(n, h)
    cos_hv = np.abs(_dot(wo, h))
    shadow = _bump_shadowed(ng, n, wi, cos_l)
    ok = (cos_v > 0) & (cos_l > 0) & (np.abs(cos_nh) < 1.0 - 1e-5) & (cos_hv > 1e-5) & ~shadow
    ratio = np.maximum(cos_nh / np.maximum(cos_hv, 1e-30), 1e-5)
    g = np.minimum(1.0, np.minimum(2.0 * np.abs(ratio * cos_v), 2.0 * np.abs(ratio * cos_l)))
    sin2 = np.maximum(1.0 - cos_nh * cos_nh, 1e-30)
    d = np.exp(-(cos_nh * cos_nh / sin2) * inv_s2) * inv_s2 / np.pi / (sin2 * sin2)
    return np.where(ok, 0.25 * d * g / np.maximum(cos_v, 1e-30), 0.0)
