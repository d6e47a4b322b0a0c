"""Write the artist material library: a .blend of asset-marked materials with catalogs and previews.

Layout of the library folder (a Blender asset library; register it in Preferences > File Paths):

    material_structures_library.blend   materials marked as assets, images packed
    blender_assets.cats.txt             the catalogs (Fabric/Velvet, Metal/..., Teeth/...)
    previews/<name>.png                 the rendered previews (also loaded as asset previews)
"""

from __future__ import annotations

import os
import sys
import uuid

import bpy
from PIL import Image

from ..core.imaging import to_display_uint8
from ..render import reset_scene
from .library import MATERIALS, available_materials, render_material_preview

LIBRARY_BLEND = "material_structures_library.blend"
CATALOG_FILE = "blender_assets.cats.txt"
_NAMESPACE = uuid.UUID("6f1c2b1e-3f6a-4d8e-9a51-7d1e5b0c9a42")


def catalog_uuid(path: str) -> str:
    """Stable catalog UUID per catalog path (so rebuilding keeps artists' catalog references)."""
    return str(uuid.uuid5(_NAMESPACE, path))


def write_catalogs(folder: str, paths: list[str]) -> str:
    """``blender_assets.cats.txt`` with every catalog path and its parents."""
    full: set[str] = set()
    for path in paths:
        parts = path.split("/")
        full.update("/".join(parts[: i + 1]) for i in range(len(parts)))
    lines = [
        "# This is an Asset Catalog Definition file for Blender.",
        "# Written by Material Structures (showcase/asset_library.py).",
        "VERSION 1",
        "",
    ]
    lines += [f"{catalog_uuid(p)}:{p}:{p.replace('/', '-')}" for p in sorted(full)]
    out = os.path.join(folder, CATALOG_FILE)
    with open(out, "w") as f:
        f.write("\n".join(lines) + "\n")
    return out


def build_asset_library(folder: str, preview_size: int = 128, samples: int = 16, progress: bool = True) -> str:
    """Render previews and write the library .blend; returns its path."""
    os.makedirs(os.path.join(folder, "previews"), exist_ok=True)
    work = os.path.join(folder, ".work")
    names = available_materials()
    previews = {}
    iterator = names
    if progress:
        from tqdm import tqdm  # not in a desktop Blender: only for the progress bar

        iterator = tqdm(names, desc="library previews", unit="material", file=sys.stderr)
    for name in iterator:
        rgba = render_material_preview(name, work, (preview_size, preview_size), samples)
        path = os.path.join(folder, "previews", f"{_slug(name)}.png")
        Image.fromarray(to_display_uint8(rgba)).save(path)
        previews[name] = path

    # The library file: only the materials (and what they use), each marked as an asset.
    scene = reset_scene()
    for name in names:
        entry = MATERIALS[name]
        mat = entry.build(scene, work)
        mat.name = entry.name
        mat.use_fake_user = True
        mat.asset_mark()
        mat.asset_data.catalog_id = catalog_uuid(entry.catalog)
        mat.asset_data.description = entry.description
        mat.asset_data.author = "Material Structures"
        with bpy.context.temp_override(id=mat):
            bpy.ops.ed.lib_id_load_custom_preview(filepath=previews[name])
    for image in bpy.data.images:
        if image.packed_file is None and image.source in {"GENERATED", "FILE"} and image.has_data:
            image.pack()
    write_catalogs(folder, [MATERIALS[n].catalog for n in names])
    out = os.path.join(folder, LIBRARY_BLEND)
    # Written under a temporary name, then renamed: no half-written library, and no ".blend1" backup
    # (Blender keeps one when saving over a file; the extension zip would ship it).
    tmp = os.path.join(folder, f".{LIBRARY_BLEND}.tmp-{os.getpid()}.blend")
    bpy.ops.wm.save_as_mainfile(filepath=tmp, compress=True, copy=True)
    os.replace(tmp, out)
    for stale in (out + "1", tmp + "1"):
        if os.path.exists(stale):
            os.remove(stale)
    return out


def _slug(name: str) -> str:
    return "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")
