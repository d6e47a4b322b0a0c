"""``fabric material PARAMS_DIR``: a .blend with the fitted fabric as a Cycles material (and a preview)."""

from __future__ import annotations

import argparse
import os

from ..core.errors import UserError
from .checks import between


def add_material_parser(fsub) -> None:
    m = fsub.add_parser("material", help="create the SGGX Fabric material from a fit folder (.blend, preview)")
    m.add_argument("params_dir", help="fit output folder (params.json + kd/ks/sigma/basis EXR maps)")
    m.add_argument("--out", default=None, help="output .blend (default: PARAMS_DIR/fabric.blend)")
    m.add_argument("--render", default=None, help="also render a shader-ball preview to this .png/.exr")
    m.add_argument("--samples", type=between(1, 1 << 24, int), default=16,
                   help="Cycles samples per pixel of the --render preview")
    m.set_defaults(func=run_material)


def run_material(args: argparse.Namespace) -> int:
    if args.render and not args.render.lower().endswith((".exr", ".png")):
        raise UserError(f"--render {args.render!r}: give a .exr (linear) or .png (sRGB) file name")
    if args.out and not args.out.lower().endswith(".blend"):
        raise UserError(f"--out {args.out!r}: give a .blend file name")
    from ..core.fabric.parameter_maps import load_params

    load_params(args.params_dir)  # a folder that is not a fit's: one line, before Blender starts
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    import bpy

    from ..addon.fabric.material import import_fit_material
    from ..render import configure_cycles, dark_world, render_to_array, reset_scene
    from ..showcase.library import build_preview_scene

    params_dir = os.path.abspath(args.params_dir)
    scene = reset_scene()
    configure_cycles(scene, resolution=(320, 240), samples=args.samples)
    dark_world(scene)
    mat = import_fit_material(params_dir, scene)
    build_preview_scene(scene, mat)
    out = os.path.abspath(args.out or os.path.join(params_dir, "fabric.blend"))
    os.makedirs(os.path.dirname(out), exist_ok=True)
    try:  # the .blend first: a preview without its .blend is half an output
        bpy.ops.wm.save_as_mainfile(filepath=out, compress=True)
    except RuntimeError as exc:  # Blender's "Cannot open file ... for writing: Permission denied"
        raise UserError(f"cannot write {out}: {' '.join(str(exc).split())}") from None
    print(out)
    if args.render:
        from .render import save_image

        save_image(args.render, render_to_array(scene))
        print(args.render)
    return 0
