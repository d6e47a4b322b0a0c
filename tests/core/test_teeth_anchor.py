"""The image control variate of the fit (optimise.Anchor): unbiased, and it removes most pass-A noise."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Capture
from material_structures.core.teeth.compiled_scene import CompiledScene
from material_structures.core.teeth.optimise import FitSettings, anchor_image, fit, iteration_gradient
from material_structures.core.teeth.param_vector import ParamLayout
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import VolumeMaterial

from ._teeth_scenes import down_camera, light, slab_scene

ANCHOR_MAT = ([1.0, 1.3, 1.7], [0.95, 0.9, 0.8])
THETA_MAT = ([1.1, 1.2, 1.9], [0.93, 0.92, 0.75])


def _scenes():
    anchor = slab_scene(*ANCHOR_MAT, floor_albedo=[0.4, 0.3, 0.2])
    theta = anchor.copy()
    theta.teeth[0].enamel = VolumeMaterial(*THETA_MAT, 0.5, -0.3, 0.7)
    return anchor, theta


def _capture(scene, n_lights=3):
    cams = [down_camera(12, 12, fov=6.0)]
    lights = [light((60.0 * np.cos(a), 60.0 * np.sin(a), 200.0)) for a in np.linspace(0, 2 * np.pi, n_lights,
                                                                                      endpoint=False)]
    masks = np.ones((1, 12, 12), dtype=bool)
    img = render(scene, cams, lights, RenderSettings(64, 6, 999)).images
    return Capture(cams, lights, img.astype(np.float32), masks)


def test_anchor_bracket_is_unbiased_and_low_variance():
    """E[C(theta; w | paths at anchor) - C(anchor; w)] = E C(theta) - E C(anchor), checked against
    independent plain renders (sum over the image, 4 standard errors), with far less variance than
    the plain difference at the same spp."""
    anchor, theta = _scenes()
    cap = _capture(anchor)
    cams, lights = cap.cameras, cap.lights
    lay = ParamLayout(anchor)
    brackets, plain = [], []
    for seed in range(24):
        st = RenderSettings(2, 6, 100 + seed)
        a = render(theta, cams, lights, st, compiled=CompiledScene(theta, anchor, layout=lay)).images.sum()
        b = render(anchor, cams, lights, st, compiled=CompiledScene(anchor, layout=lay)).images.sum()
        brackets.append(a - b)
        pa = render(theta, cams, lights, RenderSettings(2, 6, 500 + seed)).images.sum()
        pb = render(anchor, cams, lights, RenderSettings(2, 6, 900 + seed)).images.sum()
        plain.append(pa - pb)
    brackets, plain = np.array(brackets), np.array(plain)
    # reference difference from independent plain renders at 64x the samples (8 seeds x 128 spp)
    ref = np.array([render(theta, cams, lights, RenderSettings(128, 6, 2000 + k)).images.sum()
                    - render(anchor, cams, lights, RenderSettings(128, 6, 3000 + k)).images.sum() for k in range(8)])
    se = np.sqrt(brackets.var(ddof=1) / len(brackets) + ref.var(ddof=1) / len(ref))
    assert abs(brackets.mean() - ref.mean()) < 4.0 * se
    assert abs(ref.mean()) > 10.0 * se  # the two materials really render differently
    assert brackets.var(ddof=1) < 0.1 * plain.var(ddof=1)


def test_anchored_gradient_matches_plain_gradient_in_expectation():
    anchor, theta = _scenes()
    cap = _capture(anchor)
    lay = ParamLayout(theta)
    ids = np.arange(len(cap.lights))
    st = RenderSettings(1, 6)
    cols = [lay.col(f"slab.enamel.{p}") + k for p in ("sigma_t", "albedo") for k in range(3)]
    g_plain, g_anch = [], []
    for seed in range(16):
        g_plain.append(iteration_gradient(theta, cap, ids, st, 10 + seed, lay)[1][cols])
        anc = anchor_image(anchor, cap, 8, 6, 2 * (5000 + seed) + 1, lay)
        g_anch.append(iteration_gradient(theta, cap, ids, st, 3000 + seed, lay, anchor=anc)[1][cols])
    g_plain, g_anch = np.array(g_plain), np.array(g_anch)
    se = np.sqrt(g_plain.var(0, ddof=1) / 16 + g_anch.var(0, ddof=1) / 16)
    assert np.all(np.abs(g_plain.mean(0) - g_anch.mean(0)) < 4.0 * se)
    assert np.median(g_anch.var(0, ddof=1) / g_plain.var(0, ddof=1)) < 0.5


def test_fit_with_anchor_runs_and_rejects_a_gradient_hook_without_anchor():
    anchor, theta = _scenes()
    cap = _capture(anchor, n_lights=2)
    s = FitSettings(iterations=3, spp=1, lights_per_iteration=2, free=("slab.enamel.albedo",), anchor_spp=2,
                    anchor_every=2, lr=0.05)
    best, log = fit(theta, cap, s)
    assert len(log) == 3 and all(np.isfinite(e["loss"]) for e in log)

    def hook(scene, capture, light_ids, st, seed, layout):  # no anchor= parameter
        return iteration_gradient(scene, capture, light_ids, st, seed, layout)

    with pytest.raises(ValueError, match="anchor"):
        fit(theta, cap, s, gradient=hook)


def test_box_filtered_l2_loss_matches_brute_force_and_its_adjoint_matches_differences():
    """l2_loss(block=b): sum over b x b tiles of (tile's masked difference sum)^2 / (tile's masked pixels),
    over the per-pixel normaliser; block 1 is the per-pixel loss; the adjoint is its derivative; the
    camera shares used by the Dask decomposition add up to the whole."""
    from material_structures.core.teeth.optimise import l2_loss, paired_loss

    rng = np.random.default_rng(0)
    img = rng.random((2, 3, 13, 10, 3))
    ref = rng.random(img.shape)
    masks = rng.random((2, 13, 10)) > 0.3
    d = (img - ref) * masks[:, None, :, :, None]
    assert l2_loss(img, ref, masks, 1)[0] == pytest.approx(np.sum(d * d) / (masks.sum() * 9), rel=1e-12)
    brute = 0.0
    for c in range(2):
        for i in range(0, 13, 4):
            for j in range(0, 10, 4):
                n = max(masks[c, i:i + 4, j:j + 4].sum(), 1)
                brute += np.sum(d[c, :, i:i + 4, j:j + 4].sum(axis=(1, 2)) ** 2) / n
    loss, adj = l2_loss(img, ref, masks, 4)
    assert loss == pytest.approx(brute / (masks.sum() * 9), rel=1e-12)
    assert paired_loss(img, img, ref, masks, 4) == pytest.approx(loss, rel=1e-12)
    assert np.all(adj[~np.broadcast_to(masks[:, None, :, :, None], adj.shape)] == 0)
    h = 1e-6
    for idx in [(1, 2, 5, 7, 1), (0, 0, 12, 9, 2), (0, 1, 3, 4, 0)]:
        e = np.zeros_like(img)
        e[idx] = h
        fd = (l2_loss(img + e, ref, masks, 4)[0] - l2_loss(img - e, ref, masks, 4)[0]) / (2 * h)
        assert adj[idx] == pytest.approx(fd, rel=1e-6, abs=1e-12)
    shares = sum(l2_loss(img[c:c + 1], ref[c:c + 1], masks[c:c + 1], 4)[0] * masks[c].sum() / masks.sum()
                 for c in range(2))
    assert shares == pytest.approx(loss, rel=1e-12)
