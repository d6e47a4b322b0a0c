"""Integration of the scratch reflectance over area lights in direction-cosine space (Sec. 4.3.4).

In direction cosines xi = (wi + wo)_perp the rendering equation reads L = int f(xi) L_i dxi
(eq. 4.19-4.24). The scratch term is separable, sinc^2(pi W xi2 / lambda) exp(-sigma^2 k^2 xi1^2)
(eq. 4.25), and the Gaussian across the scratch is far narrower than any projected light (eq. 4.26),
so the light is integrated along the line xi1 = 0 only: over each interval [zeta0, zeta1] of xi2 where
that line lies inside the projected light,

    int sinc^2 exp(..) dxi = N(zeta1) - N(zeta0),
    N(zeta) = sqrt(pi)/(sigma k) (2 Si(k W zeta)/(k W) - 4 sin^2(k W zeta / 2)/(k^2 W^2 zeta))   (eq. 4.27)

with Si from eq. 4.29 (``si="thesis"``), an accurate series form (``"series"``, default) or scipy.

Finding the intervals. The line xi1 = 0 is the set of incident directions on the small circle
w . t = c, c = -wo . t, which we parametrise on the upper hemisphere as
w(phi) = c t + s (cos phi b + sin phi n), s = sqrt(1 - c^2), phi in [0, pi], so that
xi2 = s cos phi + wo . b decreases monotonically with phi. Light boundaries cross the circle where
A cos phi + B sin phi = C; these are the quadratics of eq. 4.32-4.35 (sphere silhouette) and
eq. 4.38-4.40 (polygon edges, one great circle per edge) solved in closed form. The crossings
together with phi = 0 and phi = pi (the horizon, i.e. the clipping of eq. 4.36-4.37) split [0, pi]
into arcs; an arc whose midpoint lies inside the light contributes. Taking the midpoint test instead
of the derivative test of eq. 4.41 handles corner cases (points on two arcs, arcs below the
horizon, lights straddling the horizon) without branches.

Sphere lights use the exact silhouette cone (half angle asin(r/d)); this is eq. 4.31 with the disk
placed at the silhouette. Polygon lights are convex planar polygons (split non-convex ones into
triangles), emitting from both faces. Directional and point lights are the limit of a vanishing
sphere: the BRDF is evaluated at the light direction and weighted by the irradiance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .sine_integral import sine_integral


@dataclass(frozen=True)
class SphereLight:
    """Spherical light. ``center``: (3,) or (N, 3) position relative to the shaded point, in the local
    frame (t_u, t_v, n) of the scratch plane, any length unit; ``radius`` in the same unit;
    ``radiance``: scalar or per-wavelength array."""

    center: ArrayLike
    radius: float | ArrayLike
    radiance: float | ArrayLike = 1.0


@dataclass(frozen=True)
class PolygonLight:
    """Convex planar polygon light; ``vertices`` (V, 3) or (N, V, 3) relative to the shaded point."""

    vertices: ArrayLike
    radiance: float | ArrayLike = 1.0


@dataclass(frozen=True)
class DirectionalLight:
    """Distant light: unit ``direction`` towards the light (3,) or (N, 3), ``irradiance`` normal to it."""

    direction: ArrayLike
    irradiance: float | ArrayLike = 1.0


@dataclass(frozen=True)
class PointLight:
    """Point light at ``position`` (relative to the shaded point) with radiant ``intensity``."""

    position: ArrayLike
    intensity: float | ArrayLike = 1.0


def sinc2_antiderivative(zeta: ArrayLike, kw: ArrayLike, si: str = "series") -> np.ndarray:
    """int_0^zeta sinc^2(k W x / 2) dx = 2 Si(kW zeta)/(kW) - 4 sin^2(kW zeta/2)/(kW^2 zeta) (eq. 4.27)."""
    zeta = np.asarray(zeta, dtype=np.float64)
    kw = np.asarray(kw, dtype=np.float64)
    u = kw * zeta
    return 2.0 * sine_integral(u, si) / kw - zeta * np.sinc(u / (2.0 * np.pi)) ** 2


def band_limited_integral(
    zeta0: ArrayLike,
    zeta1: ArrayLike,
    width_um: ArrayLike,
    lam_um: ArrayLike,
    sigma_um: float,
    si: str = "series",
) -> np.ndarray:
    """Eq. 4.27: N(zeta1) - N(zeta0), the integral of sinc^2(pi W xi2/lambda) exp(-sigma^2 k^2 xi1^2)
    over the band xi1 in R, xi2 in [zeta0, zeta1]."""
    k = 2.0 * np.pi / np.asarray(lam_um, dtype=np.float64)
    kw = k * np.asarray(width_um, dtype=np.float64)
    f = sinc2_antiderivative(zeta1, kw, si) - sinc2_antiderivative(zeta0, kw, si)
    return np.sqrt(np.pi) / (sigma_um * k) * f


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _circle_roots(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots in (0, pi) of A cos(phi) + B sin(phi) = C; NaN where absent."""
    R = np.hypot(A, B)
    ok = R > 1e-300
    q = np.where(ok, C / np.where(ok, R, 1.0), 2.0)
    ok &= np.abs(q) <= 1.0
    phi0 = np.arctan2(B, A)
    delta = np.arccos(np.clip(q, -1.0, 1.0))
    out = []
    for r in (phi0 - delta, phi0 + delta):
        r = np.mod(r + np.pi, 2.0 * np.pi) - np.pi
        out.append(np.where(ok & (r > 0.0) & (r < np.pi), r, np.nan))
    return out[0], out[1]


