"""One stochastic loss and gradient of the fit: two independently seeded rendering passes (thesis
Sec. 5.6, "two independently seeded rendering passes").

Pass A renders the image C_A of the iteration's lights (forward only, ``image_spp`` samples) and forms
the adjoint d rho / d C = 2 (C_A - C_ref) / M (``fit_loss.l2_loss``); pass B traces the gradient of
sum(adjoint x C) with an independent seed (``spp`` samples) and its image C_B. The loss estimate is
mean((C_A - C_ref)(C_B - C_ref)) (``fit_loss.paired_loss``), free of the Monte Carlo variance bias.
The dentin coefficients' entries of the gradient come instead from two more renders at pass B's seed
and samples, a central difference along a random direction with common random numbers
(``dentin_shape_gradient``): their path-space derivative is almost pure noise at a sharp boundary.

``pass_pair`` is the estimator for any set of cameras; the fit calls it through ``iteration_gradient``
(all cameras), ``scaleout.teeth`` once per camera on Dask workers (with the camera's share of the
global normaliser), so both run the same code.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .capture import Capture
from .compiled_scene import CompiledScene
from .dentin_shape_gradient import random_direction, shape_columns, shape_gradient
from .fit_loss import l2_loss, paired_loss
from .param_vector import ParamLayout
from .path_tracer import RenderSettings, render
from .scene import TeethScene


def pass_pair(scene: TeethScene, capture: Capture, cameras: list[int], light_ids, st: RenderSettings, seed_a: int,
              seed_b: int, layout: ParamLayout, loss_block: int = 1, image_spp: int = 0,
              share: float = 1.0, shape: bool = True, rows: tuple[int, int] | None = None,
              direction_seed: int | None = None) -> tuple[float, np.ndarray, dict]:
    """Loss estimate, physical gradient and statistics of ``cameras`` (indices into the capture) for
    ``light_ids``; ``share`` scales loss and adjoint (a camera's share of a loss over more cameras).
    ``shape``: estimate the dentin coefficients' entries (two more renders); False leaves them 0.
    ``rows``: only the masked pixels of image rows [rows[0], rows[1]) (a band whose edges are multiples of
    ``loss_block``: the band's loss is its share of the whole image's). ``direction_seed``: the seed of the dentin
    coefficients' random direction (default ``seed_b``); the bands of one iteration share it, so that a worker
    refits the two shifted dentins once for all its bands."""
    if image_spp < 0:
        raise ValueError(f"image_spp must be >= 0 (0 = st.spp), got {image_spp}")
    cams = [capture.cameras[c] for c in cameras]
    masks = capture.masks[cameras]
    if rows is not None:
        if rows[0] % loss_block or (rows[1] % loss_block and rows[1] < masks.shape[1]):
            raise ValueError(f"a band's rows {rows} must start and end on the loss's {loss_block}-pixel blocks")
        masks = masks.copy()
        masks[:, :rows[0]] = False
        masks[:, rows[1]:] = False
    pixels = [np.flatnonzero(m.ravel()) for m in masks]
    cs = CompiledScene(scene, layout=layout)
    ref = capture.images[np.ix_(cameras, np.asarray(light_ids))].astype(np.float64)
    sa = replace(st, spp=image_spp or st.spp, seed=seed_a, jitter=True)
    t0 = time.perf_counter()
    ra = render(scene, cams, capture.lights, sa, pixels=pixels, light_ids=light_ids, compiled=cs)
    seconds_a = time.perf_counter() - t0
    loss_a, adj = l2_loss(ra.images, ref, masks, loss_block)
    sb = replace(st, seed=seed_b, jitter=True)
    rb = render(scene, cams, capture.lights, sb, pixels=pixels, light_ids=light_ids, adjoint=adj * share,
                compiled=cs)
    loss = paired_loss(ra.images, rb.images, ref, masks, loss_block) * share
    grad = rb.grad
    cols = shape_columns(layout)
    t0 = time.perf_counter()
    if len(cols):
        grad = grad.copy()
        grad[cols] = 0.0
        if shape:
            grad[cols] = shape_gradient(scene, cams, capture.lights, light_ids, pixels, adj * share, sb, layout,
                                        random_direction(seed_b if direction_seed is None else direction_seed,
                                                         len(cols)))
    stats = {"path_vertices": ra.stats["path_vertices"] + rb.stats["path_vertices"],
             "render_seconds": seconds_a, "gradient_seconds": rb.stats["seconds"],
             "shape_seconds": time.perf_counter() - t0, "loss_single_pass": loss_a * share}
    return loss, grad, stats


def iteration_gradient(scene: TeethScene, capture: Capture, light_ids: np.ndarray, st: RenderSettings,
                       seed: int, layout: ParamLayout, loss_block: int = 1,
                       image_spp: int = 0, shape: bool = True) -> tuple[float, np.ndarray, dict]:
    """The fit's loss + gradient of one iteration over every camera (seeds 2 seed and 2 seed + 1)."""
    return pass_pair(scene, capture, list(range(len(capture.cameras))), light_ids, st, 2 * seed, 2 * seed + 1,
                     layout, loss_block, image_spp, shape=shape)
