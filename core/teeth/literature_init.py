"""Initialisation by a literature-table search (thesis Sec. 5.7).

The thesis tabulates the three-dimensional domain (albedo, density, phase anisotropy) spanned by the
values reported for enamel and dentin [Spitzer and ten Bosch 1975; Fried et al. 1995; Pop-Ciutrila
et al. 2015] (50000 points), renders a virtual *homogeneous* tooth for each point, compares it with
the masked measurements by a scale-invariant error and, per colour channel, starts from the point
with the smallest error. Here the table is a coarse log-spaced grid over the same span (sigma_t
0.3-30 / mm, albedo 0.5-0.999, g 0.3-0.9; a few hundred points), evaluated on a subset of lights with
two independently seeded renders per point and tile sums of the masked pixels, so that the errors
are not biased by the renders' Monte Carlo noise (see ``literature_start``).

Unbiased is not enough: at 1 sample per pixel the paired error of one point has a standard deviation
of about 0.04 on the Mitsuba acceptance capture, more than the spread of the errors of the good points
(0.006-0.05), and the smallest of 240 such estimates is the point with the most negative noise (the
winner's curse): the search chose g 0.9, sigma_t 3.9-6.5 / mm with errors of -0.03 to -0.07, points
whose errors at 8 samples per pixel are 0.013-0.043, and fits started there ended 42 % above the
truth's loss, in another valley. So the best points of each g and channel are rendered again, with new
seeds, more samples and other lights, and the choice is made mostly on those errors (weighted by samples).

Nor does the search tell g: at 8 samples per pixel on every table point, the best errors of g 0.3, 0.6
and 0.9 were within 0.003 of each other in every channel (a homogeneous tooth is not the capture's
enamel and dentin), and the fit keeps the valley its start's g puts it in. ``literature_starts`` gives
one start per g, and the fit starts from the one of g ``START_G`` = 0.6, the middle of the literature's range.
Measured on the Mitsuba captures of ``bench teeth-extrapolation`` (novel camera and lights, 512 spp): short trial
fits from every start, the best trial loss going on (``start_trials``, the default before), chose g 0.3 on two of
the three truths and predicted translucent-forward (truth g1 0.78 / 0.65) 12.8 % off at the worst light; from g
0.6, 4.3 % (the truth against itself: 4.8 %), dense-diffuse (truth g1 0.35 / 0.3) 6.0 % against the trials' 5.2 %
(docs/teeth-fit.md, "The fit starts at g 0.6"). The trials' losses after 30 iterations say which start converges
fastest, not which extrapolates: the capture cannot tell the valleys apart.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import UserError
from .capture import Capture
from .compiled_scene import CompiledScene
from .param_vector import TOOTH_G1_RANGE
from .parameterisation import albedo_from_kappa
from .path_tracer import RenderSettings, render, traced_tile_sums, traced_tiles, traced_values
from .scene import TeethScene, VolumeMaterial

SIGMA_RANGE_MM = (0.3, 30.0)
REFINE_KEEP = 3  # table points per g and channel rendered again (``literature_starts``)
REFINE_LIGHTS = 12
ALBEDO_RANGE = (0.5, 0.999)
G_VALUES = (TOOTH_G1_RANGE[0], 0.6, TOOTH_G1_RANGE[1])
START_G = 0.6  # the g the fit starts from (module docstring)


def literature_table(n_sigma: int = 10, n_albedo: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Grid of (sigma_t, albedo) points (n, 2): log-spaced sigma, albedo uniform in kappa (eq. 5.22)."""
    sig = np.geomspace(*SIGMA_RANGE_MM, n_sigma)
    kap = np.linspace(np.log10(1 - ALBEDO_RANGE[0]), np.log10(1 - ALBEDO_RANGE[1]), n_albedo)
    s, k = np.meshgrid(sig, kap, indexing="ij")
    return np.stack([s.ravel(), albedo_from_kappa(k.ravel())], axis=1), np.asarray(G_VALUES)


def scale_invariant_error(render_vals: np.ndarray, ref_vals: np.ndarray) -> float:
    """min_s |s r - f|^2 / |f|^2 = 1 - (r . f)^2 / (|r|^2 |f|^2)."""
    rr, ff, rf = np.dot(render_vals, render_vals), np.dot(ref_vals, ref_vals), np.dot(render_vals, ref_vals)
    if rr <= 0 or ff <= 0:
        return 1.0
    return float(1.0 - rf * rf / (rr * ff))


