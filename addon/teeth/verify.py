"""Cross-renderer check: the same teeth scene rendered by Cycles (the Enamel/Dentin/Gingiva materials)
and by the core forward path tracer (``core.teeth.path_tracer``).

Both estimate the same integral when: the blend spread is the same (``check_scene`` makes the interface
sharp, ``blend_spread`` -> 0, where the meshes' own volumes render it; at a wider spread each tooth's Blend
Volume renders the core's blend, ``blend_volume``), the camera, point lamp and units match (see
``scene_build``), and path depth limits are high enough that truncation is negligible on both sides.
Metrics, per tooth region (pixels whose centre and corners see that tooth's enamel first):

* ``mean_colour_rel_err``: max over teeth and channels of |mean_cycles - mean_core| / mean_core;
* ``median_px_rel_err``: median over tooth pixels (and channels) of |B c - B k| / B k, B = 8 x 8 box filter.
"""

from __future__ import annotations

import time

import numpy as np

from ...core.teeth.synthetic import tooth_regions
from ...render import dark_world, render_to_array, reset_scene
from .scene_build import add_camera, add_point_light, build_teeth_scene, configure_teeth_cycles

__all__ = ["check_scene", "compare", "cross_check", "render_core", "render_cycles", "tooth_regions"]

BLUR = 8


def check_scene(n_teeth: int = 2, resolution: int = 20, width: int = 64, height: int = 40):
    """The cross-check scene: synthetic teeth on gums before the cavity proxy, one camera, one lamp."""
    from ...core.teeth.capture import Camera, PointLight
    from ...core.teeth.synthetic import make_scene, scene_target

    ts = make_scene(n_teeth=n_teeth, resolution=resolution)
    ts.blend_spread = 1e-6  # sharp enamel/dentin interface (the meshes' volumes in Cycles)
    target = scene_target(ts)
    span = 8.6 * n_teeth + 4.0
    dist = 120.0
    fov = 2.0 * np.degrees(np.arctan(0.5 * span / dist))
    cam = Camera.look_at(target + np.array([0.0, dist, 0.1 * dist]), target, (0, 0, 1), fov, width, height, "check")
    light = PointLight(target + np.array([60.0, 150.0, 90.0]), np.full(3, 2.0e4))
    return ts, cam, light


def render_core(ts, cam, light, spp: int, seed: int = 1, max_depth: int = 64) -> np.ndarray:
    from ...core.teeth.path_tracer import RenderSettings, render

    res = render(ts, [cam], [light], RenderSettings(spp=spp, max_depth=max_depth, seed=seed, chunk=8192))
    return res.images[0, 0]


def render_cycles(ts, cam, light, spp: int, seed: int = 0, bounces: int = 256) -> np.ndarray:
    scene = reset_scene()
    dark_world(scene)
    build_teeth_scene(ts, scene.collection, mm_per_unit=1.0)
    add_camera(scene, cam, mm_per_unit=1.0)
    add_point_light(scene, light, mm_per_unit=1.0)
    configure_teeth_cycles(scene, spp, seed, bounces)
    return render_to_array(scene)[:, :, :3]  # row 0 = top, as the core camera


def compare(img_cycles: np.ndarray, img_core: np.ndarray, region: np.ndarray, blur: int = BLUR) -> dict:
    from scipy.ndimage import uniform_filter

    n = int(region.max()) + 1
    per_tooth = []
    for i in range(n):
        m = region == i
        if m.sum() == 0:
            continue
        a, b = img_cycles[m].mean(axis=0), img_core[m].mean(axis=0)
        per_tooth.append((np.abs(a - b) / np.maximum(b, 1e-12)).tolist())
    fa = uniform_filter(img_cycles, size=(blur, blur, 1), mode="nearest")
    fb = uniform_filter(img_core, size=(blur, blur, 1), mode="nearest")
    m = region >= 0
    px = np.abs(fa[m] - fb[m]) / np.maximum(fb[m], 1e-12)
    return {"mean_colour_rel_err": float(np.max(per_tooth)), "per_tooth_rel_err": per_tooth,
            "median_px_rel_err": float(np.median(px)), "p90_px_rel_err": float(np.quantile(px, 0.9)),
            "tooth_pixels": int(m.sum())}


def cross_check(spp_cycles: int = 256, spp_core: int = 64, n_teeth: int = 2, width: int = 64, height: int = 40,
                resolution: int = 20, max_depth: int = 64) -> dict:
    ts, cam, light = check_scene(n_teeth, resolution, width, height)
    region = tooth_regions(ts, cam)
    t0 = time.perf_counter()
    cyc = render_cycles(ts, cam, light, spp_cycles, bounces=max_depth)
    t1 = time.perf_counter()
    # two independent halves: their average is the reference, their difference measures its own MC noise
    half = max(1, spp_core // 2)
    core_a = render_core(ts, cam, light, half, seed=1, max_depth=max_depth)
    core_b = render_core(ts, cam, light, half, seed=2, max_depth=max_depth)
    core = 0.5 * (core_a + core_b)
    t2 = time.perf_counter()
    out = compare(cyc, core, region)
    # the core's own MC noise: two independent half-spp estimates compared with the same metrics
    # (the full estimate's error is about half of a half-vs-half difference; the max over teeth and
    # channels of one such difference is a rough, pessimistic scale)
    noise = compare(core_a, core_b, region)
    out["core_halves_mean_colour_rel_diff"] = noise["mean_colour_rel_err"]
    out["core_halves_median_px_rel_diff"] = noise["median_px_rel_err"]
    out.update({"cycles_seconds": t1 - t0, "core_seconds": t2 - t1, "spp_cycles": spp_cycles, "spp_core": spp_core,
                "width": width, "height": height, "max_depth": max_depth})
    return out, cyc, core, region
