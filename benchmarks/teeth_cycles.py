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
    from ..addon.teeth.verify import cross_check

    out, _, _, _ = cross_check(spp_cycles=256, spp_core=64, width=64, height=40, max_depth=64)
    out["blender"] = ".".join(str(v) for v in bpy.app.version)
    return out


BENCHMARKS = {"teeth-cycles": teeth_cycles}
