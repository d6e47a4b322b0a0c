"""Independent references for the scratch integrals: dense quadrature and Monte Carlo.

Both integrate the incoherent model with the *finite-segment* phase term of eq. 4.5 (complex erf,
no infinite-scratch limit, no band limit, no Si approximation) over the pixel footprint and the
solid angle of the light:

    L_ref = 1/A_P int_{x in A_P} int_{light} L_i sum_m |S^(m)(xi, x)|^2 / (A_C lambda^2) dxi dx   (eq. 4.12, 4.24)

with |S^(m)|^2 = W^2 sinc^2(pi W xi2 / lambda) |D|^2 |eta^(m)(xi, x)|^2 (eq. 4.3, 4.5, 4.11).
Light membership is decided by ray casting (sphere: angle to the centre; polygon: ray-plane hit and
a planar crossing-number test), not by the great-circle machinery the analytic code uses.

* :func:`reference_radiance_quadrature`: deterministic; the xi1 direction is integrated with the
  trapezoid rule over +-7 standard deviations of the coherence Gaussian, xi2 by the midpoint rule on a
  dense grid spanning the light's projection, the footprint with Gauss-Legendre rules in the scratch's
  frame (chords of the ellipse are exact).
* :func:`reference_radiance_mc`: plain Monte Carlo over (x, w_i) with x uniform in the footprint and
  w_i uniform in the light's solid angle (sphere: cone sampling, polygon: area sampling).

A validation configuration is a dict with keys ``J`` (2, 2) footprint matrix around x = 0, ``wo``
(3,), ``light`` (a light dataclass), ``segments`` (M, 4), ``width_um``/``depth_um`` (M,),
``lam_nm`` (float) and ``sigma_um``.
"""

from __future__ import annotations

import numpy as np

from .light_integration import PolygonLight, SphereLight, scratch_frame
from .scratch_model_terms import coherence_area, scratch_depth_term_sq, scratch_phase_term


