"""``render``: render a library scene or a .blend file headlessly with Cycles to EXR/PNG."""

from __future__ import annotations

import argparse
import os

from ..core.errors import MissingFileError, UserError
from .checks import between, refuse_output_over_inputs, seed


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="render a library scene or a .blend headlessly (Cycles CPU)")
    p.add_argument("scene", nargs="?", help="library scene name (see --list)")
    p.add_argument("--list", action="store_true", help="list the library scenes")
    p.add_argument("--blend", help="render this .blend file's scene instead of a library scene")
    p.add_argument("--out", default="out/render.exr", help="output .exr (linear) or .png (sRGB)")
    p.add_argument("--samples", type=between(1, 1 << 24, int), default=None, help="Cycles samples (scene default)")
    p.add_argument("--resolution", default=None, help="WxH, e.g. 320x240 (scene default)")
    p.add_argument("--seed", type=seed, default=0)
    p.set_defaults(func=run)


MAX_SIDE = 16384  # pixels a side (Cycles' own limit is far above what fits in memory here)


def parse_resolution(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--resolution must look like 320x240, got {text!r}") from None
    if w < 1 or h < 1:
        raise UserError("--resolution must be positive")
    if w > MAX_SIDE or h > MAX_SIDE:
        raise UserError(f"--resolution {w}x{h} is larger than {MAX_SIDE} pixels a side")
    return w, h


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
    resolution = parse_resolution(args.resolution)
    if args.blend:
        refuse_output_over_inputs(args.out, [args.blend])
    if not args.out.lower().endswith((".exr", ".png")):
        raise UserError(f"--out {args.out!r}: give a .exr (linear) or .png (sRGB) file name")
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from ..showcase import library

    if args.list:
        for name in library.available_scenes():
            print(f"{name:20s} {library.SCENES[name].label}")
        return 0
    if args.blend:
        rgba = render_blend(args.blend, resolution, args.samples, args.seed)
    elif args.scene:
        workdir = os.path.join(os.path.dirname(os.path.abspath(args.out)), "work")
        rgba = library.render_library_scene(args.scene, workdir, resolution, args.samples)
    else:
        raise UserError("give a scene name, --blend FILE or --list")
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
    res = resolution or (scene.render.resolution_x, scene.render.resolution_y)
    configure_cycles(scene, resolution=res, samples=samples or scene.cycles.samples, seed=seed)
    return render_to_array(scene)
