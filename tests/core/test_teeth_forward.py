"""Forward renderer vs closed-form references (slab transmittance, single scattering in a slab)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from material_structures.core.teeth.fresnel import ETA_ENAMEL, fresnel_dielectric
from material_structures.core.teeth.path_tracer import RenderSettings, render

from ._teeth_scenes import down_camera, light, slab_scene


def _fresnel_ref(cos_i, eta):
    """Textbook unpolarised Fresnel (Hecht) computed via Snell angles: independent of the module."""
    ti = np.arccos(cos_i)
    tt = np.arcsin(np.sin(ti) / eta)
    if ti == 0:
        return ((eta - 1) / (eta + 1)) ** 2
    rs = np.sin(ti - tt) ** 2 / np.sin(ti + tt) ** 2
    rp = np.tan(ti - tt) ** 2 / np.tan(ti + tt) ** 2
    return 0.5 * (rs + rp)


def test_fresnel_matches_snell_form():
    for c in (1.0, 0.8, 0.5, 0.2):
        assert fresnel_dielectric(np.array([c]), ETA_ENAMEL)[0] == pytest.approx(_fresnel_ref(c, ETA_ENAMEL), rel=1e-9)
    assert fresnel_dielectric(np.array([-0.5]), 1.33)[0] == pytest.approx(_fresnel_ref(0.5, 1.33), rel=1e-9)


def _mean_and_err(img, pixels):
    v = img.reshape(-1, 3)[pixels]
    return v.mean(axis=0), v.std(axis=0) / np.sqrt(len(v))


def test_slab_transmittance_closed_form():
    """Absorbing slab over a Lambertian floor: camera -> slab -> floor -> slab -> light (depth 3)."""
    sigma = np.array([0.3, 0.6, 1.0])
    d, a_t, rho = 2.0, 0.9, np.array([0.5, 0.4, 0.3])
    scene = slab_scene(sigma, 0.0, thickness=d, a_t=a_t, floor_albedo=rho)
    cam = down_camera(width=12, height=12, fov=1.0)
    lpos = np.array([0.0, 300.0, 500.0])
    lt = light(lpos, 2.0e5)
    with np.errstate(divide="ignore"):
        res = render(scene, [cam], [lt], RenderSettings(spp=400, max_depth=3, jitter=False, seed=1))
    img = res.images[0, 0]
    # closed form per pixel centre
    jj, ii = np.meshgrid(np.arange(12) + 0.5, np.arange(12) + 0.5)
    o, dirs = cam.rays(jj.ravel(), ii.ravel())
    t = (-5.0 - o[:, 2]) / dirs[:, 2]
    p = o + t[:, None] * dirs
    to = lpos - p
    r = np.linalg.norm(to, axis=1)
    wl = to / r[:, None]
    cos_c, cos_l = np.abs(dirs[:, 2]), wl[:, 2]
    fc = np.array([_fresnel_ref(c, ETA_ENAMEL) for c in cos_c])
    fl = np.array([_fresnel_ref(c, ETA_ENAMEL) for c in cos_l])
    expect = (rho[None] / np.pi * cos_l[:, None] * 2.0e5 / r[:, None] ** 2
              * ((a_t * (1 - fc)) ** 2)[:, None] * np.exp(-sigma[None] * d / cos_c[:, None])
              * ((a_t * (1 - fl)) ** 2)[:, None] * np.exp(-sigma[None] * d / cos_l[:, None]))
    got = img.reshape(-1, 3)
    ratio = got.mean(axis=0) / expect.mean(axis=0)
    err = got.std(axis=0) / np.sqrt(got.shape[0]) / expect.mean(axis=0)
    # per-pixel spp=400 -> pooled relative standard error ~1e-3
    assert np.all(np.abs(ratio - 1) < 4 * err + 1e-3), (ratio, err)


def _single_scatter_ref(o, dcam, lpos, I, sigma, alb, d, a_t, g1, g2, beta):
    t0 = (d - o[2]) / dcam[2]
    cos_c = abs(dcam[2])
    fc = _fresnel_ref(cos_c, ETA_ENAMEL)

    def hgf(mu, g):
        return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)

    def integrand(s):
        x = o + (t0 + s) * dcam
        to = lpos - x
        r = np.linalg.norm(to)
        w = to / r
        depth = d - x[2]
        ell = depth / w[2]
        mu = float(np.dot(dcam, w))
        fl = _fresnel_ref(w[2], ETA_ENAMEL)
        fp = beta * hgf(mu, g1) + (1 - beta) * hgf(mu, g2)
        return (np.exp(-sigma * s) * sigma * alb * fp * np.exp(-sigma * ell) * a_t * (1 - fl) * I / r**2)

    val, _ = quad(integrand, 0.0, d / cos_c, limit=200, epsabs=0, epsrel=1e-10)
    return (1 - fc) * a_t * val


def test_single_scattering_homogeneous_slab():
    sigma = np.array([0.4, 0.8, 1.6])
    alb = np.array([0.9, 0.7, 0.5])
    d, a_t, g1, g2, beta = 2.0, 0.85, 0.5, -0.3, 0.7
    scene = slab_scene(sigma, alb, thickness=d, a_t=a_t, g1=g1, g2=g2, beta=beta)
    cam = down_camera(width=8, height=8, fov=1.0, eye=(0.0, -150.0, 260.0), target=(0.0, 0.0, 0.0))
    lpos = np.array([100.0, 200.0, 400.0])
    I = 1.0e5
    res = render(scene, [cam], [light(lpos, I)], RenderSettings(spp=2000, max_depth=2, jitter=False, seed=2))
    got = res.images[0, 0].reshape(-1, 3)
    jj, ii = np.meshgrid(np.arange(8) + 0.5, np.arange(8) + 0.5)
    o, dirs = cam.rays(jj.ravel(), ii.ravel())
    expect = np.array([[_single_scatter_ref(o[k], dirs[k], lpos, I, sigma[c], alb[c], d, a_t, g1, g2, beta)
                        for c in range(3)] for k in range(len(o))])
    ratio = got.mean(axis=0) / expect.mean(axis=0)
    # standard error of the mean of the pixel estimates (each pixel has its own closed form)
    err = (got / expect).std(axis=0) / np.sqrt(len(o))
    assert np.all(np.abs(ratio - 1) < 4 * err + 2e-3), (ratio, err)
    assert np.all(err < 0.02)
