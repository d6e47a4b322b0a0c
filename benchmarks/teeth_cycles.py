"""``bench teeth-cycles``: the teeth scene rendered by Cycles (Enamel/Dentin/Gingiva materials and each tooth's
Blend Volume) and by the core forward path tracer; per-tooth mean colour and 8 x 8 box-filtered per-pixel
relative errors, with a sharp enamel/dentin boundary and with the core's default blend spread."""

from __future__ import annotations

import time

BLEND_SPP_CYCLES = 1024
BLEND_SPP_CORE = 1024


def teeth_cycles() -> dict:
    from ._blender import blender_with_addon

    bpy = blender_with_addon()
    from ..addon.teeth.verify import check_scene, compare, cross_check, render_core, render_cycles, tooth_regions
    from ..core.teeth.sigmoid_blend import DEFAULT_SPREAD_MM

    out, _, _, _ = cross_check(spp_cycles=256, spp_core=64, width=64, height=40, max_depth=64)
    out["blender"] = ".".join(str(v) for v in bpy.app.version)
    # The core's default logistic enamel/dentin blend (spread 1 / ln 19 mm): Cycles renders it through each
    # tooth's Blend Volume (addon/teeth/blend_volume.py) at 1024 spp; the core at 1024 spp in two independent
    # halves, whose difference is the reference's own noise. (At 256 / 64 spp the noise alone moved the worst
    # tooth-channel error by 1-2 points between seeds.)
    ts, cam, light = check_scene(2, 20, 64, 40)
    ts.blend_spread = DEFAULT_SPREAD_MM
    region = tooth_regions(ts, cam)
    t0 = time.perf_counter()
    cyc = render_cycles(ts, cam, light, BLEND_SPP_CYCLES, bounces=64)
    t1 = time.perf_counter()
    core_a = render_core(ts, cam, light, BLEND_SPP_CORE // 2, seed=3, max_depth=64)
    core_b = render_core(ts, cam, light, BLEND_SPP_CORE // 2, seed=4, max_depth=64)
    blended = compare(cyc, 0.5 * (core_a + core_b), region)
    noise = compare(core_a, core_b, region)
    out["default_spread_mean_colour_rel_err"] = blended["mean_colour_rel_err"]
    out["default_spread_median_px_rel_err"] = blended["median_px_rel_err"]
    out["default_spread_p90_px_rel_err"] = blended["p90_px_rel_err"]
    out["default_spread_per_tooth_rel_err"] = blended["per_tooth_rel_err"]
    out["default_spread_core_halves_mean_colour_rel_diff"] = noise["mean_colour_rel_err"]
    out["default_spread_core_halves_median_px_rel_diff"] = noise["median_px_rel_err"]
    out["default_spread_cycles_seconds"] = t1 - t0
    out["default_spread_mm"] = DEFAULT_SPREAD_MM
    out["default_spread_spp_cycles"], out["default_spread_spp_core"] = BLEND_SPP_CYCLES, BLEND_SPP_CORE
    return out


BENCHMARKS = {"teeth-cycles": teeth_cycles}
