"""Initialisation by a literature-table search (thesis Sec. 5.7).

The thesis tabulates the three-dimensional domain (albedo, density, phase anisotropy) spanned by the
values reported for enamel and dentin [Spitzer and ten Bosch 1975; Fried et al. 1995; Pop-Ciutrila
et al. 2015] (50000 points), renders a virtual *homogeneous* tooth for each point, compares it with
the masked measurements by a scale-invariant error and, per colour channel, starts from the point
with the smallest error. Here the table is a coarse log-spaced grid over the same span (sigma_t
0.3-30 / mm, albedo 0.5-0.999, g 0.3-0.9; a few hundred points), evaluated on a subset of pixels and
lights; each render evaluates three table points at once (one per colour channel).
"""

from __future__ import annotations

import numpy as np

from .capture import Capture
from .compiled_scene import CompiledScene
from .parameterisation import albedo_from_kappa
from .path_tracer import RenderSettings, render, traced_values
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


def _homogeneous(scene: TeethScene, mat: VolumeMaterial) -> TeethScene:
    out = scene.copy()
    for t in out.teeth:
        t.enamel = mat
        t.dentin = mat
        t.c = np.zeros(3)
    return out


def literature_start(scene: TeethScene, capture: Capture, n_sigma: int = 10, n_albedo: int = 8,
                     pixel_stride: int = 3, n_lights: int = 6, seed: int = 0) -> TeethScene:
    """Start scene whose enamel and dentin take, per channel, the best table point (c = 0)."""
    if capture.images is None or capture.masks is None:
        raise ValueError("the literature search needs capture images and masks")
    table, gs = literature_table(n_sigma, n_albedo)
    rng = np.random.default_rng(seed)
    light_ids = np.sort(rng.choice(len(capture.lights), min(n_lights, len(capture.lights)), replace=False))
    pixels = [np.flatnonzero(m.ravel())[::pixel_stride] for m in capture.masks]
    ref = traced_values(capture.images[:, light_ids], pixels).reshape(-1, 3)
    n_pts = len(table)
    pad = (-n_pts) % 3
    idx = np.concatenate([np.arange(n_pts), np.zeros(pad, dtype=np.int64)])
    best = {c: (np.inf, None, None) for c in range(3)}
    base = scene.teeth[0].enamel
    for g in gs:
        for j in range(0, len(idx), 3):
            pts = table[idx[j:j + 3]]
            mat = VolumeMaterial(pts[:, 0], np.minimum(pts[:, 1], 0.999), g, base.g2, base.beta)
            sc = _homogeneous(scene, mat)
            res = render(sc, capture.cameras, capture.lights, RenderSettings(spp=1, max_depth=4, seed=seed + j),
                         pixels=pixels, light_ids=light_ids, compiled=CompiledScene(sc))
            vals = traced_values(res.images, pixels).reshape(-1, 3)
            for k in range(3):
                for c in range(3):
                    e = scale_invariant_error(vals[:, k], ref[:, c])
                    if e < best[c][0]:
                        best[c] = (e, pts[k], g)
    sigma = np.array([best[c][1][0] for c in range(3)])
    albedo = np.array([best[c][1][1] for c in range(3)])
    g = float(np.median([best[c][2] for c in range(3)]))
    return _homogeneous(scene, VolumeMaterial(sigma, np.minimum(albedo, 0.999), g, base.g2, base.beta))
