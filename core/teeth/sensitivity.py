"""How strongly a capture constrains each parameter direction (a diagnostic for the fit, Sec. 5.6-5.7).

For a displacement d of the physical parameters, the noise-free image change is J d (J = dC/dx, the
forward-mode image Jacobian of ``path_tracer.render``). Its energy relative to the capture's noise,

    chi2(d) = sum over tiles, lights, channels of (sum_tile J d)^2 / (tile pixels * noise variance),

says whether the capture can tell x from x + d: chi2 ~ 1 is one standard deviation of the capture
noise. The dentin coefficients' share of J d is instead the central difference (C(x + d_c) - C(x - d_c)) / 2
of two renders with common random numbers (as the fit's ``dentin_shape_gradient``): their path-space
derivative is noise, and biased, at a sharp enamel/dentin boundary (a photograph's, a Mitsuba capture's).
J is only available as a Monte Carlo estimate, and |J_hat d|^2 is biased upwards by J_hat's
variance, so the square is estimated without bias from independent passes: the mean over pairs
i != j of (J_i d)(J_j d) (which can come out negative when the signal is below the estimator's noise).
Pixels are pooled into ``block`` x ``block`` tiles first (a lower bound on the per-pixel chi2, with
far less estimator noise). The fit needs a direction's chi2 to stand out of its own gradient noise to
move along it, so directions with chi2 orders of magnitude below the others converge far more slowly.

The same passes tell how well the scene fits the capture. With T_i a pass's tile sums and C the capture's, the
mean over pairs i != j of (T_i - C)(T_j - C) estimates (E T - E C)^2 + var C without the passes' own noise;
divided by var C = tile pixels * noise variance and averaged over tiles, lights and channels it is the reduced
chi-square of the fit, 1 where the scene renders the capture to within its noise (``reduced_chi2``).

Memory: the per-pixel Jacobian is rendered a few lights at a time (``CHUNK_BYTES``) and summed into tiles at once,
and the dentin coefficients' scenes are compiled one direction at a time; neither changes a number (a light's
image and derivatives do not depend on the lights rendered with it). On the smile's intervals (345 directions, 8
lights) the peak fell from 8.9 GB to 1.4 GB.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from .capture import Capture
from .compiled_scene import CompiledScene
from .dentin_shape_gradient import shape_columns, shape_ends
from .param_vector import ParamLayout, scene_to_vector, volume_pairs
from .path_tracer import RenderSettings, render, traced_tile_sums, traced_tiles, traced_values
from .scene import TeethScene
from .task_map import TaskMap, local_map

CHUNK_BYTES = 2**30  # the per-pixel image Jacobian of one chunk of lights at most


def default_directions(scene: TeethScene, layout: ParamLayout | None = None, rel: float = 0.1,
                       dc: float = 0.05) -> tuple[list[str], np.ndarray]:
    """Names and (K, P) physical displacements: per volume and channel sigma_s x (1 + rel) at fixed sigma_a
    and sigma_a x (1 + rel) at fixed sigma_s (first order in sigma_t and albedo), and every dentin
    coefficient + dc."""
    layout = layout or ParamLayout(scene)
    x = scene_to_vector(scene, layout)
    names, rows = [], []
    component = layout.component_names()
    for s, a in zip(*volume_pairs(layout), strict=True):
        st, al = x[s], x[a]
        for what, dst, dal in (("sigma_s", rel * st * al, rel * al * (1.0 - al)),
                               ("sigma_a", rel * st * (1.0 - al), -rel * al * (1.0 - al))):
            d = np.zeros(layout.size)
            d[s], d[a] = dst, dal
            names.append(component[s].replace(".sigma_t[", f".{what}["))
            rows.append(d)
    for e in layout.entries:
        if e.kind == "c":
            for k in range(e.size):
                d = np.zeros(layout.size)
                d[e.start + k] = dc
                names.append(f"{e.name}[{k}]")
                rows.append(d)
    return names, np.array(rows)


def capture_sensitivity(scene: TeethScene, capture: Capture, directions: np.ndarray, *, passes: int = 6,
                        block: int = 8, noise_variance: float | None = None, capture_spp: int | None = None,
                        max_depth: int | None = None, seed: int = 0, task_map: TaskMap | None = None) -> dict:
    """chi2 of each row of ``directions`` (K, P physical displacements) for ``capture`` (module docstring).

    The capture's per-value noise variance is ``noise_variance`` or, for a synthetic capture rendered with
    ``capture_spp`` samples, the passes' pooled 1-spp variance / ``capture_spp``. The renders are items of
    ``task_map`` (default: this process): each dentin-coefficient direction's pair of scenes, then chunks of
    lights (one per worker of the map, within ``CHUNK_BYTES``); the sums are the same whichever map computes
    them. Returns ``{"chi2": (K,), "noise_variance": float, "tiles": int}``."""
    if capture.masks is None:
        raise UserError("the capture needs masks")
    if passes < 2:
        raise ValueError("passes must be >= 2 (the square is estimated from pairs of independent passes)")
    if (noise_variance is None) == (capture_spp is None):
        raise ValueError("give exactly one of noise_variance and capture_spp")
    task_map = task_map or local_map
    layout = ParamLayout(scene)
    directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    if directions.shape[1] != layout.size:
        raise ValueError(f"directions must have {layout.size} columns (the scene's parameters), "
                         f"got {directions.shape[1]}")
    c_cols = shape_columns(layout)
    material = directions.copy()
    material[:, c_cols] = 0.0
    cols = np.flatnonzero(np.any(material != 0, axis=0))
    k = len(directions)
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    tile_of, n_tiles = traced_tiles(pixels, *capture.masks.shape[1:], block)
    n_rows = len(tile_of)
    tile_pixels = np.bincount(tile_of, minlength=n_tiles).astype(np.float64)
    # the directions' coefficient parts: per pass, the tile sums of the central difference of two renders (every
    # light), their two scenes compiled one direction at a time (a compiled smile holds about 70 MB)
    shape_dirs = [j for j, d in enumerate(directions) if np.any(d[c_cols] != 0)]
    ends = task_map(shape_end_tiles, (scene, capture, layout, passes, block, max_depth, seed),
                    [(directions[j][c_cols],) for j in shape_dirs])
    end_tiles = np.array(ends) if ends else np.zeros((0, passes, len(capture.lights), n_tiles, 3))
    n_lights = len(capture.lights)
    # the lights in chunks whose per-pixel Jacobian stays within CHUNK_BYTES: a light's image and its derivatives
    # do not depend on which other lights are rendered with it (the camera paths are the same), so the result is
    # the one of all lights at once; a map that runs chunks side by side gets one per worker at least
    per_light = 8 * n_rows * 3 * max(len(cols), 1)
    chunk = int(max(1, min(n_lights, CHUNK_BYTES // per_light, -(-n_lights // max(task_map.parallel, 1)))))
    chunks = [np.arange(l0, min(l0 + chunk, n_lights)) for l0 in range(0, n_lights, chunk)]
    parts = task_map(light_chunk_information,
                     (scene, capture, layout, cols, material, shape_dirs, passes, block, max_depth, seed),
                     [(ids, end_tiles[:, :, ids]) for ids in chunks])
    info = np.zeros((k, k))  # sum over tiles, lights, channels of (sum_i T_i d_k)(sum_j T_j d_j) - own terms
    s2 = np.zeros((k, k))  # sum over passes of the pass's own information, the bias of s1 s1^T
    var_sum, var_count = 0.0, 0
    res_pairs = []  # per chunk: the mean over pairs i != j of (T_i - C)(T_j - C), (lights, tiles, channels)
    for part in parts:
        info += part.info
        s2 += part.own
        var_sum, var_count = var_sum + part.var_sum, var_count + part.var_count
        if part.residual_pairs is not None:
            res_pairs.append(part.residual_pairs)
    if noise_variance is None:
        noise_variance = float(var_sum / var_count / capture_spp)  # pooled 1-spp variance over the capture's spp
    # unbiased sum over tiles, lights, channels of (E[J] d_k)(E[J] d_j) / tile pixels
    info = (info - s2) / (passes * (passes - 1)) / max(noise_variance, 1e-300)
    info = 0.5 * (info + info.T)
    reduced = float("nan")
    if res_pairs:
        pair_mean = np.concatenate(res_pairs)
        reduced = float(np.mean(pair_mean / (tile_pixels[None, :, None] * max(noise_variance, 1e-300))))
    return {"chi2": np.diag(info).copy(), "information": info, "noise_variance": float(noise_variance),
            "tiles": int(n_tiles), "reduced_chi2": reduced}


def shape_end_tiles(scene: TeethScene, capture: Capture, layout: ParamLayout, passes: int, block: int,
                    max_depth: int | None, seed: int, dc: np.ndarray) -> np.ndarray:
    """(passes, lights, tiles, 3): per pass (seed ``seed + pass``, the material passes' seeds: common random
    numbers) the tile sums of (C(x + d_c) - C(x - d_c)) / 2 for the dentin-coefficient displacement ``dc``."""
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    tile_of, n_tiles = traced_tiles(pixels, *capture.masks.shape[1:], block)
    pair = [(sc, CompiledScene(sc, layout=layout)) for sc in shape_ends(scene, layout, dc)]
    out = []
    for i in range(passes):
        st = RenderSettings(spp=1, max_depth=max_depth, seed=seed + i)
        plus, minus = (traced_values(render(sc, capture.cameras, capture.lights, st, pixels=pixels,
                                            compiled=csc).images, pixels) for sc, csc in pair)
        out.append(0.5 * traced_tile_sums(plus - minus, tile_of, n_tiles))
    return np.array(out)


@dataclass
class ChunkInformation:
    """One chunk of lights' share of :func:`capture_sensitivity`: ``info`` the sum over its tiles, lights and
    channels of (sum_i T_i d_k)(sum_j T_j d_j) / tile pixels, ``own`` the passes' own such products (the bias
    removed), the image variance's sum and count, and the mean over pass pairs of the tile residuals' products
    (lights, tiles, 3; None without capture images)."""

    info: np.ndarray
    own: np.ndarray
    var_sum: float
    var_count: int
    residual_pairs: np.ndarray | None


def light_chunk_information(scene: TeethScene, capture: Capture, layout: ParamLayout, cols: np.ndarray,
                            material: np.ndarray, shape_dirs: list[int], passes: int, block: int,
                            max_depth: int | None, seed: int, ids: np.ndarray,
                            end_tiles: np.ndarray) -> ChunkInformation:
    """The lights ``ids``' :class:`ChunkInformation`: ``passes`` 1-spp renders (seed ``seed + pass``) with the
    forward-mode Jacobian of the material columns ``cols``, projected on the rows of ``material``, plus the
    dentin-coefficient directions ``shape_dirs``' ``end_tiles`` (directions, passes, these lights, tiles, 3)."""
    pixels = [np.flatnonzero(m.ravel()) for m in capture.masks]
    tile_of, n_tiles = traced_tiles(pixels, *capture.masks.shape[1:], block)
    n_rows, k = len(tile_of), len(material)
    wt = 1.0 / np.bincount(tile_of, minlength=n_tiles).astype(np.float64)
    cs = CompiledScene(scene, layout=layout)
    lights = [capture.lights[i] for i in ids]
    cap_tiles = None if capture.images is None else traced_tile_sums(
        traced_values(capture.images[:, ids], pixels), tile_of, n_tiles)
    s1 = None
    s2 = np.zeros((k, k))
    img_sum = img_sq = 0.0
    res_sum, res_sq = 0.0, 0.0  # sums over passes of (T_i - C) and its square, for the reduced chi-square
    for i in range(passes):
        st = RenderSettings(spp=1, max_depth=max_depth, seed=seed + i)
        if len(cols):
            r = render(scene, capture.cameras, lights, st, pixels=pixels, compiled=cs, jacobian_cols=cols)
            jt = np.zeros((n_tiles, len(ids) * 3 * len(cols)))
            np.add.at(jt, tile_of, r.jacobian.reshape(n_rows, -1))
            jt = jt.reshape(n_tiles, len(ids), 3, len(cols))
            r.jacobian = None  # freed before the next pass renders its own
            t = jt @ material[:, cols].T  # (tiles, lights, 3, K)
        else:
            r = render(scene, capture.cameras, lights, st, pixels=pixels, compiled=cs)
            t = np.zeros((n_tiles, len(ids), 3, k))
        for n, j in enumerate(shape_dirs):
            t[..., j] += np.moveaxis(end_tiles[n, i], 0, 1)
        s1 = t if s1 is None else s1 + t
        s2 += np.einsum("tlck,tlcj,t->kj", t, t, wt)
        vals = traced_values(r.images, pixels)
        img_sum = img_sum + vals
        img_sq = img_sq + vals * vals
        if cap_tiles is not None:
            res = traced_tile_sums(vals, tile_of, n_tiles) - cap_tiles
            res_sum, res_sq = res_sum + res, res_sq + res * res
    var = (img_sq - img_sum * img_sum / passes) / (passes - 1)
    pairs = None
    if cap_tiles is not None:  # sum over pairs i != j of res_i res_j = (sum res)^2 - sum res^2
        pairs = (res_sum * res_sum - res_sq) / (passes * (passes - 1))
    return ChunkInformation(np.einsum("tlck,tlcj,t->kj", s1, s1, wt), s2, float(var.sum()), int(var.size), pairs)


def cramer_rao_std(information: np.ndarray) -> np.ndarray:
    """The smallest standard deviation any unbiased estimate of each direction's coefficient can have from
    the capture (square roots of the diagonal of the inverse information matrix; Cramer-Rao). The
    information is chi2 in the module docstring's sense between pairs of directions: F_kj = sum (J d_k)
    (J d_j) / noise. A direction that others can imitate (a similarity relation between sigma_t, albedo
    and g, say) keeps a large bound however large its own chi2 = F_kk. Where the estimate of F is not
    positive definite (estimator noise), the bound is inf for the directions it leaves unconstrained."""
    w, v = np.linalg.eigh(0.5 * (information + information.T))
    ok = w > 1e-12 * max(float(w.max()), 1e-300)
    var = (v[:, ok] ** 2 / w[ok]).sum(axis=1)
    unconstrained = (v[:, ~ok] ** 2 > 1e-6).any(axis=1)
    return np.sqrt(np.where(unconstrained, np.inf, var))
