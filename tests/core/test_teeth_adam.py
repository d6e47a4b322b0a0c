"""Adam (thesis eq. 2.38-2.39) as the teeth fit uses it."""

import numpy as np
import pytest

from material_structures.core.teeth.optimise import Adam, FitSettings


def test_adam_step_matches_eq_2_38_2_39():
    rng = np.random.default_rng(3)
    gs = rng.normal(size=(5, 4))
    opt = Adam(0.1, 0.9, 0.999, 1e-16)
    y = np.zeros(4)
    m = v = np.zeros(4)
    ref = np.zeros(4)
    for n, g in enumerate(gs, start=1):
        y = opt.step(y, g)
        m = 0.9 * m + 0.1 * g
        v = 0.999 * v + 0.001 * g * g
        ref = ref - 0.1 * (m / (1 - 0.9**n)) / np.sqrt(v / (1 - 0.999**n) + 1e-16)
    np.testing.assert_allclose(y, ref, rtol=1e-12, atol=0)


def test_default_epsilon_keeps_the_step_independent_of_the_gradient_scale():
    """The acceptance fit's gradients are 1e-6 to 1e-5 near the optimum (the loss is a per-pixel mean);
    eq. 2.39's epsilon must stay small against v there, or Adam degrades to plain gradient descent with
    the step lr / sqrt(eps) (the default was 1e-8 once: sqrt 1e-4, ten to a hundred times the gradients)."""
    rng = np.random.default_rng(4)
    gs = rng.normal(size=(20, 6))
    s = FitSettings()
    steps = {}
    for scale in (1.0, 1e-6):
        opt = Adam(s.lr)  # Adam's own b1, b2, eps (adam.py)
        y = np.zeros(6)
        for g in gs:
            y = opt.step(y, scale * g)
        steps[scale] = y
    np.testing.assert_allclose(steps[1e-6], steps[1.0], rtol=1e-3)


def test_iterates_past_zero_albedo_keep_a_finite_gradient():
    """Normalised Adam steps (about lr each) can carry an albedo or the cavity's rho below 0 in the
    optimiser domain; the clamp keeps them positive, so the log-space path weights and their
    derivatives stay finite (rho clamped to 0 once gave inf x 0 = NaN parameters)."""
    from material_structures.core.teeth.capture import Capture
    from material_structures.core.teeth.optimise import iteration_gradient
    from material_structures.core.teeth.param_vector import (
        ParamLayout,
        from_optimiser,
        scene_to_vector,
        to_optimiser,
        vector_to_scene,
    )
    from material_structures.core.teeth.path_tracer import RenderSettings, render

    from ._teeth_scenes import down_camera, light, slab_scene

    scene = slab_scene([1.0, 1.3, 1.7], [0.95, 0.9, 0.8], floor_albedo=[0.4, 0.3, 0.2])
    lay = ParamLayout(scene)
    cams, lights = [down_camera(8, 8, fov=6.0)], [light((40.0, 0.0, 200.0))]
    img = render(scene, cams, lights, RenderSettings(4, 6, 1)).images
    cap = Capture(cams, lights, img.astype(np.float32), np.ones((1, 8, 8), dtype=bool))
    y = to_optimiser(scene_to_vector(scene, lay), lay)
    y[lay.slice("cavity.albedo")] = -0.05  # rho is stepped as is: below 0
    y[lay.slice("slab.enamel.albedo")] = 0.3  # kappa > 0: albedo 1 - 10^0.3 < 0
    x = from_optimiser(y, lay)
    assert np.all(x[lay.slice("cavity.albedo")] > 0) and np.all(x[lay.slice("slab.enamel.albedo")] > 0)
    loss, g, _ = iteration_gradient(vector_to_scene(scene, x, lay), cap, np.array([0]), RenderSettings(2, 6, 3), 5,
                                    lay)
    assert np.isfinite(loss) and np.all(np.isfinite(g))
    # the floor is seen and its rho matters: the derivative is a number, not 0 by accident
    assert np.any(g[lay.slice("cavity.albedo")] != 0)


def test_a_parameter_at_its_bound_leaves_it_as_soon_as_adam_turns():
    """The steps are projected onto the valid ranges. A gradient that pushes beta (range [0, 1]) up for 6
    steps of lr 0.04 from 0.9, then down, with |g| constant: Adam's normalised step is exactly
    lr m_hat, m_hat = -1 while pushed (beta reaches 1 at the 3rd step), and after the turn m_hat = -0.616,
    -0.333, -0.115, then +0.056 (closed form from B1 = 0.9). Projected, beta sits at 1 and leaves it at
    the 4th step after the turn: 1 - 0.04 x 0.056. Unprojected, the variable would be at 1.14 + 0.04 x
    1.064 and beta held at 1 for four more steps."""
    from material_structures.core.teeth.capture import Capture
    from material_structures.core.teeth.optimise import fit
    from material_structures.core.teeth.param_vector import ParamLayout

    from ._teeth_scenes import down_camera, light, slab_scene

    scene = slab_scene([1.0, 1.3, 1.7], [0.95, 0.9, 0.8], beta=0.9)
    cams, lights = [down_camera(4, 4, fov=6.0)], [light((40.0, 0.0, 200.0))]
    cap = Capture(cams, lights, np.zeros((1, 1, 4, 4, 3), dtype=np.float32), np.ones((1, 4, 4), dtype=bool))
    col = ParamLayout(scene).col("slab.enamel.beta")

    def pushed(scene, capture, light_ids, st, seed, layout):  # seed = iteration (fit seed 0, first phase)
        g = np.zeros(layout.size)
        g[col] = -1e-6 if seed < 6 else 1e-6
        return 1.0, g, {}

    s = FitSettings(iterations=11, free=("slab.enamel.beta",), optimiser="adam", lr=0.04, lr_decay=0.0,
                    image_spp=0, loss_block=1, held_out_lights=0, average_tail=0.0)
    betas: list = []
    fit(scene, cap, s, gradient=pushed, callback=lambda e, sc: betas.append(sc.teeth[0].enamel.beta))
    # betas[k]: after k steps
    np.testing.assert_allclose(betas[:3], [0.9, 0.94, 0.98], rtol=1e-12)
    assert betas[3:10] == [1.0] * 7
    m_hat = (0.9 * (0.9 * (0.9 * (0.9 * -(1 - 0.9**6) + 0.1) + 0.1) + 0.1) + 0.1) / (1 - 0.9**10)
    assert m_hat == pytest.approx(0.0560, abs=1e-4)
    assert betas[10] == pytest.approx(1.0 - 0.04 * m_hat, rel=1e-9)
