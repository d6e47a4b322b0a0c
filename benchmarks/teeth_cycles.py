"""``bench teeth-cycles``: the teeth scene rendered by Cycles (Enamel/Dentin/Gingiva materials) and by the
core forward path tracer; per-tooth mean colour and 8 x 8 box-filtered per-pixel relative errors."""

from __future__ import annotations


def teeth_cycles() -> dict:
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    import bpy

    from .. import addon

    if not hasattr(bpy.types.Object, "ms_tooth"):
        addon.register()
    from ..addon.teeth.verify import check_scene, compare, cross_check, render_core
    from ..core.teeth.sigmoid_blend import DEFAULT_SPREAD_MM

    out, cyc, _, region = cross_check(spp_cycles=256, spp_core=64, width=64, height=40, max_depth=64)
    out["blender"] = ".".join(str(v) for v in bpy.app.version)
    # The core's default logistic enamel/dentin blend (spread 1 / ln 19 mm) has no Cycles counterpart:
    # how far the core's own image moves from the Cycles one with it (16 spp: the effect is large).
    ts, cam, light = check_scene(2, 20, 64, 40)
    ts.blend_spread = DEFAULT_SPREAD_MM
    blended = compare(cyc, render_core(ts, cam, light, 16, seed=3, max_depth=64), region)
    out["default_spread_mean_colour_rel_err"] = blended["mean_colour_rel_err"]
    out["default_spread_median_px_rel_err"] = blended["median_px_rel_err"]
    return out


BENCHMARKS = {"teeth-cycles": teeth_cycles}
