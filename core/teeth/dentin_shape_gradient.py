"""The fit's gradient with respect to the dentin shape coefficients c (eq. 5.14): a central difference
along a random direction, with common random numbers (simultaneous perturbation).

The loss gradient of a coefficient is g_j = sum over pixels of adjoint x dC / dc_j, with the adjoint
d rho / d C of pass A (``fit_gradient``). With a random direction u (every u_j = +-1 with probability
1/2) and two renders that draw the same random numbers w (same seed and pixels),

    D = sum adjoint x (C(c + h u; w) - C(c - h u; w)) / (2 h),     g_hat_j = D u_j,

E[g_hat_j] = g_j + O(h^2), since E[u_i u_j] = 0 for i != j (Spall's simultaneous perturbation). A path
that never comes near a dentin boundary, or crosses one where the boundary's move does not change its
sampling decisions, contributes the same to both renders and cancels. Two renders serve every
coefficient of every tooth; a coordinate's variance is that of the one difference plus the other
coordinates' squared gradients (small near the optimum). h = 0.05 (the coefficients' range is 1.6)
keeps the O(h^2) bias far below the fit's tolerance of 0.05.

Why not the path-space derivative that the tracer gives for every other parameter (eq. 5.19-5.32)? The
thesis builds it on the smooth blend l(q) of the distance q to the dentin surface (eq. 5.15), and there it
holds: on a one-tooth test scene with the blend spread 0.8 mm its mean agreed with independent renders of
c +- 0.3 (-7.7 +- 1.3 against -8.9 +- 0.9). A photograph's boundary, and a Mitsuba capture's, is sharp,
and so is the fitted scene's then. There the path-space derivative is both noisy and wrong: at a 1e-5 mm
spread it gave -3.3 +- 0.8 and -2.05 +- 0.12 for two coefficients where independent renders give
-0.28 +- 0.04 and -0.07 +- 0.04 (its reweighted finite differences, which the gradient tests compare it
with, agree with it, so those tests cannot see this); these differences gave -0.25 +- 0.07 and
0.07 +- 0.09. On the Mitsuba acceptance capture at the truth (4 independent 16-spp passes of all 54
lights, 8 x 8 tiles) the product of two passes' path-space c columns was at most 0.1 % of one pass's
square, most of them negative (pure noise), against 13-32 % for central differences with common random
numbers at the same sample count; 0.1 off the truth, the fit's per-iteration c gradient (6 lights, 4 spp) had a 10-60x
lower standard deviation by differences (docs/teeth-fit.md).
"""

from __future__ import annotations

import numpy as np

from .capture import Camera, PointLight
from .compiled_scene import CompiledScene
from .param_vector import RANGES, ParamLayout, scene_to_vector, vector_to_scene
from .path_tracer import RenderSettings, render
from .scene import TeethScene

SHAPE_STEP = 0.05  # h, in coefficient units (the range is RANGES["c"])


def shape_columns(layout: ParamLayout) -> np.ndarray:
    """Indices of every tooth's dentin coefficients in the physical parameter vector."""
    return np.flatnonzero(layout.kinds() == "c")


def shape_gradient(scene: TeethScene, cameras: list[Camera], lights: list[PointLight], light_ids, pixels: list,
                   adjoint: np.ndarray, settings: RenderSettings, layout: ParamLayout, direction: np.ndarray,
                   step: float = SHAPE_STEP) -> np.ndarray:
    """The estimate g_hat (module docstring) for every dentin coefficient, shape (k,) in the order of
    :func:`shape_columns`, along ``direction`` (k entries of +-1). ``adjoint`` is (n_cam,
    n_selected_lights, H, W, 3); both renders use ``settings`` (its seed) unchanged, so they share their
    random numbers. Coefficients within ``step`` of a bound of their range are differenced about the
    nearest point ``step`` inside it."""
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step}")
    cols = shape_columns(layout)
    u = np.asarray(direction, dtype=np.float64)
    if u.shape != (len(cols),) or not np.all(np.abs(u) == 1.0):
        raise ValueError(f"direction must hold {len(cols)} entries of +-1")
    if len(cols) == 0:
        return np.zeros(0)
    images = [render(sc, cameras, lights, settings, pixels=pixels, light_ids=light_ids,
                     compiled=CompiledScene(sc, layout=layout)).images
              for sc in shape_ends(scene, layout, step * u)]
    d = float(np.sum(adjoint * (images[0] - images[1]))) / (2.0 * step)
    return d * u


def shape_ends(scene: TeethScene, layout: ParamLayout, dc: np.ndarray) -> tuple[TeethScene, TeethScene]:
    """The two scenes of a central difference of the dentin coefficients by ``dc`` (one entry per
    :func:`shape_columns`): c + dc and c - dc about the nearest centre that keeps both ends in range."""
    cols = shape_columns(layout)
    x = scene_to_vector(scene, layout)
    lo, hi = RANGES["c"]
    centre = np.clip(x[cols], lo + np.abs(dc), hi - np.abs(dc))
    ends = []
    for sign in (1.0, -1.0):
        xs = x.copy()
        xs[cols] = centre + sign * dc
        ends.append(vector_to_scene(scene, xs, layout))
    return ends[0], ends[1]


def random_direction(seed: int, k: int) -> np.ndarray:
    """The +-1 direction of an iteration's shape gradient, from its seed (the same on every worker)."""
    return np.where(np.random.default_rng([seed, 0x5A]).random(k) < 0.5, -1.0, 1.0)
