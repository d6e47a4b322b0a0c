"""Capture sensitivity (chi2 of parameter directions): the tile/pair estimator against a brute-force
recomputation from central differences (common random numbers; the dentin coefficients' by renders of
both ends), and its unbiasedness across independent seeds."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.gradient_check import fd_test_scene
from material_structures.core.teeth.param_vector import ParamLayout, scene_to_vector, vector_to_scene
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.sensitivity import capture_sensitivity, default_directions


@pytest.fixture(scope="module")
def problem():
    sc, cams, lights = fd_test_scene()
    masks = np.zeros((1, cams[0].height, cams[0].width), bool)
    masks[0, 1:11, 2:13] = True
    return sc, Capture(cams, lights, None, masks)


def test_default_directions_keep_sigma_s_or_sigma_a_fixed(problem):
    sc, _ = problem
    layout = ParamLayout(sc)
    names, D = default_directions(sc, layout, rel=0.1, dc=0.05)
    x = scene_to_vector(sc, layout)
    h = 1e-4
    for name, d in zip(names, D, strict=True):
        if ".c[" in name:
            assert d.max() == 0.05 and np.count_nonzero(d) == 1
            continue
        prefix, what = name.rsplit(".", 1)
        ch = int(what.split("[")[1][0])
        s, a = layout.col(prefix + ".sigma_t") + ch, layout.col(prefix + ".albedo") + ch
        y = x + h * d
        ss0, sa0 = x[s] * x[a], x[s] * (1 - x[a])
        ss1, sa1 = y[s] * y[a], y[s] * (1 - y[a])
        moved, fixed = ((ss1 / ss0, sa1 / sa0) if what.startswith("sigma_s") else (sa1 / sa0, ss1 / ss0))
        assert (moved - 1) / h == pytest.approx(0.1, rel=1e-3), name
        assert abs(fixed - 1) / h < 1e-3 * 0.1, name


def test_chi2_matches_brute_force_from_crn_central_differences(problem):
    sc, cap = problem
    layout = ParamLayout(sc)
    names, D = default_directions(sc, layout)
    pick = [names.index(n) for n in ("tooth0.dentin.sigma_a[1]", "tooth0.enamel.sigma_a[0]", "tooth0.c[0]")]
    D = np.vstack([D[pick], np.zeros(layout.size)])  # plus a direction that changes nothing
    passes, block, nv = 4, 4, 2e-5
    out = capture_sensitivity(sc, cap, D, passes=passes, block=block, noise_variance=nv, max_depth=5, seed=3)
    # brute force: per pass, the CRN central difference of the images along d, tiles summed by loops
    x0 = scene_to_vector(sc, layout)
    m = cap.masks[0]
    hgt, wid = m.shape
    ref = []
    for d in D[:-1]:
        # materials: the derivative (reweighted differences, the sampling of x0); a dentin coefficient: the
        # image change of +-d itself, each end sampled as rendered (common random numbers)
        shape = bool(np.any(d[layout.kinds() == "c"] != 0))
        eps, sampling = (1.0, None) if shape else (1e-5 / np.abs(d).max(), sc)
        tiles = []
        for i in range(passes):
            st = RenderSettings(spp=1, max_depth=5, seed=3 + i)
            ip, im = (render(vector_to_scene(sc, x0 + sgn * eps * d, layout), cap.cameras, cap.lights, st,
                             pixels=[np.flatnonzero(m)], sampling_scene=sampling).images[0] for sgn in (1, -1))
            diff = (ip - im) / (2 * eps)
            t = []
            for r0 in range(0, hgt, block):
                for c0 in range(0, wid, block):
                    mm = m[r0:r0 + block, c0:c0 + block]
                    if mm.any():
                        t.append((diff[:, r0:r0 + block, c0:c0 + block][:, mm].sum(axis=1), mm.sum()))
            tiles.append(t)
        chi2 = 0.0
        for ti in range(len(tiles[0])):
            n_pix = tiles[0][ti][1]
            for i in range(passes):
                for j in range(passes):
                    if i != j:
                        chi2 += np.sum(tiles[i][ti][0] * tiles[j][ti][0]) / (passes * (passes - 1) * n_pix * nv)
        ref.append(chi2)
    assert out["tiles"] == len(tiles[0])
    np.testing.assert_allclose(out["chi2"][:-1], ref, rtol=2e-3)
    assert out["chi2"][-1] == 0.0
    # the dentin's green absorption shows far more than the enamel's red one (0.40 against 0.036 here)
    assert out["chi2"][0] > 3 * abs(out["chi2"][1])


def test_chi2_does_not_depend_on_the_number_of_passes_and_scales_with_the_capture_noise(problem):
    """The pair estimator is unbiased for any number of passes: the mean of eight 4-pass estimates equals
    a 32-pass estimate on other seeds. A plain square of the mean Jacobian would be biased by Var / passes;
    the unbiased estimates of these two directions measured within 19 % of each other over three seed sets,
    hence the 35 % tolerance. (Directions whose image change is small against the per-pass noise, such as
    sigma_s at fixed sigma_a on this scene, need far more passes for that.)"""
    sc, cap = problem
    names, D = default_directions(sc)
    D = D[[names.index(n) for n in ("tooth0.enamel.sigma_a[2]", "tooth0.enamel.sigma_a[0]")]]

    def chi2(passes, seed, **kw):
        kw = kw or {"noise_variance": 1e-5}
        return capture_sensitivity(sc, cap, D, passes=passes, block=1, max_depth=5, seed=seed, **kw)["chi2"]
    small = np.mean([chi2(4, 100 * i) for i in range(8)], axis=0)
    np.testing.assert_allclose(small, chi2(32, 5000), rtol=0.35)
    # capture_spp: the passes' pooled 1-spp variance over the capture's samples
    a, b = chi2(4, 0, capture_spp=32), chi2(4, 0, capture_spp=64)
    np.testing.assert_allclose(b, 2 * a, rtol=1e-9)


def test_sensitivity_rejects_bad_input(problem):
    sc, cap = problem
    _, D = default_directions(sc)
    with pytest.raises(ValueError, match="columns"):
        capture_sensitivity(sc, cap, D[:, :-1], capture_spp=8)
    with pytest.raises(ValueError, match="passes"):
        capture_sensitivity(sc, cap, D, passes=1, capture_spp=8)
    with pytest.raises(ValueError, match="exactly one"):
        capture_sensitivity(sc, cap, D)


def test_cramer_rao_bound_matches_the_closed_form_and_sees_imitating_directions():
    from material_structures.core.teeth.sensitivity import cramer_rao_std

    # two directions whose image changes are a and b: F = [[a.a, a.b], [a.b, b.b]]
    rng = np.random.default_rng(0)
    a = rng.normal(size=50)
    for mix in (0.0, 0.9, 0.999):
        b = mix * a + np.sqrt(1 - mix**2) * rng.normal(size=50)
        F = np.array([[a @ a, a @ b], [a @ b, b @ b]])
        want = np.sqrt(np.diag(np.linalg.inv(F)))  # independent: the explicit inverse
        np.testing.assert_allclose(cramer_rao_std(F), want, rtol=1e-9)
        # each direction alone would be bounded by 1/sqrt(F_kk); imitation by the other widens it
        assert np.all(cramer_rao_std(F) >= 1 / np.sqrt(np.diag(F)) * (1 - 1e-12))
    F = np.array([[4.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, 1.0]])  # 2 and 3 indistinguishable
    std = cramer_rao_std(F)
    assert std[0] == pytest.approx(0.5) and np.isinf(std[1]) and np.isinf(std[2])


def test_information_off_diagonal_is_the_chi2_of_summed_directions(problem):
    """F_kj is bilinear: chi2(d1 + d2) = F_11 + F_22 + 2 F_12 from the same passes (the bias correction of the
    cross terms must match that of the squares)."""
    sc, cap = problem
    layout = ParamLayout(sc)
    names, D = default_directions(sc, layout)
    d1, d2 = D[names.index("tooth0.dentin.sigma_a[1]")], D[names.index("tooth0.enamel.sigma_a[1]")]
    out = capture_sensitivity(sc, cap, np.vstack([d1, d2, d1 + d2]), passes=4, block=4, noise_variance=2e-5,
                              max_depth=5, seed=3)
    F = out["information"]
    assert F[2, 2] == pytest.approx(F[0, 0] + F[1, 1] + 2 * F[0, 1], rel=1e-9)
    np.testing.assert_allclose(np.diag(F), out["chi2"])
    assert abs(F[0, 1]) > 1e-3 * np.sqrt(F[0, 0] * F[1, 1])  # a real cross term, not zeros
    # a direction that moves a material and a dentin coefficient is the sum of its two parts' image changes
    d3 = D[names.index("tooth0.c[0]")]
    F = capture_sensitivity(sc, cap, np.vstack([d1, d3, d1 + d3]), passes=4, block=4, noise_variance=2e-5,
                            max_depth=5, seed=3)["information"]
    assert F[2, 2] == pytest.approx(F[0, 0] + F[1, 1] + 2 * F[0, 1], rel=1e-9)
    assert F[1, 1] != 0.0 and F[0, 1] != 0.0  # the coefficient's part is in (its sign is the pairs' noise here)


def test_reduced_chi2_is_one_at_the_truth_and_grows_with_the_misfit(problem):
    """A capture rendered from the scene itself at 4 samples per pixel (capture_spp: its noise from the passes):
    the reduced chi-square at that scene is 1 within the estimator's noise (16 passes, 4 x 4 tiles: 0.55-1.32
    over seeds 0-40 of the passes, mean of three 0.7-1.0), and a capture 15 % brighter than the scene renders
    measures 4-6.4. Leaving out the passes' own noise (the pairs i = j) would read about 5 at the truth."""
    sc, cap = problem
    spp = 4
    images = render(sc, cap.cameras, cap.lights, RenderSettings(spp=spp, max_depth=5, seed=99)).images
    names, D = default_directions(sc)
    D = D[[names.index("tooth0.enamel.sigma_a[0]")]]

    def reduced(scale, seed):
        shot = Capture(cap.cameras, cap.lights, scale * images, cap.masks)
        return capture_sensitivity(sc, shot, D, passes=16, block=4, max_depth=5, seed=seed,
                                   capture_spp=spp)["reduced_chi2"]
    at_truth = np.mean([reduced(1.0, 10 * s) for s in range(3)])
    assert 0.5 < at_truth < 1.6
    assert reduced(1.15, 0) > 2.5
    # a capture without images has no residual to measure
    assert np.isnan(capture_sensitivity(sc, cap, D, passes=2, block=2, max_depth=5,
                                        capture_spp=spp)["reduced_chi2"])


