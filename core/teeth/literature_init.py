"""Initialisation by a literature-table search (thesis Sec. 5.7).

The thesis tabulates the three-dimensional domain (albedo, density, phase anisotropy) spanned by the
values reported for enamel and dentin [Spitzer and ten Bosch 1975; Fried et al. 1995; Pop-Ciutrila
et al. 2015] (50000 points), renders a virtual *homogeneous* tooth for each point, compares it with
the masked measurements by a scale-invariant error and, per colour channel, starts from the point
with the smallest error. Here the table is a coarse log-spaced grid over the same span (sigma_t
0.3-30 / mm, albedo 0.5-0.999, g 0.3-0.9; a few hundred points), evaluated on a subset of lights with
two independently seeded renders per point and tile sums of the masked pixels, so that the choice
follows the model and not the renders' Monte Carlo noise (see ``literature_start``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .capture import Capture
from .compiled_scene import CompiledScene
from .parameterisation import albedo_from_kappa
from .path_tracer import RenderSettings, render, traced_tiles, traced_values
from .scene import TeethScene, VolumeMaterial

SIGMA_RANGE_MM = (0.3, 30.0)
ALBEDO_RANGE = (0.5, 0.999)
G_VALUES = (0.3, 0.6, 0.9)


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
    out = np.zeros((values.shape[0], n_tiles, 3))
    np.add.at(out, (slice(None), tile_of), values)
    return out.reshape(-1, 3)


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


def literature_start(scene: TeethScene, capture: Capture, n_sigma: int = 10, n_albedo: int = 8,
                     pixel_stride: int = 3, n_lights: int = 6, seed: int = 0, spp: int = 1, tile: int = 8,
                     max_depth: int | None = None, scale_invariant: bool = True,
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
    calibrated captures). ``progress(n)`` is called after each table point with n = 1."""
    if capture.images is None or capture.masks is None:
        raise ValueError("the literature search needs capture images and masks")
    if spp < 1 or tile < 1 or pixel_stride < 1:
        raise ValueError(f"spp, tile and pixel_stride must be >= 1, got {spp}, {tile}, {pixel_stride}")
    table, gs = literature_table(n_sigma, n_albedo)
    rng = np.random.default_rng(seed)
    light_ids = np.sort(rng.choice(len(capture.lights), min(n_lights, len(capture.lights)), replace=False))
    pixels = [np.flatnonzero(m.ravel())[::pixel_stride] for m in capture.masks]
    if sum(len(p) for p in pixels) == 0:
        raise ValueError("the capture's masks select no pixels")
    tiles = traced_tiles(pixels, *capture.masks.shape[1:], tile)
    ref = _tile_sums(traced_values(capture.images[:, light_ids].astype(np.float64), pixels), *tiles)
    errors = np.zeros((len(gs), len(table), 3))
    for gi, g in enumerate(gs):
        for j, (sig, alb) in enumerate(table):
            mat = VolumeMaterial(np.full(3, sig), np.full(3, min(alb, 0.999)), g)
            sc = _homogeneous(scene, mat)
            cs = CompiledScene(sc)
            r = [_tile_sums(traced_values(render(sc, capture.cameras, capture.lights,
                                                 RenderSettings(spp=spp, max_depth=max_depth,
                                                                seed=2 * (seed + gi * len(table) + j) + h),
                                                 pixels=pixels, light_ids=light_ids, compiled=cs).images, pixels),
                            *tiles) for h in (0, 1)]
            for c in range(3):
                errors[gi, j, c] = paired_table_errors(r[0][:, c:c + 1], r[1][:, c:c + 1], ref[:, c],
                                                       scale_invariant)[0]
            if progress is not None:
                progress(1)
    best = [np.unravel_index(np.argmin(errors[:, :, c]), errors.shape[:2]) for c in range(3)]
    sigma = np.array([table[j, 0] for _, j in best])
    albedo = np.array([table[j, 1] for _, j in best])
    g = float(np.median([gs[gi] for gi, _ in best]))
    return _homogeneous(scene, VolumeMaterial(sigma, np.minimum(albedo, 0.999), g))
