"""Benchmark of the scratched-metal shader in Cycles (issue 14).

``scratch-render``: per-pixel accuracy of the shader against ``core.scratch.scratch_radiance`` on the
verification plate (sphere + rectangle lamps; sun + point + disk lamps), and the render time of the
10 000-scratch showcase scene relative to the same scene with a plain metal (Principled, same base
colour and roughness), same resolution and samples, rendered alternately in one run (minimum of
``REPEATS`` renders each, after one warm-up render that compiles the shaders and loads the tables).
The timing uses the library's sample scene settings (``scratch-plate``: 320 x 240, 16 spp); the same
ratio for a 160 x 120, 8 spp render, where fixed per-render costs dominate, is reported as
``small_render``. ``time_ratio_vs_base`` is wall-clock; ``cpu_time_ratio_vs_base`` (process CPU time, all render
threads) is reported too because wall-clock ratios swing by 2x on a shared, loaded machine.
"""

from __future__ import annotations

import time

import numpy as np

from ._blender import blender_with_addon

RESOLUTION = (160, 120)  # small render: reported too, where fixed per-render costs dominate
SAMPLES = 8
REPEATS = 3
SAMPLE_SCENE = "scratch-plate"  # the timing criterion is about this library scene at its own settings
PLATE_CASES = (
    (("POINT", (0.5, 0.3, 1.2), 200.0, 0.08), ("AREA", (0.45, 0.3, 1.0), 100.0, (0.3, 0.2))),
    (
        ("SUN", (0.5, 0.3, 1.2), 3.0, 0),
        ("POINT", (0.6, -0.2, 1.0), 150.0, 0),
        ("AREA", (-0.4, -0.3, 1.1), 80.0, (0.35, 0.35)),
    ),
)


def _scene(bpy, name, plain, resolution, samples):
    from ..render import configure_cycles
    from ..showcase.scenes_scratch import build_scratched_plate

    scene = bpy.data.scenes.new(name)
    configure_cycles(scene, resolution=resolution, samples=samples, seed=0)
    world = bpy.data.worlds.new(f"{name} World")
    if world.node_tree is None:
        world.use_nodes = True
    scene.world = world
    build_scratched_plate(scene, plain=plain)
    return scene


def scratch_render() -> dict:
    bpy = blender_with_addon()
    from ..addon.scratch.verify import relative_errors, render_plate_vs_core
    from ..render import render_to_array, reset_scene

    errs = []
    for lamps in PLATE_CASES:
        rgb, ref, mask = render_plate_vs_core(lamps=lamps)
        errs.append(relative_errors(rgb, ref, mask))
    err = np.concatenate(errs)

    hdri = _hdri_error()
    from ..showcase.library import SCENES, available_scenes

    available_scenes()
    entry = SCENES[SAMPLE_SCENE]
    small = _time_ratio(bpy, reset_scene, render_to_array, RESOLUTION, SAMPLES)
    full = _time_ratio(bpy, reset_scene, render_to_array, entry.resolution, entry.samples)
    return {
        "median_rel_err": float(np.median(err)),
        "p99_rel_err": float(np.percentile(err, 99)),
        "pixels": int(err.size),
        "time_ratio_vs_base": full["wall"],
        "cpu_time_ratio_vs_base": full["cpu"],
        "time_scratched_s": full["scratched_s"],
        "time_plain_s": full["plain_s"],
        "resolution": list(entry.resolution),
        "samples": entry.samples,
        "small_render": {"resolution": list(RESOLUTION), "samples": SAMPLES, **small},
        "n_scratches": 10000,
        "hdri_approx_median_rel_err": hdri["median_rel_err"],
        "hdri_approx_p99_rel_err": hdri["p99_rel_err"],
        "hdri_approx_total_rel_err": hdri["total_rel_err"],
    }


def _time_ratio(bpy, reset_scene, render_to_array, resolution, samples) -> dict:
    """Scratched vs plain showcase plate, rendered alternately (minimum of REPEATS after a warm-up)."""
    reset_scene()
    scenes = {
        "scratched": _scene(bpy, "MS Scratched", False, resolution, samples),
        "plain": _scene(bpy, "MS Plain", True, resolution, samples),
    }
    times = {k: [] for k in scenes}
    cpu = {k: [] for k in scenes}
    for sc in scenes.values():
        render_to_array(sc)  # warm-up: shader compile, texture cache
    for _ in range(REPEATS):
        for k, sc in scenes.items():
            t0, c0 = time.perf_counter(), time.process_time()
            render_to_array(sc)
            times[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    t_s, t_p = min(times["scratched"]), min(times["plain"])
    return {"wall": t_s / t_p, "cpu": min(cpu["scratched"]) / min(cpu["plain"]), "scratched_s": t_s, "plain_s": t_p}


def _hdri_error() -> dict:
    """Scratch term under a synthetic sky (6 degree sun + gradient) approximated by 2 world lamps,
    against every texel integrated as a polygon light (addon/scratch/world.py)."""
    import math

    from ..addon.scratch import world as W
    from ..addon.scratch.verify import test_scratch_set

    d, _ = W.equirect_directions()
    sun = np.array([0.5, 0.3, 0.81]) / np.linalg.norm([0.5, 0.3, 0.81])
    env = np.clip(d[..., 2], 0, 1)[..., None] * np.array([0.3, 0.4, 0.6])
    env = env + (d @ sun > math.cos(math.radians(6)))[..., None] * np.array([40.0, 38.0, 34.0])
    pts = np.random.default_rng(0).uniform(300, 1700, (60, 2))
    wo = np.array([-0.4, -0.2, 0.89])
    return W.world_approximation_error(env, 2, test_scratch_set(), pts, wo / np.linalg.norm(wo))


BENCHMARKS = {"scratch-render": scratch_render}
