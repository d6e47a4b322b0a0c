"""Finite-difference check of the per-path analytic gradients (used by the tests and the benchmark).

The reference is the central difference of the *same estimator* with common random numbers: paths
sampled with theta_0, contribution f(theta_0 +- h e_p) / p(theta_0) (``sampling_scene``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .capture import Camera, PointLight
from .param_vector import ParamLayout, scene_to_vector, vector_to_scene
from .path_tracer import RenderSettings, render
from .scene import TeethScene
from .synthetic import make_scene, scene_target


def fd_test_scene() -> tuple[TeethScene, list[Camera], list[PointLight]]:
    """One tooth (2 x 2 a_t texture), gums and cavity, a 14 x 12 camera and three lights."""
    sc = make_scene(n_teeth=1, resolution=14)
    t = sc.teeth[0]
    t.a_t = np.array([[[0.9, 0.85, 0.8], [0.95, 0.9, 0.85]], [[0.8, 0.9, 0.95], [0.7, 0.75, 0.9]]])
    # the dentin's g1 off the enamel's, inside the literature range the fit keeps it to (its ends clamp a difference)
    t.dentin.g1, t.enamel.g2 = 0.35, -0.25
    sc.blend_spread = 0.8  # wider blend so that the sigmoid terms (eq. 5.19, 5.21) matter
    tgt = scene_target(sc)
    cam = Camera.look_at(tgt + [60.0, 280.0, 40.0], tgt, (0, 0, 1), 4.2, 14, 12)
    lights = [PointLight(tgt + 1000 * np.array(v) / np.linalg.norm(v), [1.0e6, 1.2e6, 0.9e6])
              for v in ([0.2, 1.0, 0.3], [-0.8, 0.6, 0.1], [0.1, 0.4, -0.9])]
    return sc, [cam], lights


def fd_check(spp: int = 3, max_depth: int | None = 5, seed: int = 7, rel_step: float = 1e-5,
             rr_depth: int | None = None, reference: bool = False,
             components: Sequence[int] | None = None) -> tuple[ParamLayout, np.ndarray, np.ndarray]:
    """Returns (layout, analytic gradient, central-difference gradient) of sum(adjoint * C); with
    ``components``, both only at those indices of the layout (in that order).

    ``max_depth=None`` checks the all-bounce estimator with Russian roulette (from vertex ``rr_depth``,
    default ``RenderSettings``'s): its survival probabilities are evaluated at theta_0 (part of
    p(path; theta_0)), so the renders at theta_0 +- h make the same roulette decisions and the central
    difference is that of the same estimator. ``reference``: check ``render``'s numpy reference tracer
    instead of the compiled one."""
    sc, cams, lights = fd_test_scene()
    layout = ParamLayout(sc)
    x0 = scene_to_vector(sc, layout)
    st = RenderSettings(spp=spp, max_depth=max_depth, seed=seed)
    if rr_depth is not None:
        st.rr_depth = rr_depth
    adj = np.random.default_rng(3).random((1, len(lights), cams[0].height, cams[0].width, 3))
    g = render(sc, cams, lights, st, adjoint=adj, reference=reference).grad
    comps = list(range(layout.size)) if components is None else list(components)
    fd = np.zeros(len(comps))
    for i, p in enumerate(comps):
        h = rel_step * max(abs(x0[p]), 0.05)
        vals = []
        for sgn in (1, -1):
            x = x0.copy()
            x[p] += sgn * h
            img = render(vector_to_scene(sc, x, layout), cams, lights, st, sampling_scene=sc,
                         reference=reference).images
            vals.append(np.sum(adj * img))
        fd[i] = (vals[0] - vals[1]) / (2 * h)
    return layout, g[comps], fd
