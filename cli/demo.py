"""``demo``: render every library scene into ``out/`` and compose ``out/library.png``."""

from __future__ import annotations

import argparse
import os
import sys
import time

from .checks import UsageError, between

WIDTH = 640  # the showcase's picture size; heights follow each scene's aspect
PREVIEW_SAMPLES = 16  # Cycles samples of a material preview (denoised)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render the sample library into out/ with a contact sheet")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--only", nargs="*", default=None, help="render only these scenes / library materials")
    p.add_argument("--width", type=between(64, 4096, int), default=WIDTH,
                   help=f"image width in pixels (default {WIDTH})")
    p.add_argument("--samples", type=between(1, 1 << 24, int), default=None,
                   help=f"Cycles samples per pixel (default: {PREVIEW_SAMPLES} for the material previews, each "
                        "scene's own for the scenes)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from ..showcase import library
    from ..showcase.contact_sheet import contact_sheet

    # Every library material on the standard preview stage, then the showcase scenes.
    items = [("material", n) for n in library.available_materials()] + [
        ("scene", n) for n in library.available_scenes()
    ]
    if args.only:
        known = {n for _, n in items}
        unknown = sorted(set(args.only) - known)
        if unknown:
            raise UsageError(f"unknown scene(s)/material(s) {unknown}; available: {sorted(known)}")
        items = [it for it in items if it[1] in args.only]
    os.makedirs(args.out, exist_ok=True)
    import tempfile

    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="material-structures-demo-") as workdir:  # the scenes' textures
        images, labels = _render_all(library, items, workdir, args)
    sheet = contact_sheet(images, labels)
    sheet_path = os.path.join(args.out, "library.png")
    sheet.save(sheet_path)
    print(f"{len(items)} images in {time.monotonic() - start:.1f} s -> {sheet_path}")
    return 0


def _render_all(library, items, workdir: str, args: argparse.Namespace) -> tuple[list, list]:
    """Render every (kind, name) of ``items`` into ``args.out`` (EXR and PNG); their pixels and labels."""
    from tqdm import tqdm

    from .render import save_image

    images, labels = [], []
    for kind, name in tqdm(items, desc="rendering library", unit="image", file=sys.stderr):
        slug = "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")
        exr = os.path.join(args.out, f"{kind}-{slug}.exr")
        if kind == "material":
            res = (args.width, args.width * 3 // 4)
            rgba = library.render_material_preview(name, workdir, res, args.samples or PREVIEW_SAMPLES, exr,
                                                   denoise=True)
            label = f"{library.MATERIALS[name].catalog.split('/')[0]}: {library.MATERIALS[name].label}"
        else:
            entry = library.SCENES[name]
            res = (args.width, max(8, round(args.width * entry.resolution[1] / entry.resolution[0])))
            rgba = library.render_library_scene(name, workdir, res, args.samples, exr, denoise=True)
            label = entry.label
        save_image(exr[:-4] + ".png", rgba)
        images.append(rgba)
        labels.append(label)
    return images, labels
