"""Pass A's own sample count (``image_spp``) and chunk tracing in forked processes (``workers``)."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.optimise import FitSettings, fit, iteration_gradient, l2_loss
from material_structures.core.teeth.param_vector import ParamLayout
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import VolumeMaterial

from ._teeth_scenes import slab_fit_problem


def _problem():
    return slab_fit_problem(12, 64, VolumeMaterial([1.1, 1.2, 1.9], [0.93, 0.92, 0.75], 0.5, -0.3, 0.7))


def test_forked_chunks_give_the_serial_render():
    """Chunks have their own random streams: 3 forked workers return the serial image, gradient,
    Jacobian and counts (up to the order of the floating-point sums)."""
    theta, cap = _problem()
    lay = ParamLayout(theta)
    adj = np.random.default_rng(1).normal(size=(1, 3, 12, 12, 3))
    cols = np.array([lay.col("slab.enamel.sigma_t"), lay.col("slab.enamel.albedo") + 2])
    out = {}
    for workers in (1, 3):
        st = RenderSettings(8, 6, 5, chunk=200, workers=workers)  # 1152 paths: 6 chunks
        out[workers] = (render(theta, cap.cameras, cap.lights, st, adjoint=adj),
                        render(theta, cap.cameras, cap.lights, st, jacobian_cols=cols))
    (a, ja), (b, jb) = out[1], out[3]
    assert np.abs(a.images).max() > 0 and np.abs(a.grad).max() > 0
    np.testing.assert_allclose(b.images, a.images, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(b.grad, a.grad, rtol=1e-10, atol=1e-12 * np.abs(a.grad).max())
    np.testing.assert_allclose(jb.jacobian, ja.jacobian, rtol=1e-12, atol=1e-15)
    for k in ("path_vertices", "shadow_rays", "ray_casts", "camera_paths"):
        assert b.stats[k] == a.stats[k]


def test_image_spp_is_pass_a_sample_count():
    """iteration_gradient(image_spp=k) is the composition of a k-spp pass A (seed 2 s) and an
    ``st.spp`` pass B (seed 2 s + 1) with the L2 adjoint of pass A."""
    theta, cap = _problem()
    lay = ParamLayout(theta)
    ids = np.arange(3)
    ref = cap.images[:, ids].astype(np.float64)
    loss, g, stats = iteration_gradient(theta, cap, ids, RenderSettings(2, 6), 21, lay, image_spp=5)
    a = render(theta, cap.cameras, cap.lights, RenderSettings(5, 6, 42), light_ids=ids)
    _, adj = l2_loss(a.images, ref, cap.masks)
    b = render(theta, cap.cameras, cap.lights, RenderSettings(2, 6, 43), light_ids=ids, adjoint=adj)
    np.testing.assert_allclose(g, b.grad, rtol=1e-12, atol=0)
    assert stats["path_vertices"] == a.stats["path_vertices"] + b.stats["path_vertices"]
    w = np.float64(ref.size)
    assert loss == pytest.approx(float(np.sum((a.images - ref) * (b.images - ref)) / w), rel=1e-12)


def test_image_spp_gradient_is_unbiased_and_less_noisy():
    """Same expectation as the plain 1-spp gradient (4 standard errors) and, since pass A's noise
    dominates the adjoint, much less variance with a 16-spp pass A."""
    theta, cap = _problem()
    lay = ParamLayout(theta)
    ids = np.arange(3)
    st = RenderSettings(1, 6)
    cols = [lay.col(f"slab.enamel.{p}") + k for p in ("sigma_t", "albedo") for k in range(3)]
    g1 = np.array([iteration_gradient(theta, cap, ids, st, 10 + s, lay)[1][cols] for s in range(16)])
    g16 = np.array([iteration_gradient(theta, cap, ids, st, 500 + s, lay, image_spp=16)[1][cols] for s in range(16)])
    se = np.sqrt(g1.var(0, ddof=1) / 16 + g16.var(0, ddof=1) / 16)
    assert np.all(np.abs(g1.mean(0) - g16.mean(0)) < 4.0 * se)
    assert np.median(g16.var(0, ddof=1) / g1.var(0, ddof=1)) < 0.5


def test_fit_with_image_spp_and_workers_matches_one_process():
    theta, cap = _problem()
    base = dict(iterations=3, spp=1, lights_per_iteration=2, free=("slab.enamel.*",), image_spp=3, seed=4)
    a, log_a = fit(theta, cap, FitSettings(**base))
    b, log_b = fit(theta, cap, FitSettings(**base, workers=2))
    np.testing.assert_allclose([e["loss"] for e in log_b], [e["loss"] for e in log_a], rtol=1e-9)
    np.testing.assert_allclose(b.teeth[0].enamel.sigma_t, a.teeth[0].enamel.sigma_t, rtol=1e-9)
    _, log_1 = fit(theta, cap, FitSettings(**{**base, "image_spp": 0}))
    assert log_1[0]["path_vertices"] < log_a[0]["path_vertices"]


@pytest.mark.parametrize("kw, match", [({"image_spp": -1}, "image_spp"), ({"workers": 0}, "workers")])
def test_bad_pass_settings_are_clear_errors(kw, match):
    theta, cap = _problem()
    with pytest.raises(ValueError, match=match):
        fit(theta, cap, FitSettings(iterations=1, **kw))


def test_image_spp_needs_a_gradient_function_that_takes_it():
    theta, cap = _problem()

    def old_gradient(scene, capture, light_ids, st, seed, layout):
        return iteration_gradient(scene, capture, light_ids, st, seed, layout)

    with pytest.raises(ValueError, match="image_spp=0"):
        fit(theta, cap, FitSettings(iterations=1, image_spp=4, loss_block=1), gradient=old_gradient)
    _, log = fit(theta, cap, FitSettings(iterations=1, spp=1, lights_per_iteration=1, image_spp=0, loss_block=1),
                 gradient=old_gradient)
    assert len(log) == 1
