"""Russian roulette (``RenderSettings.max_depth=None``, all bounces): unbiased against a deep fixed-depth
render, the safety cap, and its gradients / Jacobian as exact derivatives of the same estimator.
(The comparison with Mitsuba 3 ``volpath`` with all bounces is in test_teeth_mitsuba.py.)"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from material_structures.core.teeth import path_tracer
from material_structures.core.teeth.gradient_check import fd_check, fd_test_scene
from material_structures.core.teeth.param_vector import ParamLayout, scene_to_vector, vector_to_scene
from material_structures.core.teeth.path_tracer import RenderSettings, render

from ._teeth_scenes import down_camera, light, slab_scene
from .conftest import TRACERS

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`


def _slab():
    """A high-albedo slab (optical depth 4-6) over a Lambertian floor, all pixels on the slab, 2 lights."""
    sc = slab_scene([2.0, 2.5, 3.0], [0.95, 0.9, 0.8], thickness=2.0, a_t=0.9, floor_albedo=[0.5, 0.4, 0.3])
    return sc, [down_camera(12, 12, fov=6.0)], [light((60.0, 20.0, 200.0)), light((-80.0, -40.0, 150.0))]


@functools.cache
def _deep_render(spp: int, reference: bool):
    sc, cams, lights = _slab()
    return render(sc, cams, lights, RenderSettings(spp=spp, max_depth=200, seed=21), reference=reference)


def _paired_z(rr_depth: int, spp: int = 48, reference: bool = False) -> tuple[np.ndarray, np.ndarray, dict, dict]:
    """(mean difference roulette - depth 200 per channel, its standard error, roulette stats, depth-200 stats).

    Every (pixel, light) value of the two renders is an independent estimate (own random numbers), and
    under "roulette is unbiased" both have the same expectation per pixel; so the per-pixel differences
    d_p are independent with mean 0, and the standard error of their mean is std(d_p) / sqrt(n) (pixel
    to pixel variation of the image itself does not enter)."""
    sc, cams, lights = _slab()
    deep = _deep_render(spp, reference)
    rr = render(sc, cams, lights, RenderSettings(spp=spp, max_depth=None, seed=22, rr_depth=rr_depth),
                reference=reference)
    d = (rr.images - deep.images).reshape(-1, 3)
    return d.mean(axis=0), d.std(axis=0, ddof=1) / np.sqrt(len(d)), rr.stats, deep.stats


@pytest.mark.parametrize("rr_depth", [2, 10])
def test_roulette_is_unbiased_against_a_deep_fixed_depth_render(rr_depth, tracer):
    """Mean over pixels of the roulette render = that of a max_depth 200 render (0.95^200 ~ 4e-5 of the
    light left out) within 4 standard errors (+ 1e-9), per channel. Measured: |diff| / SE 1.26, 0.97,
    0.52 (rr_depth 2) and 0.18, 0.05, 0.84 (rr_depth 10), the SE 1.0-1.3 % of the mean; roulette traced
    29 % (rr_depth 2) / 37 % (10) of the depth-200 render's vertices."""
    diff, se, st_rr, st_deep = _paired_z(rr_depth, reference=tracer.reference)
    assert st_rr["capped_paths"] == 0
    assert st_rr["path_vertices"] < 0.7 * st_deep["path_vertices"]  # roulette did end paths early
    assert np.all(np.abs(diff) < 4 * se + 1e-9), (diff, se, diff / se)


@pytest.mark.parametrize("rr_depth", [2, 10])
def test_roulette_without_the_survival_weight_is_caught(monkeypatch, rr_depth):
    """The same check detects a roulette that forgets to divide the survivors by q (biased low). Measured
    diff / SE -50, -47, -31 (rr_depth 2: 46 / 41 / 31 % too dark) and -22, -14, -4.7 (rr_depth 10:
    18 / 12 / 5 % too dark). (On the numpy reference, whose roulette can be replaced from Python; the
    compiled tracer passes the same unbiasedness check above.)"""
    real = path_tracer._roulette

    def no_weight(u, logfs, logp):
        live, log_q = real(u, logfs, logp)
        return live, np.zeros_like(log_q)

    monkeypatch.setattr(path_tracer, "_roulette", no_weight)
    diff, se, _, _ = _paired_z(rr_depth, reference=True)
    assert np.all(diff < 0), (diff, se, diff / se)  # too dark in every channel ...
    assert not np.all(np.abs(diff) < 4 * se + 1e-9), (diff, se, diff / se)  # ... and the check above fails


def test_safety_cap_is_a_fixed_depth(monkeypatch):
    """With the cap below the roulette start, max_depth=None is exactly the fixed-depth estimator at the
    cap (the same random numbers: roulette draws its own numbers only once it starts), and the paths
    the cap stopped are counted. (Numpy reference: the compiled tracer's cap is a compile-time constant.)"""
    sc, cams, lights = _slab()
    monkeypatch.setattr(path_tracer, "MAX_PATH_VERTICES", 4)
    capped = render(sc, cams, lights, RenderSettings(spp=2, max_depth=None, seed=5, rr_depth=100), reference=True)
    fixed = render(sc, cams, lights, RenderSettings(spp=2, max_depth=4, seed=5), reference=True)
    np.testing.assert_array_equal(capped.images, fixed.images)
    assert capped.stats["capped_paths"] > 0
    assert "capped_paths" not in fixed.stats