def test_lights_in_chunks_give_the_result_of_all_lights_at_once(problem, monkeypatch):
    """A light's image and derivatives do not depend on the lights rendered with it, so a capture whose Jacobian
    would not fit in memory is done a few lights at a time with the same result: one light per chunk here (the
    smile's intervals held 23 GB). Every output, the dentin coefficients' renders included."""
    import material_structures.core.teeth.sensitivity as sensitivity

    sc, cap = problem
    images = render(sc, cap.cameras, cap.lights, RenderSettings(spp=4, max_depth=5, seed=99)).images
    shot = Capture(cap.cameras, cap.lights, images, cap.masks)
    names, D = default_directions(sc)
    D = D[[names.index(n) for n in ("tooth0.enamel.sigma_a[0]", "tooth0.dentin.sigma_s[1]", "tooth0.c[0]")]]

    def run():
        return capture_sensitivity(sc, shot, D, passes=3, block=4, max_depth=5, seed=2, capture_spp=4)
    whole = run()
    monkeypatch.setattr(sensitivity, "CHUNK_BYTES", 1)
    chunked = run()
    assert len(cap.lights) >= 3
    np.testing.assert_allclose(chunked["information"], whole["information"], rtol=1e-9, atol=1e-12)
    assert chunked["noise_variance"] == pytest.approx(whole["noise_variance"], rel=1e-12)
    assert chunked["reduced_chi2"] == pytest.approx(whole["reduced_chi2"], rel=1e-9)
    assert np.abs(whole["information"]).max() > 0
