"""``demo``: render every library scene into ``out/`` and compose ``out/library.png``."""

from __future__ import annotations

import argparse
import os
import sys
import time


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="render the sample library into out/ with a contact sheet")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--only", nargs="*", default=None, help="render only these scenes")
    p.add_argument("--scale", type=float, default=1.0, help="resolution scale factor")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from tqdm import tqdm

    from ..render import library
    from ..render.contact_sheet import contact_sheet
    from .render import save_image

    names = args.only or library.available_scenes()
    unknown = sorted(set(names) - set(library.available_scenes()))
    if unknown:
        raise ValueError(f"unknown scene(s) {unknown}; available: {library.available_scenes()}")
    os.makedirs(args.out, exist_ok=True)
    workdir = os.path.join(args.out, "work")
    images, labels = [], []
    start = time.monotonic()
    for name in tqdm(names, desc="rendering library", unit="scene", file=sys.stderr):
        entry = library.SCENES[name]
        res = tuple(max(8, int(round(v * args.scale))) for v in entry.resolution)
        rgba = library.render_library_scene(name, workdir, res, None, os.path.join(args.out, f"{name}.exr"))
        save_image(os.path.join(args.out, f"{name}.png"), rgba)
        images.append(rgba)
        labels.append(entry.label)
    sheet = contact_sheet(images, labels)
    sheet_path = os.path.join(args.out, "library.png")
    sheet.save(sheet_path)
    print(f"{len(names)} scenes in {time.monotonic() - start:.1f} s -> {sheet_path}")
    return 0