def _one_component_of_each_kind(layout) -> list[int]:
    """A component of every parameter (enamel.sigma_t, ..., cavity.albedo), the k-th parameter's k-th
    channel (mod its size): 19 of fd_test_scene's 48."""
    kinds: dict[str, list[int]] = {}
    for i, name in enumerate(layout.component_names()):
        kinds.setdefault(name.split("[")[0], []).append(i)
    return [comps[k % len(comps)] for k, comps in enumerate(kinds.values())]


def test_roulette_gradient_of_the_reference_tracer_matches_central_differences_of_each_kind():
    """``test_roulette_gradient_matches_central_differences[reference]`` (nightly) on one component of every
    parameter: the numpy tracer's 97 renders were 14 s. The same estimator, renders and 5 % bound."""
    comps = _one_component_of_each_kind(ParamLayout(fd_test_scene()[0]))
    assert len(comps) == 19
    layout, g, fd = fd_check(max_depth=None, rr_depth=2, reference=True, components=comps)
    names = [layout.component_names()[p] for p in comps]
    scale = np.max(np.abs(fd))
    assert np.all(np.abs(fd) > 1e-7 * scale), [n for n, f in zip(names, fd, strict=True) if abs(f) <= 1e-7 * scale]
    rel = np.abs(g - fd) / np.maximum(np.abs(fd), 1e-12)
    assert np.max(rel) < 0.05, {n: r for n, r in zip(names, rel, strict=True) if r >= 0.05}


# the numpy reference tracer's check of all 48 components is nightly (14 s); `make test` checks one of
# each kind (test_roulette_gradient_of_the_reference_tracer_matches_central_differences_of_each_kind)
@pytest.mark.parametrize("tracer", [TRACERS[0], pytest.param(TRACERS[1], marks=pytest.mark.slow)], indirect=True,
                         ids=[t.name for t in TRACERS])
def test_roulette_gradient_matches_central_differences(tracer):
    """Short counterpart in `make test` of [reference]:
    test_roulette_gradient_of_the_reference_tracer_matches_central_differences_of_each_kind.
    Every gradient component with roulette on (from vertex 2, so that most paths meet it) against the
    central difference of the same estimator (``fd_check``, common random numbers): <= 5 % (measured:
    worst 3.7e-8). With q computed from the evaluation-scene throughput instead of theta_0's, the worst
    component is off by 227 % (median 3 %)."""
    layout, g, fd = fd_check(max_depth=None, rr_depth=2, reference=tracer.reference)
    names = layout.component_names()
    scale = np.max(np.abs(fd))
    assert np.all(np.abs(fd) > 1e-7 * scale), [n for n, f in zip(names, fd, strict=True) if abs(f) <= 1e-7 * scale]
    rel = np.abs(g - fd) / np.maximum(np.abs(fd), 1e-12)
    assert np.max(rel) < 0.05, {n: r for n, r in zip(names, rel, strict=True) if r >= 0.05}


def test_roulette_jacobian_matches_reverse_mode_and_per_pixel_differences(tracer):
    """Forward mode (``jacobian_cols``) with roulette: contracted with an adjoint it equals the reverse-mode
    gradient of the same paths (to rounding), and a subset of its columns matches per-pixel central
    differences of the same estimator (CRN) within 5 % (relative Frobenius norm). Measured: 3e-16 and
    2.3e-9; with q from the evaluation-scene throughput the worst column is off by 166 %."""
    sc, cams, lights = fd_test_scene()
    layout = ParamLayout(sc)
    st = RenderSettings(spp=2, max_depth=None, seed=11, rr_depth=2)
    h_, w_ = cams[0].height, cams[0].width
    pixels = [np.arange(0, h_ * w_, 2)]
    cols = np.arange(layout.size)
    res = render(sc, cams, lights, st, pixels=pixels, jacobian_cols=cols, reference=tracer.reference)
    jac = res.jacobian
    adj = np.random.default_rng(5).random((1, len(lights), h_, w_, 3))
    g = render(sc, cams, lights, st, pixels=pixels, adjoint=adj, reference=tracer.reference).grad
    a = adj[0].reshape(len(lights), -1, 3)[:, pixels[0]].transpose(1, 0, 2)
    np.testing.assert_allclose(np.einsum("nlc,nlcp->p", a, jac), g, rtol=1e-9, atol=1e-12 * np.abs(g).max())
    x0 = scene_to_vector(sc, layout)
    worst = 0.0
    for p in range(0, layout.size, 4):
        h = 1e-5 * max(abs(x0[p]), 0.05)
        imgs = []
        for sgn in (1, -1):
            x = x0.copy()
            x[p] += sgn * h
            im = render(vector_to_scene(sc, x, layout), cams, lights, st, pixels=pixels, sampling_scene=sc,
                        reference=tracer.reference).images
            imgs.append(im[0].reshape(len(lights), -1, 3)[:, pixels[0]].transpose(1, 0, 2))
        fd = (imgs[0] - imgs[1]) / (2 * h)
        assert np.linalg.norm(fd) > 0, layout.component_names()[p]
        worst = max(worst, np.linalg.norm(jac[..., p] - fd) / np.linalg.norm(fd))
    assert worst < 0.05, worst
