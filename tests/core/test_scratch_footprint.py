"""Footprint integration (eq. 4.13-4.18) against brute-force sampling of the ellipse."""

from __future__ import annotations

import numpy as np

from material_structures.core.scratch.scratch_footprint import (
    footprint_alpha,
    footprint_area,
    footprint_matrix,
    footprint_semi_major,
    scratch_contained_length,
    scratch_footprint_density,
    scratch_footprint_phase_sq,
    scratch_weighted_length,
)

SIG = 60.0


def _random_ellipse(rng, ratio):
    aspect = rng.uniform(1, 3)
    a1, a2 = SIG * np.sqrt(ratio * aspect), SIG * np.sqrt(ratio / aspect)
    th = rng.uniform(0, np.pi)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    # a shear as well: J need not have orthogonal columns
    return R @ np.diag([a1, a2]) @ np.array([[1.0, rng.uniform(-0.5, 0.5)], [0.0, 1.0]])


def test_contained_length_vs_point_sampling():
    rng = np.random.default_rng(0)
    for _ in range(30):
        J = _random_ellipse(rng, rng.uniform(3, 60))
        Ji = np.linalg.inv(J)
        p0, p1 = rng.uniform(-600, 600, 2), rng.uniform(-600, 600, 2)
        t = (np.arange(200_000) + 0.5) / 200_000
        pts = p0 + t[:, None] * (p1 - p0)
        inside = np.einsum("ij,nj->ni", Ji, pts)
        frac = np.mean((inside**2).sum(1) <= 1.0)
        ref = frac * np.linalg.norm(p1 - p0)
        assert abs(scratch_contained_length(p0, p1, np.zeros(2), Ji) - ref) < 1e-2


def test_area_and_semi_major_axis():
    J = np.array([[3.0, 1.0], [0.0, 2.0]])
    s = np.linalg.svd(J, compute_uv=False)
    assert np.isclose(footprint_area(J), np.pi * s[0] * s[1])
    assert np.isclose(footprint_semi_major(J), s[0])
    assert footprint_matrix(5.0, 3).shape == (3, 2, 2)
    assert np.isclose(footprint_alpha(np.pi * SIG**2, SIG), 0.5)
    assert footprint_alpha(100 * np.pi * SIG**2, SIG) == 1.0


def _gaussian_over_ellipse(J, p0, p1, s, n=900):
    """int_{ellipse} exp(-dist_to_line^2 / s^2) [foot on segment] dA by a dense grid."""
    g = (np.arange(n) + 0.5) / n * 2 - 1
    U, V = np.meshgrid(g, g)
    m = U**2 + V**2 <= 1
    pts = np.stack([U[m], V[m]], 1) @ J.T
    d = p1 - p0
    L = np.linalg.norm(d)
    t = d / L
    rel = pts - p0
    along = rel @ t
    sb = rel[:, 0] * t[1] - rel[:, 1] * t[0]
    w = np.exp(-(sb**2) / s**2) * ((along >= 0) & (along <= L))
    return w.sum() * abs(np.linalg.det(J)) * (2.0 / n) ** 2


def test_weighted_length_vs_dense_area_integral():
    rng = np.random.default_rng(1)
    errs_thesis, errs_chords, refs = [], [], []
    for _ in range(25):
        J = _random_ellipse(rng, np.exp(rng.uniform(np.log(8), np.log(80))))
        Ji = np.linalg.inv(J)
        c = J @ (np.sqrt(rng.random()) * np.array([np.cos(a := rng.uniform(0, 6.3)), np.sin(a)]))
        ph = rng.uniform(0, np.pi)
        t = np.array([np.cos(ph), np.sin(ph)])
        p0, p1 = c - 3000 * t, c + 3000 * t
        ref = _gaussian_over_ellipse(J, p0, p1, SIG) / (SIG * np.sqrt(np.pi))
        refs.append(ref)
        errs_thesis.append(scratch_weighted_length(p0, p1, np.zeros(2), J, Ji, SIG, "thesis") - ref)
        errs_chords.append(scratch_weighted_length(p0, p1, np.zeros(2), J, Ji, SIG, "chords") - ref)
    refs = np.array(refs)
    rel = lambda e: np.sqrt(np.sum(np.square(e)) / np.sum(refs**2))  # noqa: E731
    assert rel(errs_chords) < 2e-3  # the 12-chord rule
    assert rel(errs_thesis) > 5 * rel(errs_chords)  # eq. 4.14 is visibly coarser
    assert rel(errs_thesis) < 0.1


def test_phase_and_density_limits():
    A_P = 50 * np.pi * SIG**2  # alpha = 1: eq. 4.15 and eq. 4.18 exactly
    l, w = 300.0, 2.0
    eta = scratch_footprint_phase_sq(l, 0.0, True, A_P, SIG)
    a1a2 = A_P / np.pi
    assert np.isclose(eta, 2 * SIG**3 * np.sqrt(np.pi) * l / a1a2)
    assert np.isclose(scratch_footprint_density(w, l, 0.0, True, A_P, SIG), 2 * w * l / A_P)
    # tiny footprint: |eta_s|^2 = 2 A_C exp(-sb^2/sigma^2) (eq. 4.10) and rho_C (eq. 4.17)
    tiny = 1e-6
    assert np.isclose(scratch_footprint_phase_sq(0.0, 30.0, True, tiny, SIG), 2 * np.pi * SIG**2 * np.exp(-0.25))
    rho_c = w * np.sqrt(2 * np.pi) * SIG * np.exp(-30.0**2 / (2 * SIG**2)) / (np.pi * SIG**2)
    assert np.isclose(scratch_footprint_density(w, 0.0, 30.0, True, tiny, SIG), rho_c)


def test_footprint_average_of_eta_s_matches_eq_4_13():
    # (1/A_P) int |eta_s|^2 dx for a long scratch through a large footprint, by dense sampling
    J = np.diag([700.0, 400.0])
    p0, p1 = np.array([-5000.0, 50.0]), np.array([5000.0, 80.0])
    ref = 2 * np.pi * SIG**2 * _gaussian_over_ellipse(J, p0, p1, SIG) / (np.pi * 700 * 400)
    lw = scratch_weighted_length(p0, p1, np.zeros(2), J, np.linalg.inv(J), SIG, "chords")
    got = scratch_footprint_phase_sq(lw, 60.0, True, np.pi * 700 * 400, SIG)
    assert abs(got / ref - 1) < 2e-3