def _light_contains(light, w: np.ndarray) -> np.ndarray:
    """Ray-cast membership of unit directions w (..., 3) in the light (upper hemisphere only)."""
    up = w[..., 2] > 0
    if isinstance(light, SphereLight):
        c = np.asarray(light.center, dtype=np.float64)
        d = np.linalg.norm(c)
        cos_a = np.sqrt(max(1.0 - (float(light.radius) / d) ** 2, 0.0))
        return up & (w @ (c / d) >= cos_a)
    V = np.asarray(light.vertices, dtype=np.float64)
    nrm = np.cross(V[1] - V[0], V[2] - V[0])
    nrm = nrm / np.linalg.norm(nrm)
    denom = w @ nrm
    tt = (V[0] @ nrm) / np.where(np.abs(denom) > 1e-15, denom, np.nan)
    hit = np.where((tt > 0)[..., None], w * tt[..., None], np.nan)
    # planar crossing-number test in the polygon's plane
    e1 = (V[1] - V[0]) / np.linalg.norm(V[1] - V[0])
    e2 = np.cross(nrm, e1)
    q = np.stack([(hit - V[0]) @ e1, (hit - V[0]) @ e2], -1)
    poly = np.stack([(V - V[0]) @ e1, (V - V[0]) @ e2], -1)
    inside = np.zeros(w.shape[:-1], dtype=bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        cond = (a[1] > q[..., 1]) != (b[1] > q[..., 1])
        xcross = a[0] + (q[..., 1] - a[1]) * (b[0] - a[0]) / (b[1] - a[1] if b[1] != a[1] else 1e-300)
        inside ^= cond & (q[..., 0] < xcross)
    return up & inside & np.isfinite(tt) & (tt > 0)


def _light_boundary_dirs(light, n: int = 4096) -> np.ndarray:
    """Unit directions sampled densely along the light's outline (for bounding its projection)."""
    if isinstance(light, SphereLight):
        c = np.asarray(light.center, dtype=np.float64)
        d = np.linalg.norm(c)
        p = c / d
        sin_a = min(float(light.radius) / d, 1.0)
        a = np.array([1.0, 0, 0]) if abs(p[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(p, a)
        u /= np.linalg.norm(u)
        v = np.cross(p, u)
        th = np.linspace(0, 2 * np.pi, n, endpoint=False)
        return np.sqrt(1 - sin_a**2) * p + sin_a * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v)
    V = np.asarray(light.vertices, dtype=np.float64)
    t = np.linspace(0, 1, n // len(V), endpoint=False)[:, None]
    pts = np.concatenate([V[i] + t * (V[(i + 1) % len(V)] - V[i]) for i in range(len(V))])
    return pts / np.linalg.norm(pts, axis=1, keepdims=True)


def _footprint_rule(J: np.ndarray, p0: np.ndarray, t2: np.ndarray, s_b0: float, sigma: float, nv: int, nu: int):
    """Gauss-Legendre nodes (u, v) and weights over the ellipse in the scratch frame (x = u t + v b).

    v is restricted to s_b0 +- 7 sigma (the integrand's Gaussian support), u to the exact chord.
    """
    b2 = np.array([-t2[1], t2[0]])
    Ji = np.linalg.inv(J)
    # ellipse in (u, v): |Ji (u t + v b)|^2 <= 1 -> quadratic form Q
    R = np.stack([t2, b2], 1)  # columns t, b
    Q = (Ji @ R).T @ (Ji @ R)
    vmax = np.sqrt(1.0 / (Q[1, 1] - Q[0, 1] ** 2 / Q[0, 0]))
    lo, hi = max(-vmax, s_b0 - 7 * sigma), min(vmax, s_b0 + 7 * sigma)
    if hi <= lo:
        return np.zeros((0,)), np.zeros((0,)), np.zeros((0,))
    gv, wv = np.polynomial.legendre.leggauss(nv)
    gu, wu = np.polynomial.legendre.leggauss(nu)
    # split v at s_b0 (the peak) when it lies inside, to resolve the Gaussian well
    pieces = [(lo, hi)] if not (lo < s_b0 < hi) else [(lo, s_b0), (s_b0, hi)]
    us, vs, ws = [], [], []
    for a, b in pieces:
        v = 0.5 * (b - a) * gv + 0.5 * (a + b)
        wvv = 0.5 * (b - a) * wv
        # chord: Q00 u^2 + 2 Q01 u v + Q11 v^2 <= 1
        disc = np.maximum((Q[0, 1] * v) ** 2 - Q[0, 0] * (Q[1, 1] * v * v - 1.0), 0.0)
        ulo = (-Q[0, 1] * v - np.sqrt(disc)) / Q[0, 0]
        uhi = (-Q[0, 1] * v + np.sqrt(disc)) / Q[0, 0]
        u = 0.5 * (uhi - ulo)[:, None] * gu[None, :] + 0.5 * (uhi + ulo)[:, None]
        w = wvv[:, None] * 0.5 * (uhi - ulo)[:, None] * wu[None, :]
        us.append(u.ravel())
        vs.append(np.broadcast_to(v[:, None], u.shape).ravel())
        ws.append(w.ravel())
    return np.concatenate(us), np.concatenate(vs), np.concatenate(ws)


def reference_radiance_quadrature(
    cfg: dict, n_xi1: int = 41, n_xi2: int = 3000, n_v: int = 24, n_u: int = 48
) -> float:
    """Dense-quadrature reference of the footprint- and light-integrated scratch radiance (one wavelength)."""
    sigma = float(cfg.get("sigma_um", 60.0))
    lam = float(cfg["lam_nm"]) / 1000.0
    k = 2 * np.pi / lam
    J = np.asarray(cfg["J"], dtype=np.float64)
    wo = np.asarray(cfg["wo"], dtype=np.float64)
    light = cfg["light"]
    li = float(np.mean(light.radiance))
    area_p = np.pi * abs(np.linalg.det(J))
    bdirs = _light_boundary_dirs(light)
    total = 0.0
    for seg, w_s, d_s in zip(np.asarray(cfg["segments"]), cfg["width_um"], cfg["depth_um"], strict=True):
        p0, p1 = seg[:2], seg[2:]
        length = float(np.linalg.norm(p1 - p0))
        t2 = (p1 - p0) / length
        t3, b3 = scratch_frame(t2)
        s_t0 = float(p0 @ t2)
        s_b0 = float(t2[0] * p0[1] - t2[1] * p0[0])
        u, v, wsp = _footprint_rule(J, p0, t2, s_b0, sigma, n_v, n_u)
        if u.size == 0:
            continue
        xi1 = np.linspace(-7.0, 7.0, n_xi1) / (sigma * k)
        h1 = xi1[1] - xi1[0]
        # spatial integral of |eta|^2 for every xi1 node: (n_xi1,)
        eta = scratch_phase_term(xi1[:, None], 0.0, s_t0 - u[None, :], s_b0 - v[None, :], length, lam, sigma)
        spat = (np.abs(eta) ** 2) @ wsp
        # angular: for each xi1 node, int sinc^2 1_light dxi2 on a dense midpoint grid
        zb = (bdirs + wo) @ b3
        zlo, zhi = zb.min() - 0.01, zb.max() + 0.01
        h2 = (zhi - zlo) / n_xi2
        xi2 = zlo + h2 * (np.arange(n_xi2) + 0.5)
        wo_perp = wo.copy()
        wo_perp[2] = 0.0
        xi = xi1[:, None, None] * t3 + xi2[None, :, None] * b3  # (n1, n2, 3)
        wperp = xi - wo_perp
        r2 = np.einsum("abi,abi->ab", wperp, wperp)
        wi = wperp.copy()
        wi[..., 2] = np.sqrt(np.maximum(1.0 - r2, 0.0))
        inside = (r2 < 1.0) & _light_contains(light, wi)
        sinc2 = np.sinc(w_s * xi2 / lam) ** 2
        ang = (inside * sinc2[None, :]).sum(axis=1) * h2  # (n1,)
        integral = float(np.sum(spat * ang) * h1)
        pref = li * w_s**2 * float(scratch_depth_term_sq(d_s, lam)) / (coherence_area(sigma) * lam**2)
        total += pref * integral / area_p
    return total


def sample_light_directions(light, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(directions (n, 3), solid-angle pdf (n,)) sampled uniformly over the light's solid angle (sphere)
    or uniformly over its area (polygon, converted to a solid-angle pdf)."""
    if isinstance(light, SphereLight):
        c = np.asarray(light.center, dtype=np.float64)
        d = np.linalg.norm(c)
        p = c / d
        cos_max = np.sqrt(max(1.0 - (float(light.radius) / d) ** 2, 0.0))
        cz = 1.0 - rng.random(n) * (1.0 - cos_max)
        ph = 2 * np.pi * rng.random(n)
        sz = np.sqrt(np.maximum(1 - cz * cz, 0))
        a = np.array([1.0, 0, 0]) if abs(p[0]) < 0.9 else np.array([0, 1.0, 0])
        u = np.cross(p, a)
        u /= np.linalg.norm(u)
        v = np.cross(p, u)
        w = cz[:, None] * p + sz[:, None] * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
        return w, np.full(n, 1.0 / (2 * np.pi * (1.0 - cos_max)))
    V = np.asarray(light.vertices, dtype=np.float64)
    tris = [(V[0], V[i], V[i + 1]) for i in range(1, len(V) - 1)]
    areas = np.array([0.5 * np.linalg.norm(np.cross(b - a, c - a)) for a, b, c in tris])
    pick = rng.choice(len(tris), size=n, p=areas / areas.sum())
    r1, r2 = rng.random(n), rng.random(n)
    su = np.sqrt(r1)
    A = np.array([t[0] for t in tris])[pick]
    B = np.array([t[1] for t in tris])[pick]
    C = np.array([t[2] for t in tris])[pick]
    pts = (1 - su)[:, None] * A + (su * (1 - r2))[:, None] * B + (su * r2)[:, None] * C
    dist = np.linalg.norm(pts, axis=1)
    w = pts / dist[:, None]
    nrm = np.cross(V[1] - V[0], V[2] - V[0])
    nrm /= np.linalg.norm(nrm)
    cos_l = np.abs(w @ nrm)
    return w, dist**2 / (areas.sum() * np.maximum(cos_l, 1e-300))


def reference_radiance_mc(cfg: dict, n_samples: int, rng: np.random.Generator, batch: int = 200_000) -> float:
    """Plain Monte Carlo estimate of the same quantity as :func:`reference_radiance_quadrature`."""
    sigma = float(cfg.get("sigma_um", 60.0))
    lam = float(cfg["lam_nm"]) / 1000.0
    J = np.asarray(cfg["J"], dtype=np.float64)
    wo = np.asarray(cfg["wo"], dtype=np.float64)
    light = cfg["light"]
    li = float(np.mean(light.radiance))
    segs = np.asarray(cfg["segments"], dtype=np.float64)
    acc = 0.0
    done = 0
    while done < n_samples:
        m = min(batch, n_samples - done)
        r = np.sqrt(rng.random(m))
        th = 2 * np.pi * rng.random(m)
        x = (np.stack([r * np.cos(th), r * np.sin(th)], -1)) @ J.T
        wi, pdf = sample_light_directions(light, m, rng)
        up = wi[:, 2] > 0
        xi = wi + wo
        f = np.zeros(m)
        for seg, w_s, d_s in zip(segs, cfg["width_um"], cfg["depth_um"], strict=True):
            p0, p1 = seg[:2], seg[2:]
            length = float(np.linalg.norm(p1 - p0))
            t2 = (p1 - p0) / length
            t3, b3 = scratch_frame(t2)
            rel = p0 - x
            s_t = rel @ t2
            s_b = t2[0] * rel[:, 1] - t2[1] * rel[:, 0]
            xi1, xi2 = xi @ t3, xi @ b3
            eta = scratch_phase_term(xi1, xi2, s_t, s_b, length, lam, sigma)
            f += (
                w_s**2
                * np.sinc(w_s * xi2 / lam) ** 2
                * float(scratch_depth_term_sq(d_s, lam))
                * np.abs(eta) ** 2
            )
        f /= coherence_area(sigma) * lam**2
        acc += float(np.sum(np.where(up, li * f * wi[:, 2] / pdf, 0.0)))
        done += m
    return acc / n_samples


def random_validation_configs(
    n: int,
    rng: np.random.Generator,
    sigma_um: float = 60.0,
    area_ratio: tuple[float, float] = (10.0, 100.0),
    kinds: tuple[str, ...] = ("sphere", "polygon"),
) -> list[dict]:
    """Random configurations of footprint, scratches and light for the acceptance test.

    Footprint: ellipse around x = 0 with A_P / A_C log-uniform in ``area_ratio``, aspect 1-3, random
    orientation. Scratches: 1-3 straight segments through random points of the footprint, random
    orientation, ends at least 5 sigma outside the footprint (the thesis' assumption that scratches
    extend over the coherence area), width and depth uniform 0.8-6 um. View: theta_o <= 70 deg.
    Light: sphere (half angle 0.02-0.25 rad) or convex triangle/quad of similar size, centred so that
    the first scratch's specular line crosses it; some lights straddle the horizon. lambda: 380-780 nm.
    """
    out = []
    for i in range(n):
        ratio = float(np.exp(rng.uniform(np.log(area_ratio[0]), np.log(area_ratio[1]))))
        aspect = rng.uniform(1.0, 3.0)
        a1 = sigma_um * np.sqrt(ratio * aspect)
        a2 = sigma_um * np.sqrt(ratio / aspect)
        th = rng.uniform(0, np.pi)
        Rm = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        J = Rm @ np.diag([a1, a2])
        m = int(rng.integers(1, 4))
        segs = []
        for _ in range(m):
            rr, aa = np.sqrt(rng.random()), rng.uniform(0, 2 * np.pi)
            c = J @ np.array([rr * np.cos(aa), rr * np.sin(aa)])
            phi = rng.uniform(0, np.pi)
            t = np.array([np.cos(phi), np.sin(phi)])
            half = a1 + 6 * sigma_um + rng.uniform(0, a1)
            segs.append(np.concatenate([c - half * t, c + half * t]))
        segs = np.array(segs)
        tz = np.deg2rad(rng.uniform(0, 70))
        pz = rng.uniform(0, 2 * np.pi)
        wo = np.array([np.sin(tz) * np.cos(pz), np.sin(tz) * np.sin(pz), np.cos(tz)])
        t2 = (segs[0, 2:] - segs[0, :2]) / np.linalg.norm(segs[0, 2:] - segs[0, :2])
        t3, b3 = scratch_frame(t2)
        alpha = rng.uniform(0.02, 0.25)
        ct = float(np.clip(-wo @ t3 + rng.uniform(-0.8, 0.8) * np.sin(alpha), -0.98, 0.98))
        psi = rng.uniform(0.0, np.pi)
        wc = ct * t3 + np.sqrt(1 - ct * ct) * (np.cos(psi) * b3 + np.sin(psi) * np.array([0, 0, 1.0]))
        kind = kinds[i % len(kinds)]
        if kind == "sphere":
            light = SphereLight(center=wc, radius=float(np.sin(alpha)))
        else:
            nv = int(rng.integers(3, 5))
            # polygon in a plane through wc, tilted by up to 45 deg from facing the point
            tilt = rng.normal(size=3)
            tilt -= (tilt @ wc) * wc
            nrm = wc + np.tan(rng.uniform(0, np.pi / 4)) * tilt / np.linalg.norm(tilt)
            nrm /= np.linalg.norm(nrm)
            e1 = np.cross(nrm, [0.3, 0.5, 0.8])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(nrm, e1)
            angs = np.sort(rng.uniform(0, 2 * np.pi, nv))
            rad = np.tan(alpha) * rng.uniform(0.7, 1.3)
            verts = np.array([wc + rad * (np.cos(a) * e1 + np.sin(a) * e2) for a in angs])
            light = PolygonLight(vertices=verts)
        out.append(
            {
                "J": J,
                "wo": wo,
                "light": light,
                "segments": segs,
                "width_um": rng.uniform(0.8, 6.0, m),
                "depth_um": rng.uniform(0.8, 6.0, m),
                "lam_nm": float(rng.uniform(380, 780)),
                "sigma_um": sigma_um,
                "kind": kind,
            }
        )
    return out


def analytic_radiance_config(cfg: dict, si: str = "series", footprint_rule: str = "chords") -> float:
    """The analytic pipeline (eq. 4.16, 4.27, 4.30-4.41) on one validation configuration."""
    from .scratch_radiance import scratch_radiance_pairs

    segs = np.asarray(cfg["segments"], dtype=np.float64)
    m = segs.shape[0]
    res = scratch_radiance_pairs(
        np.zeros((1, 2)),
        np.asarray(cfg["J"])[None],
        np.asarray(cfg["wo"])[None],
        cfg["light"],
        segs,
        cfg["width_um"],
        cfg["depth_um"],
        np.zeros(m, np.int64),
        np.arange(m),
        [cfg["lam_nm"]],
        sigma_um=float(cfg.get("sigma_um", 60.0)),
        si=si,
        footprint_rule=footprint_rule,
    )
    return float(res.spectral[0, 0])


def analytic_radiance_configs(cfgs: list[dict], si: str = "series", footprint_rule: str = "chords") -> np.ndarray:
    """Vectorised :func:`analytic_radiance_config` over many configurations (one call per light type)."""
    from .scratch_radiance import shade_scratch_pairs

    out = np.zeros(len(cfgs))
    groups: dict[tuple, list[int]] = {}
    for i, c in enumerate(cfgs):
        key = ("sphere",) if isinstance(c["light"], SphereLight) else ("polygon", len(c["light"].vertices))
        groups.setdefault(key, []).append(i)
    for key, idx in groups.items():
        pc = np.concatenate([np.full(len(cfgs[i]["segments"]), i) for i in idx])
        seg = np.concatenate([np.asarray(cfgs[i]["segments"], float) for i in idx])
        w = np.concatenate([cfgs[i]["width_um"] for i in idx])
        d = np.concatenate([cfgs[i]["depth_um"] for i in idx])
        J = np.stack([np.asarray(cfgs[i]["J"], float) for i in pc])
        wo = np.stack([np.asarray(cfgs[i]["wo"], float) for i in pc])
        lam = np.array([[cfgs[i]["lam_nm"] / 1000.0] for i in pc])
        if key[0] == "sphere":
            geom = {"kind": "sphere", "center": np.stack([np.asarray(cfgs[i]["light"].center, float) for i in pc]),
                    "radius": np.array([float(cfgs[i]["light"].radius) for i in pc])}
        else:
            geom = {"kind": "polygon", "vertices": np.stack([np.asarray(cfgs[i]["light"].vertices, float) for i in pc])}
        li = np.array([float(np.mean(cfgs[i]["light"].radiance)) for i in pc])
        rad, _, _ = shade_scratch_pairs(np.zeros((len(pc), 2)), J, wo, geom, seg, w, d, lam,
                                        float(cfgs[idx[0]].get("sigma_um", 60.0)), si, footprint_rule)
        out += np.bincount(pc, weights=rad[:, 0] * li, minlength=len(cfgs))
    return out
