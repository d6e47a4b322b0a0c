"""``library``: build the artist material library (Blender asset library) into ``samples/library``."""

from __future__ import annotations

import argparse
import os

from .checks import UsageError, between

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_DIR = os.path.join(ROOT, "samples", "library")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("library", help="build the material asset library (samples/library)")
    p.add_argument("action", choices=["build", "list", "previews"],
                   help="build the .blend + catalogs + previews, list the materials, or render the stored previews "
                        "that a build at the default size and samples copies (showcase/previews)")
    p.add_argument("--out", default=DEFAULT_DIR, help="library folder (default: samples/library)")
    p.add_argument("--preview-size", type=between(8, 4096, int), default=128,
                   help="asset preview width = height in pixels")
    p.add_argument("--samples", type=between(1, 1 << 24, int), default=16,
                   help="Cycles samples per pixel of the previews")
    p.add_argument("--render-previews", action="store_true",
                   help="build: render every preview instead of copying the stored ones")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.action == "previews" and (args.preview_size, args.samples, args.render_previews) != (128, 16, False):
        raise UsageError("library previews renders the stored previews at 128 px and 16 samples: leave out "
                         "--preview-size, --samples and --render-previews")
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    from ..showcase.library import MATERIALS, available_materials

    if args.action == "list":
        for name in available_materials():
            print(f"{MATERIALS[name].catalog:28s} {name}")
        return 0
    from ..showcase import asset_library

    if args.action == "previews":
        for path in asset_library.store_previews():
            print(path)
        return 0
    print(asset_library.build_asset_library(args.out, args.preview_size, args.samples,
                                            render_previews=args.render_previews))
    return 0
