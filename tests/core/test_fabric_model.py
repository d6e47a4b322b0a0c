"""Pile-fabric model (eq. 3.5-3.10) and specular sampling against independent references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats

from material_structures.core.fabric.quaternion import (
    matrix_to_quat,
    quat_from_axis_angle,
    quat_to_matrix,
)
from material_structures.core.fabric.sggx_brdf import sggx_brdf, sggx_specular
from material_structures.core.fabric.sggx_matrix import projected_area, sggx_matrix
from material_structures.core.fabric.sggx_ndf import sggx_ndf
from material_structures.core.fabric.sggx_sampling import sample_specular, specular_pdf


def sphere_grid(nt: int, nph: int, upper: bool = False):
    """Midpoint lat-long quadrature over the sphere (or the upper hemisphere)."""
    tmax = np.pi / 2 if upper else np.pi
    t = (np.arange(nt) + 0.5) / nt * tmax
    p = (np.arange(nph) + 0.5) / nph * 2 * np.pi
    tt, pp = np.meshgrid(t, p, indexing="ij")
    w = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    da = np.sin(tt) * (tmax / nt) * (2 * np.pi / nph)
    return w, da


def random_dirs(rng, n, upper=True):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    if upper:
        v[:, 2] = np.abs(v[:, 2]) + 1e-3
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v


def random_params(rng, n):
    q = quat_from_axis_angle(rng.normal(size=(n, 3)), rng.uniform(0, np.pi, n))
    sigma = rng.uniform(0.1, 1.5, (n, 2))
    kd = rng.uniform(0, 0.5, (n, 3))
    ks = rng.uniform(0, 1, (n, 3))
    return kd, ks, sigma, q


TILTED = quat_from_axis_angle(np.array([0.3, 1.0, 0.1]), np.array(np.radians(30)))


def test_quaternion_roundtrip():
    rng = np.random.default_rng(1)
    q = quat_from_axis_angle(rng.normal(size=(500, 3)), rng.uniform(0, np.pi, 500))
    q = np.where(q[:, :1] < 0, -q, q)
    r = quat_to_matrix(q)
    assert np.allclose(np.einsum("nij,nik->njk", r, r), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0, atol=1e-12)
    assert np.allclose(matrix_to_quat(r), q, atol=1e-10)


def test_sggx_matrix_eigen_structure():
    """eq. 3.6-3.8: basis axes are eigenvectors and sigma(w_k) = S_v^(k)."""
    sig = np.array([0.2, 0.7])
    s = sggx_matrix(TILTED, sig)
    m = quat_to_matrix(TILTED)
    for k, sv in enumerate([0.2, 0.7, 1.0]):
        assert np.allclose(s @ m[:, k], sv**2 * m[:, k], atol=1e-12)
        assert projected_area(m[:, k], s) == pytest.approx(sv, rel=1e-12)


def test_ndf_projected_area_normalisation():
    """int <w, m>_+ D(m) dm = sigma(w) (SGGX normalisation), by quadrature on the sphere."""
    s = sggx_matrix(TILTED, np.array([0.35, 0.6]))
    m, da = sphere_grid(600, 1200)
    d = sggx_ndf(m, s)
    for w in (np.array([0, 0, 1.0]), np.array([0.6, 0.0, 0.8]), np.array([0.0, 1.0, 0.0])):
        lhs = np.sum(np.maximum(m @ w, 0) * d * da)
        assert lhs == pytest.approx(projected_area(w, s), rel=2e-3)


def test_brdf_reciprocity_and_nonnegativity():
    rng = np.random.default_rng(2)
    n = 20000
    kd, ks, sigma, q = random_params(rng, n)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    f1 = sggx_brdf(wi, wo, kd, ks, sigma, q)
    f2 = sggx_brdf(wo, wi, kd, ks, sigma, q)
    assert np.allclose(f1, f2, rtol=1e-12, atol=0)
    assert np.all(f1 >= 0) and np.all(np.isfinite(f1))


def test_brdf_matches_full_matrix_implementation():
    """Second implementation of eq. 3.9 via the full 3x3 SGGX matrix (inverse, determinant)."""
    rng = np.random.default_rng(3)
    n = 5000
    kd, ks, sigma, q = random_params(rng, n)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    s = sggx_matrix(q, sigma)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    ci, co = wi[:, 2], wo[:, 2]
    spec = sggx_ndf(h, s) / (4 * ci * co * (projected_area(wo, s) / co + projected_area(wi, s) / ci))
    ref = ks * spec[:, None] + kd / np.pi
    assert np.allclose(sggx_brdf(wi, wo, kd, ks, sigma, q), ref, rtol=1e-10)


def test_untilted_equals_half_ggx_height_correlated():
    """Untilted SGGX specular = 1/2 anisotropic GGX microfacet BRDF (F=1, height-correlated Smith)."""
    rng = np.random.default_rng(4)
    n = 5000
    ax, ay = rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    # anisotropic GGX NDF (Heitz 2014, eq. 85) and Smith Lambda (eq. 86)
    cos_h = h[:, 2]
    tan2_terms = (h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2
    d_ggx = 1.0 / (np.pi * ax * ay * cos_h**4 * (1 + tan2_terms / cos_h**2) ** 2)

    def lam(w):
        a2tan2 = ((ax * w[:, 0]) ** 2 + (ay * w[:, 1]) ** 2) / w[:, 2] ** 2
        return 0.5 * (-1 + np.sqrt(1 + a2tan2))

    g2 = 1.0 / (1.0 + lam(wi) + lam(wo))
    ggx = d_ggx * g2 / (4 * wi[:, 2] * wo[:, 2])
    ident = np.tile([1.0, 0, 0, 0], (n, 1))
    ours = sggx_specular(wi, wo, np.stack([ax, ay], -1), ident)
    assert np.allclose(ours, 0.5 * ggx, rtol=1e-10)


def test_isotropic_reduction_lommel_seeliger():
    """sigma = 1 (any basis): D = 1/pi and f_r = k_s / (4 pi (cos_i + cos_o)) (Lommel-Seeliger)."""
    rng = np.random.default_rng(5)
    n = 2000
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    q = quat_from_axis_angle(rng.normal(size=(n, 3)), rng.uniform(0, 3, n))
    f = sggx_brdf(wi, wo, np.zeros((n, 3)), np.full((n, 3), 0.8), np.ones((n, 2)), q)
    ref = 0.8 / (4 * np.pi * (wi[:, 2] + wo[:, 2]))
    assert np.allclose(f, ref[:, None], rtol=1e-12)


def test_isotropic_albedo_matches_chandrasekhar_single_scattering():
    """Directional albedo of the isotropic limit vs the closed form of Chandrasekhar's single-scattering
    (Lommel-Seeliger) law: A(mu) = w/2 (1 - mu ln(1 + 1/mu))."""
    w, da = sphere_grid(400, 8, upper=True)
    for mu in (0.2, 0.5, 0.9):
        wi = np.array([np.sqrt(1 - mu * mu), 0, mu])
        f = sggx_brdf(wi, w, np.zeros(3), np.ones(3), np.ones(2), np.array([1.0, 0, 0, 0]))[..., 0]
        albedo = np.sum(f * w[..., 2] * da)
        assert albedo == pytest.approx(0.5 * (1 - mu * np.log(1 + 1 / mu)), rel=1e-3)


def test_brdf_equals_single_scattering_rte_integral():
    """eq. 3.1-3.3: integrate the single-scattering RTE over depth numerically (scipy.quad) and compare
    to f_r cos_i of eq. 3.9 (the volume density cancels)."""
    sig = np.array([0.3, 0.55])
    s = sggx_matrix(TILTED, sig)
    rng = np.random.default_rng(6)
    rho = 7.3
    for wi, wo in zip(random_dirs(rng, 5), random_dirs(rng, 5), strict=True):
        h = (wi + wo) / np.linalg.norm(wi + wo)
        so, si = projected_area(wo, s), projected_area(wi, s)
        fp = sggx_ndf(h, s) / (4 * so)  # eq. 3.4
        ci, co = wi[2], wo[2]

        def integrand(t, so=so, si=si, fp=fp, ci=ci, co=co):
            return np.exp(-rho * so * t) * rho * so * fp * np.exp(-rho * si * co / ci * t)

        radiance, _ = integrate.quad(integrand, 0, np.inf, epsabs=0, epsrel=1e-10)
        f = sggx_brdf(wi, wo, np.zeros(3), np.ones(3), sig, TILTED)[0]
        assert f * ci == pytest.approx(radiance, rel=1e-7)


@pytest.mark.parametrize("sigma", [(0.3, 0.6), (0.15, 1.0), (1.0, 1.0)])
def test_albedo_at_most_one(sigma):
    """Hemispherical albedo int f_r cos_o dwo <= 1 for k_s + k_d = 1 (numeric quadrature)."""
    w, da = sphere_grid(300, 600, upper=True)
    sig = np.array(sigma)
    worst = 0.0
    for theta in (0.0, 0.7, 1.2, 1.45):
        for q in (np.array([1.0, 0, 0, 0]), TILTED):
            wi = np.array([np.sin(theta), 0.0, np.cos(theta)])
            spec = sggx_brdf(wi, w, np.zeros(3), np.ones(3), sig, q)[..., 0]
            a_spec = np.sum(spec * w[..., 2] * da)
            worst = max(worst, a_spec)
            # diffuse part integrates to exactly k_d: check the total for k_s = 0.6, k_d = 0.4
            tot = sggx_brdf(wi, w, np.full(3, 0.4), np.full(3, 0.6), sig, q)[..., 0]
            assert np.sum(tot * w[..., 2] * da) <= 1.0 + 1e-3
    # ks = 1 alone: single scattering in a non-absorbing half-space reflects at most everything
    assert 0.05 < worst <= 1.0 + 1e-3


def test_sampling_pdf_integrates_to_one_and_matches_histogram():
    sig = np.array([0.3, 0.6])
    wo = np.array([0.5, 0.2, 0.8])
    wo /= np.linalg.norm(wo)
    nt, nph = 600, 1200
    w, da = sphere_grid(nt, nph)
    pdf = specular_pdf(w, wo, sig, TILTED)
    assert np.sum(pdf * da) == pytest.approx(1.0, abs=2e-3)
    rng = np.random.default_rng(7)
    n = 200_000
    wi, pdf_s = sample_specular(np.broadcast_to(wo, (n, 3)), sig, TILTED, rng.random(n), rng.random(n))
    assert np.allclose(np.linalg.norm(wi, axis=-1), 1, atol=1e-12)
    assert np.allclose(pdf_s, specular_pdf(wi, wo, sig, TILTED), rtol=1e-10)
    bt, bp = 20, 40
    it = np.clip((np.arccos(np.clip(wi[:, 2], -1, 1)) / np.pi * bt).astype(int), 0, bt - 1)
    ip = ((np.arctan2(wi[:, 1], wi[:, 0]) % (2 * np.pi)) / (2 * np.pi) * bp).astype(int) % bp
    hist = np.zeros((bt, bp))
    np.add.at(hist, (it, ip), 1)
    expected = (pdf * da).reshape(bt, nt // bt, bp, nph // bp).sum((1, 3)) * n
    keep = expected > 5
    chi2 = np.sum((hist - expected)[keep] ** 2 / expected[keep])
    dof = int(keep.sum()) - 1
    assert stats.chi2.sf(chi2, dof) > 1e-3
    assert hist[~keep].sum() < 2e-3 * n
