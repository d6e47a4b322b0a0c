"""``render``: render a library scene or a .blend file headlessly with Cycles to EXR/PNG."""

from __future__ import annotations

import argparse
import os

from ..core.errors import MissingFileError, UserError
from .checks import UsageError, between, refuse_output_over_inputs, resolution, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="render a library scene or a .blend headlessly (Cycles CPU)")
    p.add_argument("scene", nargs="?", help="library scene name (see --list)")
    p.add_argument("--list", action="store_true", help="list the library scenes")
    p.add_argument("--blend", help="render this .blend file's scene instead of a library scene")
    p.add_argument("--out", default="out/render.exr", help="output .exr (linear) or .png (sRGB)")
    p.add_argument("--samples", type=between(1, 1 << 24, int), default=None,
                   help="Cycles samples per pixel (default: the scene's)")
    p.add_argument("--resolution", type=resolution, default=None,
                   help="image size WxH in pixels, e.g. 320x240 (default: the scene's)")
    p.add_argument("--seed", type=seed, default=0, help="Cycles' random seed")
    p.set_defaults(func=run)


def save_image(path: str, rgba) -> None:
    """Write linear pixels as EXR, or as an sRGB PNG when ``path`` ends in .png."""
    from ..core.exr_io import write_exr

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if path.lower().endswith(".png"):
        from ..core.imaging import to_display_uint8

        pixels = to_display_uint8(rgba)
        try:
            from PIL import Image
        except ImportError:  # a desktop Blender has no Pillow, but its bundled OpenImageIO writes PNG
            _write_png_oiio(path, pixels)
        else:
            Image.fromarray(pixels).save(path)
    else:
        write_exr(path, rgba)


def _write_png_oiio(path: str, pixels) -> None:
    import OpenImageIO as oiio

    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(path)
    if out is None or not out.open(path, oiio.ImageSpec(w, h, c, "uint8")):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    try:
        if not out.write_image(pixels):
            raise OSError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()


def run(args: argparse.Namespace) -> int:
    if args.blend:
        refuse_output_over_inputs(args.out, [args.blend])
    if not args.out.lower().endswith((".exr", ".png")):
        raise UsageError(f"--out {args.out!r}: give a .exr (linear) or .png (sRGB) file name")
    if not (args.list or args.blend or args.scene):
        raise UsageError("give a scene name, --blend FILE or --list")
    if args.blend and args.scene:
        raise UsageError(f"give a scene name ({args.scene}) or --blend FILE, not both")
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from ..showcase import library

    if args.list:
        for name in library.available_scenes():
            print(f"{name:20s} {library.SCENES[name].label}")
        return 0
    if args.blend:
        rgba = render_blend(args.blend, args.resolution, args.samples, args.seed)
    else:
        import tempfile

        # the scene's textures and tables are written here while it renders; nothing is left beside --out
        with tempfile.TemporaryDirectory(prefix="material-structures-render-") as workdir:
            rgba = library.render_library_scene(args.scene, workdir, args.resolution, args.samples)
    save_image(args.out, rgba)
    print(args.out)
    return 0


def render_blend(path: str, resolution, samples, seed):
    import bpy

    from ..render import configure_cycles, render_to_array

    if not os.path.isfile(path):
        raise MissingFileError(f"no such .blend file: {path}", path)
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path))
    except RuntimeError as exc:  # Blender's "Error: Cannot read file ...": not a .blend, or a damaged one
        detail = " ".join(str(exc).split()) or "Blender cannot read it"
        raise UserError(f"{path}: not a readable .blend file ({detail})") from None
    scene = bpy.context.scene
    if scene.camera is None:  # Blender's "Cannot render, no camera" would come out as a traceback
        raise UserError(f"{path}: its scene {scene.name!r} has no camera to render from")
    res = resolution or (scene.render.resolution_x, scene.render.resolution_y)
    configure_cycles(scene, resolution=res, samples=samples or scene.cycles.samples, seed=seed)
    return render_to_array(scene)
