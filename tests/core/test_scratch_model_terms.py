"""Model terms eq. 4.1-4.11 against direct numerical integration, and coherent vs incoherent."""

from __future__ import annotations

import numpy as np
from scipy.integrate import quad

from material_structures.core.scratch.scratch_brdf import coherent_brdf, incoherent_brdf
from material_structures.core.scratch.scratch_model_terms import (
    base_response_flat,
    scratch_depth_term,
    scratch_depth_term_sq,
    scratch_phase_sq_angular,
    scratch_phase_sq_spatial,
    scratch_phase_term,
    scratch_phase_term_infinite,
)

SIG = 60.0


def _eta_by_quadrature(xi1, xi2, s_t, s_b, length, lam):
    """eta = int_0^l exp(-|s' + h t|^2 / (2 sigma^2)) exp(-i k xi . (s' + h t)) dh, eq. 4.5's integral."""
    k = 2 * np.pi / lam

    def f(h, part):
        u = s_t + h
        val = np.exp(-(u * u + s_b * s_b) / (2 * SIG**2) - 1j * k * (xi1 * u + xi2 * s_b))
        return val.real if part == 0 else val.imag

    re = quad(f, 0, length, args=(0,), limit=400, points=[-s_t])[0]
    im = quad(f, 0, length, args=(1,), limit=400, points=[-s_t])[0]
    return re + 1j * im


def test_phase_term_matches_direct_integration():
    rng = np.random.default_rng(3)
    for _ in range(12):
        lam = rng.uniform(0.38, 0.78)
        xi1 = rng.normal(0, 2.0) / (SIG * 2 * np.pi / lam)
        xi2 = rng.uniform(-0.5, 0.5)
        s_t, s_b, length = rng.uniform(-200, 50), rng.uniform(-90, 90), rng.uniform(20, 300)
        got = scratch_phase_term(xi1, xi2, s_t, s_b, length, lam, SIG)
        ref = _eta_by_quadrature(xi1, xi2, s_t, s_b, length, lam)
        assert abs(got - ref) <= 1e-7 * max(1.0, abs(ref))


def test_phase_term_is_stable_far_from_the_band():
    # exp(-sigma^2 k^2 xi1^2 / 2) underflows to 0 and erf overflows there; the product (edge
    # diffraction of the truncated segment, ~1/(k xi1)) must still match the integral
    for xi1 in (0.05, 0.3):
        v = scratch_phase_term(xi1, 0.1, -100.0, 5.0, 400.0, 0.5, SIG)
        ref = _eta_by_quadrature(xi1, 0.1, -100.0, 5.0, 400.0, 0.5)
        assert np.isfinite(v) and abs(v - ref) < 1e-6 * abs(ref)


def test_infinite_limit_and_separable_square():
    lam = 0.55
    xi1 = np.linspace(-3, 3, 7) / (SIG * 2 * np.pi / lam)
    long = scratch_phase_term(xi1, 0.2, -1e5, 37.0, 2e5, lam, SIG)
    inf = scratch_phase_term_infinite(xi1, 0.2, 37.0, lam, SIG)
    assert np.allclose(long, inf, rtol=1e-12, atol=0)
    # eq. 4.9/4.10: |eta|^2 = |eta_s|^2 |eta_a|^2
    assert np.allclose(np.abs(inf) ** 2, scratch_phase_sq_spatial(37.0, SIG) * scratch_phase_sq_angular(xi1, lam, SIG))


def test_depth_term_square_identity():
    d = np.linspace(0.8, 6, 50)
    for lam in (0.4, 0.55, 0.7):
        assert np.allclose(np.abs(scratch_depth_term(d, lam)) ** 2, scratch_depth_term_sq(d, lam), atol=1e-12)


def test_flat_base_brdf_integrates_to_one():
    lam = 0.5
    s = 4.0 / (SIG * 2 * np.pi / lam)
    g = np.linspace(-s, s, 801)
    X, Y = np.meshgrid(g, g)
    f = base_response_flat(X, Y, lam, SIG) ** 2 / (np.pi * SIG**2 * lam**2)
    assert abs(f.sum() * (g[1] - g[0]) ** 2 - 1.0) < 1e-3


def test_incoherent_equals_coherent_averaged_over_random_phases():
    rng = np.random.default_rng(11)
    lam = 0.6
    segs = np.array([[-300.0, -20, 300, 10], [-50, -250, 40, 260], [-280, 60, 260, -30]])
    w = np.array([2.0, 4.5, 1.1])
    d = np.array([1.3, 0.9, 3.7])
    k = 2 * np.pi / lam
    xi = np.array([[0.3 / (SIG * k), 0.05], [0.0, 0.12], [1.5 / (SIG * k), -0.2], [0.0, 0.0]])
    n = 20000
    phases = rng.uniform(0, 2 * np.pi, (n, 1, 3))
    coh = coherent_brdf(xi[None], np.zeros(2), segs, w, d, lam, SIG, phases)  # (n, 4)
    inc = incoherent_brdf(xi, np.zeros(2), segs, w, d, lam, SIG)
    mean, sem = coh.mean(axis=0), coh.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(mean - inc) < 4 * sem + 1e-9 * inc)
    # and without averaging the cross terms are not negligible (the test can fail)
    assert np.any(np.abs(coh[0] - inc) > 10 * sem)