def paired_table_errors(r1: np.ndarray, r2: np.ndarray, f: np.ndarray, scale_invariant: bool = True) -> np.ndarray:
    """Errors of rendered values against the reference ``f`` (n,), per column of ``r1``, ``r2`` (n, k),
    two renders of the same table points with independent seeds.

    A render's Monte Carlo noise adds its variance to |r|^2, which would favour table points whose
    renders are less noisy; products of the two independent renders have no such bias:
    scale-invariant 1 - (r1 . f)(r2 . f) / ((r1 . r2) |f|^2) (the thesis' error, up to that bias), or
    absolute (|f|^2 - (r1 + r2) . f + r1 . r2) / |f|^2 = |E r - f|^2 / |f|^2 for calibrated captures."""
    ff = float(np.dot(f, f))
    if ff <= 0:
        return np.ones(r1.shape[1])
    f1, f2, r12 = f @ r1, f @ r2, np.einsum("nk,nk->k", r1, r2)
    if scale_invariant:
        return np.where(r12 > 0, 1.0 - f1 * f2 / np.where(r12 > 0, r12, 1.0) / ff, 1.0)
    return (ff - f1 - f2 + r12) / ff


def _tile_sums(values: np.ndarray, tile_of: np.ndarray, n_tiles: int) -> np.ndarray:
    """(n_light, n_rows, 3) traced values summed per tile (``path_tracer.traced_tiles``): (n_light * n_tiles, 3)."""
    return traced_tile_sums(values, tile_of, n_tiles).reshape(-1, 3)


# the model's own surface transmission (the literature tabulates it no more than the second phase lobe,
# which comes from VolumeMaterial's defaults): the start takes it, not the scene's, so that a synthetic
# capture's scene.json (its ground truth) leaks nothing into the start but the geometry and the surroundings
MODEL_A_T = 1.0


def _homogeneous(scene: TeethScene, mat: VolumeMaterial) -> TeethScene:
    out = scene.copy()
    for t in out.teeth:
        t.enamel = mat
        t.dentin = mat
        t.a_t = np.full((1, 1, 3), MODEL_A_T)
        t.c = np.zeros(3)
    return out


def literature_points(n_sigma: int = 10, n_albedo: int = 8, refine_keep: int = REFINE_KEEP) -> int:
    """How many times ``literature_start(s)`` calls its ``progress``: the table, then the refinement."""
    return n_sigma * n_albedo * len(G_VALUES) + len(G_VALUES) * 3 * refine_keep


def literature_start(scene: TeethScene, capture: Capture, n_sigma: int = 10, n_albedo: int = 8,
                     pixel_stride: int = 3, n_lights: int = 6, seed: int = 0, spp: int = 1, tile: int = 8,
                     max_depth: int | None = None, scale_invariant: bool = True, refine_keep: int = REFINE_KEEP,
                     progress: Callable[[int], None] | None = None) -> TeethScene:
    """Start scene whose enamel and dentin take, per channel, the best table point (c = 0).

    Every tooth parameter comes from the table or the model's defaults: sigma_t, albedo and g1 from the
    table; g2, beta from ``VolumeMaterial``'s defaults and a homogeneous a_t = :data:`MODEL_A_T`;
    dentin coefficients 0. Only the geometry, the gums and the oral cavity are ``scene``'s.

    Every (sigma_t, albedo, g) point is rendered as a grey homogeneous tooth (the surroundings keep
    their colours, so channel c of the render is compared with channel c of the capture), twice with
    independent seeds at ``spp``; every ``pixel_stride``-th masked pixel (3: about 95 s for the default
    table on the acceptance capture, 2 cores) is summed over ``tile`` x ``tile`` tiles per
    camera and light (per-pixel 1-spp values are mostly noise) and compared by
    :func:`paired_table_errors` (``scale_invariant``: the thesis' error; else the absolute one, for
    calibrated captures).

    Then, unless ``refine_keep`` is 0, the ``refine_keep`` points of smallest error of each g and channel
    are rendered again, twice with seeds no table point used, at max(8, 2 ``spp``) samples per pixel on
    every min(2, ``pixel_stride``)-th masked pixel of 12 other random lights, and the choice is made on the
    mean of both errors weighted by their samples, mostly the new one's (module docstring: the table's own
    minimum is mostly its noise).
    ``progress(n)`` is called after each point; :func:`literature_points` calls in all."""
    points, errors, table, gs = _search(scene, capture, n_sigma, n_albedo, pixel_stride, n_lights, seed, spp, tile,
                                        max_depth, scale_invariant, refine_keep, progress)
    best = [points[int(np.argmin(errors[:, c]))] for c in range(3)]
    return _start(scene, table, best, float(np.median([gs[gi] for gi, _ in best])))


def literature_starts(scene: TeethScene, capture: Capture, n_sigma: int = 10, n_albedo: int = 8,
                      pixel_stride: int = 3, n_lights: int = 6, seed: int = 0, spp: int = 1, tile: int = 8,
                      max_depth: int | None = None, scale_invariant: bool = True, refine_keep: int = REFINE_KEEP,
                      progress: Callable[[int], None] | None = None) -> list[TeethScene]:
    """One start per g of the table (in ``G_VALUES``' order): each channel takes the point of that g whose
    error is smallest (the search of :func:`literature_start`, the same arguments). The search cannot tell
    g (module docstring); the fit tries them (``start_trials.best_start``)."""
    points, errors, table, gs = _search(scene, capture, n_sigma, n_albedo, pixel_stride, n_lights, seed, spp, tile,
                                        max_depth, scale_invariant, refine_keep, progress)
    starts = []
    for gi, g in enumerate(gs):
        mine = [k for k, (pg, _) in enumerate(points) if pg == gi]
        starts.append(_start(scene, table, [points[mine[int(np.argmin(errors[mine, c]))]] for c in range(3)],
                             float(g)))
    return starts