def scratch_frame(tangent2: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """3D tangent t = (tx, ty, 0) and bitangent b = n x t = (-ty, tx, 0) of in-plane unit tangents."""
    t2 = np.asarray(tangent2, dtype=np.float64)
    z = np.zeros(t2.shape[:-1])
    t = np.stack([t2[..., 0], t2[..., 1], z], axis=-1)
    b = np.stack([-t2[..., 1], t2[..., 0], z], axis=-1)
    return t, b


def _arcs_inside(breaks: np.ndarray, inside_fn, t, b, c, s) -> tuple[np.ndarray, np.ndarray]:
    """Sort breakpoints (with 0 and pi), keep arcs whose midpoint is inside; return (phi_a, phi_b)."""
    P = breaks.shape[0]
    allb = np.concatenate([np.zeros((P, 1)), breaks, np.full((P, 1), np.pi)], axis=1)
    allb = np.where(np.isnan(allb), np.pi, allb)
    allb = np.sort(allb, axis=1)
    pa, pb = allb[:, :-1], allb[:, 1:]
    pm = 0.5 * (pa + pb)
    n = np.zeros_like(t)
    n[..., 2] = 1.0
    w = (
        c[:, None, None] * t[:, None, :]
        + s[:, None, None] * (np.cos(pm)[..., None] * b[:, None, :] + np.sin(pm)[..., None] * n[:, None, :])
    )
    keep = inside_fn(w) & (pb > pa)
    return np.where(keep, pa, 0.0), np.where(keep, pb, 0.0)


def _intervals_from_arcs(pa, pb, s, o2):
    """xi2 intervals [zeta0, zeta1] of arcs [phi_a, phi_b] (xi2 decreases with phi); empty -> zero width."""
    z1 = s[:, None] * np.cos(pa) + o2[:, None]
    z0 = s[:, None] * np.cos(pb) + o2[:, None]
    empty = pb <= pa
    return np.where(empty, 0.0, z0), np.where(empty, 0.0, z1)


def _line_setup(tangent2, wo):
    t, b = scratch_frame(tangent2)
    wo = np.asarray(wo, dtype=np.float64)
    c = -_dot(wo, t)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    o2 = _dot(wo, b)
    return t, b, c, s, o2


def specular_line_intervals_sphere(
    tangent2: ArrayLike, wo: ArrayLike, center: ArrayLike, radius: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """xi2 intervals (P, 2) where the line xi1 = 0 of each scratch crosses a sphere light (eq. 4.30-4.37).

    ``tangent2`` (P, 2) unit scratch tangents, ``wo`` (P, 3), ``center`` (P, 3) relative to the point,
    ``radius`` (P,). On the circle w(phi), w . p = c (t . p) + s rho cos(phi - phi_c) with
    rho = |(b . p, n . p)|, so the silhouette cone w . p >= cos(alpha) cuts the arc
    [phi_c - Delta, phi_c + Delta], cos(Delta) = (cos(alpha) - c t.p) / (s rho) (eq. 4.32-4.35 in
    closed form). Horizon clipping (eq. 4.36-4.37) intersects it with [0, pi]; an arc wrapping
    through phi = -pi gives a second piece. Returns (zeta0, zeta1), zero-width where empty; lights
    enclosing the point give none.
    """
    t2 = np.asarray(tangent2, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    center = np.asarray(center, dtype=np.float64)
    tx, ty = t2[:, 0], t2[:, 1]
    c = -(wo[:, 0] * tx + wo[:, 1] * ty)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    o2 = -wo[:, 0] * ty + wo[:, 1] * tx
    d = np.sqrt(np.einsum("pi,pi->p", center, center))
    p = center / d[:, None]
    sin_a = np.clip(np.asarray(radius, dtype=np.float64) / d, 0.0, 1.0)
    cos_a = np.sqrt(1.0 - sin_a**2)
    pt = p[:, 0] * tx + p[:, 1] * ty
    pb = -p[:, 0] * ty + p[:, 1] * tx
    rho = np.hypot(pb, p[:, 2])
    den = s * rho
    ok = (den > 1e-300) & (d > np.asarray(radius))
    q = np.where(ok, (cos_a - c * pt) / np.where(ok, den, 1.0), 2.0)
    ok &= q <= 1.0
    P = t2.shape[0]
    z0 = np.zeros((P, 2))
    z1 = np.zeros((P, 2))
    i = np.flatnonzero(ok)  # the trigonometry only where the line meets the cone
    if i.size:
        phi_c = np.arctan2(np.broadcast_to(p[:, 2], (P,))[i], pb[i])
        delta = np.arccos(np.maximum(q[i], -1.0))
        lo, hi = phi_c - delta, phi_c + delta
        pa = np.stack([np.maximum(lo, 0.0), np.maximum(lo + 2 * np.pi, 0.0)], 1)
        pb_ = np.stack([np.minimum(hi, np.pi), np.minimum(hi + 2 * np.pi, np.pi)], 1)
        keep = pb_ > pa
        si, oi = s[i, None], o2[i, None]
        z1[i] = np.where(keep, si * np.cos(pa) + oi, 0.0)
        z0[i] = np.where(keep, si * np.cos(pb_) + oi, 0.0)
    return z0, z1


def specular_line_intervals_polygon(
    tangent2: ArrayLike, wo: ArrayLike, vertices: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """xi2 intervals (P, 2V+1) where the line xi1 = 0 crosses a convex polygon light (eq. 4.36-4.41).

    ``vertices`` (P, V, 3) relative to the shaded point. Edges are great-circle arcs (eq. 4.36); their
    crossings with the line are eq. 4.38-4.40; horizon clipping is the restriction to phi in [0, pi].
    """
    t, b, c, s, o2 = _line_setup(tangent2, wo)
    V = np.asarray(vertices, dtype=np.float64)
    U = V / np.linalg.norm(V, axis=-1, keepdims=True)
    ne = np.cross(U, np.roll(U, -1, axis=1))  # (P, V, 3) edge great-circle normals
    ne = np.broadcast_to(ne, (t.shape[0],) + ne.shape[1:])
    orient = np.sign(_dot(U[:, 0], np.cross(U[:, 1], U[:, 2])))
    orient = np.where(orient == 0, 1.0, orient)
    r0, r1 = _circle_roots(
        s[:, None] * _dot(ne, b[:, None, :]), s[:, None] * ne[..., 2], -c[:, None] * _dot(ne, t[:, None, :])
    )
    breaks = np.concatenate([r0, r1], axis=1)

    def inside(w):  # w (P, K, 3)
        side = np.einsum("pkj,pej->pke", w, ne) * orient[:, None, None]
        return np.all(side >= 0.0, axis=-1)

    pa, pb = _arcs_inside(breaks, inside, t, b, c, s)
    z0, z1 = _intervals_from_arcs(pa, pb, s, o2)
    return np.where((s <= 0)[:, None], 0.0, z0), np.where((s <= 0)[:, None], 0.0, z1)
