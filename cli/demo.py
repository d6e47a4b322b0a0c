"""``demo``: render every library scene into ``out/`` and compose ``out/library.png``."""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..core.errors import UserError
from .checks import between

WIDTH = 640  # the showcase's picture size; heights follow each scene's aspect


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render the sample library into out/ with a contact sheet")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--only", nargs="*", default=None, help="render only these scenes / library materials")
    p.add_argument("--width", type=between(64, 4096, int), default=WIDTH,
                   help=f"image width in pixels (default {WIDTH})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from tqdm import tqdm

    from ..showcase import library
    from ..showcase.contact_sheet import contact_sheet
    from .render import save_image

    # Every library material on the standard preview stage, then the showcase scenes.
    items = [("material", n) for n in library.available_materials()] + [
        ("scene", n) for n in library.available_scenes()
    ]
    if args.only:
        known = {n for _, n in items}
        unknown = sorted(set(args.only) - known)
        if unknown:
            raise UserError(f"unknown scene(s)/material(s) {unknown}; available: {sorted(known)}")
        items = [it for it in items if it[1] in args.only]
    os.makedirs(args.out, exist_ok=True)
    workdir = os.path.join(args.out, "work")
    images, labels = [], []
    start = time.monotonic()
    for kind, name in tqdm(items, desc="rendering library", unit="image", file=sys.stderr):
        slug = "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")
        exr = os.path.join(args.out, f"{kind}-{slug}.exr")
        if kind == "material":
            res = (args.width, args.width * 3 // 4)
            rgba = library.render_material_preview(name, workdir, res, 16, exr, denoise=True)
            label = f"{library.MATERIALS[name].catalog.split('/')[0]}: {library.MATERIALS[name].label}"
        else:
            entry = library.SCENES[name]
            res = (args.width, max(8, round(args.width * entry.resolution[1] / entry.resolution[0])))
            rgba = library.render_library_scene(name, workdir, res, None, exr, denoise=True)
            label = entry.label
        save_image(exr[:-4] + ".png", rgba)
        images.append(rgba)
        labels.append(label)
    sheet = contact_sheet(images, labels)
    sheet_path = os.path.join(args.out, "library.png")
    sheet.save(sheet_path)
    print(f"{len(items)} images in {time.monotonic() - start:.1f} s -> {sheet_path}")
    return 0