def _start(scene: TeethScene, table: np.ndarray, best: list, g: float) -> TeethScene:
    """The homogeneous start whose channel c takes table point ``best[c]`` = (g index, table index)."""
    sigma = np.array([table[j, 0] for _, j in best])
    albedo = np.array([table[j, 1] for _, j in best])
    return _homogeneous(scene, VolumeMaterial(sigma, np.minimum(albedo, 0.999), g))


def _search(scene, capture, n_sigma, n_albedo, pixel_stride, n_lights, seed, spp, tile, max_depth, scale_invariant,
            refine_keep, progress) -> tuple[list, np.ndarray, np.ndarray, np.ndarray]:
    """The table search and its refinement: (points as (g index, table index), their errors (n, 3), table, gs)."""
    if capture.images is None or capture.masks is None:
        raise UserError("the literature search needs capture images and masks")
    if spp < 1 or tile < 1 or pixel_stride < 1:
        raise ValueError(f"spp, tile and pixel_stride must be >= 1, got {spp}, {tile}, {pixel_stride}")
    if refine_keep < 0:
        raise ValueError(f"refine_keep must be >= 0, got {refine_keep}")
    table, gs = literature_table(n_sigma, n_albedo)
    rng = np.random.default_rng(seed)
    light_ids = np.sort(rng.choice(len(capture.lights), min(n_lights, len(capture.lights)), replace=False))
    masked = [np.flatnonzero(m.ravel()) for m in capture.masks]
    if sum(len(p) for p in masked) == 0:
        raise UserError("the capture's masks select no pixels")

    def point_errors(points, ids, stride, n_spp, seed_of) -> np.ndarray:
        """(len(points), 3) paired errors of (g index, table index) points on lights ``ids``."""
        pixels = [p[::stride] for p in masked]
        tiles = traced_tiles(pixels, *capture.masks.shape[1:], tile)
        ref = _tile_sums(traced_values(capture.images[:, ids].astype(np.float64), pixels), *tiles)
        out = np.zeros((len(points), 3))
        for n, (gi, j) in enumerate(points):
            sig, alb = table[j]
            sc = _homogeneous(scene, VolumeMaterial(np.full(3, sig), np.full(3, min(alb, 0.999)), gs[gi]))
            cs = CompiledScene(sc)
            r = [_tile_sums(traced_values(render(sc, capture.cameras, capture.lights,
                                                 RenderSettings(spp=n_spp, max_depth=max_depth,
                                                                seed=seed_of(n, gi, j, h)),
                                                 pixels=pixels, light_ids=ids, compiled=cs).images, pixels),
                            *tiles) for h in (0, 1)]
            for c in range(3):
                out[n, c] = paired_table_errors(r[0][:, c:c + 1], r[1][:, c:c + 1], ref[:, c], scale_invariant)[0]
            if progress is not None:
                progress(1)
        return out

    grid = [(gi, j) for gi in range(len(gs)) for j in range(len(table))]
    errors = point_errors(grid, light_ids, pixel_stride, spp, lambda n, gi, j, h: 2 * (seed + gi * len(table) + j) + h)
    if refine_keep == 0:
        return grid, errors, table, gs
    cand = sorted({grid[gi * len(table) + int(j)] for gi in range(len(gs)) for c in range(3)
                   for j in np.argsort(errors[gi * len(table):(gi + 1) * len(table), c], kind="stable")[:refine_keep]})
    others = np.setdiff1d(np.arange(len(capture.lights)), light_ids)
    pool = others if len(others) >= REFINE_LIGHTS else np.arange(len(capture.lights))
    ids = np.sort(np.random.default_rng([seed, 1]).choice(pool, min(REFINE_LIGHTS, len(pool)), replace=False))
    used = seed + len(grid)  # seeds 2 (used + n) + h: after every table point's
    stride2, spp2 = min(2, pixel_stride), max(8, 2 * spp)
    refined = point_errors(cand, ids, stride2, spp2, lambda n, gi, j, h: 2 * (used + n) + h)
    if progress is not None and len(gs) * 3 * refine_keep > len(cand):
        progress(len(gs) * 3 * refine_keep - len(cand))
    # both estimates, weighted by their samples (their inverse variances, roughly): the table's carries its
    # selection bias, with a small weight where its renders were cheap (1:24 for the defaults)
    w1 = spp * sum(len(p[::pixel_stride]) for p in masked) * len(light_ids)
    w2 = spp2 * sum(len(p[::stride2]) for p in masked) * len(ids)
    first = errors[[gi * len(table) + j for gi, j in cand]]
    return cand, (w1 * first + w2 * refined) / (w1 + w2), table, gs
