"""``release``: the zips and a Blender extensions repository in one folder (``make release``).

Builds every platform's and Python's zip (``build``), removes zips of other versions of this extension from
the folder (a repository lists one release), and writes the repository index the way Blender writes it:
Blender's own ``server-generate`` (``blender_ext.py`` in the bpy wheel; ``blender --command extension
server-generate`` in a desktop Blender) makes ``index.json`` and a browsable ``index.html``. The folder served
by any static web server is then a repository: its ``index.json`` URL is what artists add under *Preferences >
Get Extensions > Repositories*; Blender picks the zip for its platform and Blender version and offers updates.
"""

from __future__ import annotations

import argparse
import glob
import os

from ..core.errors import UserError
from . import build


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("release", help="build every zip and Blender's repository index (index.json) into --out")
    build.add_build_options(p)
    p.set_defaults(func=run)


def write_index(folder: str) -> str:
    """Blender's repository index of the zips in ``folder`` (``index.json`` + ``index.html``); returns its path."""
    proc = build._tool("server-generate", "--repo-dir", folder, "--html")
    index = os.path.join(folder, "index.json")
    if proc.returncode != 0 or not os.path.isfile(index):
        raise RuntimeError(f"server-generate failed:\n{proc.stdout}{proc.stderr}")
    return index


def run(args: argparse.Namespace) -> int:
    out = os.path.abspath(args.out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise UserError(f"--out {args.out} is a file, not a folder")
    written = build.build_platforms(out, platforms=args.platform, pythons=args.python, version=args.set_version)
    manifest = build._manifest(build.ROOT)
    version = args.set_version or manifest["version"]
    for old in glob.glob(os.path.join(out, f"{manifest['id']}-*.zip")):
        if not os.path.basename(old).startswith(f"{manifest['id']}-{version}-"):
            os.remove(old)  # another version's zip: the repository lists one release
    for path in written:
        print(f"{path}  {os.path.getsize(path) / 2**20:.1f} MiB")
    print(write_index(out))
    return 0
