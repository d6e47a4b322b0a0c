"""Adam (thesis eq. 2.38-2.39) as the teeth fit uses it."""

import numpy as np

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

