"""Write the artist material library: a .blend of asset-marked materials with catalogs and previews.

Layout of the library folder (a Blender asset library; register it in Preferences > File Paths):

    material_structures_library.blend   materials marked as assets, images packed
    blender_assets.cats.txt             the catalogs (Fabric/Velvet, Metal/..., Teeth/...)
    previews/<name>.png                 the rendered previews (also loaded as asset previews)

A build at the default preview size and samples copies each material's stored preview
(``showcase/previews/<name>.png``, written by ``library previews``) instead of rendering it: the ten
previews take about 100 s of Cycles (the three dentin shades about 15 s each, the volume set-up of their
tooth), and a build runs before every bare-Blender test stage. A material without a stored preview, another
size or sample count, or ``library build --render-previews`` renders. ``make test-all`` renders every
preview again and compares it with the stored one.
"""

from __future__ import annotations

import os
import shutil
import sys
import uuid

import bpy
from PIL import Image

from ..addon.teeth.materials import gate_for_linking
from ..core.imaging import to_display_uint8
from ..render import reset_scene
from .library import MATERIALS, available_materials, render_material_preview

LIBRARY_BLEND = "material_structures_library.blend"
CATALOG_FILE = "blender_assets.cats.txt"
_NAMESPACE = uuid.UUID("6f1c2b1e-3f6a-4d8e-9a51-7d1e5b0c9a42")
PREVIEW_SIZE = 128  # pixels, width = height
PREVIEW_SAMPLES = 16
STORED_PREVIEWS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "previews")


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


def _with_progress(names: list[str], progress: bool):
    if not progress:
        return names
    from tqdm import tqdm  # not in a desktop Blender: only for the progress bar

    return tqdm(names, desc="library previews", unit="material", file=sys.stderr)


def preview_file_name(name: str) -> str:
    return f"{_slug(name)}.png"


def stored_preview(name: str, preview_size: int = PREVIEW_SIZE, samples: int = PREVIEW_SAMPLES,
                   folder: str = STORED_PREVIEWS) -> str | None:
    """The stored preview of library material ``name``, or None where there is none or the build asks for
    another size or sample count than the stored previews were rendered with."""
    if (preview_size, samples) != (PREVIEW_SIZE, PREVIEW_SAMPLES):
        return None
    path = os.path.join(folder, preview_file_name(name))
    return path if os.path.isfile(path) else None


def render_preview_png(name: str, work: str, path: str, preview_size: int = PREVIEW_SIZE,
                       samples: int = PREVIEW_SAMPLES) -> str:
    """Render ``name``'s preview into the PNG ``path`` (written under a temporary name, then renamed)."""
    rgba = render_material_preview(name, work, (preview_size, preview_size), samples)
    tmp = f"{path}.tmp-{os.getpid()}.png"
    Image.fromarray(to_display_uint8(rgba)).save(tmp)
    os.replace(tmp, path)
    return path


def store_previews(folder: str = STORED_PREVIEWS, progress: bool = True) -> list[str]:
    """Render every library material's preview at the default size and samples into ``folder`` (the previews
    a build copies); returns the paths."""
    os.makedirs(folder, exist_ok=True)
    work = os.path.join(folder, ".work")
    try:
        return [render_preview_png(n, work, os.path.join(folder, preview_file_name(n)))
                for n in _with_progress(available_materials(), progress)]
    finally:
        shutil.rmtree(work, ignore_errors=True)


def build_asset_library(folder: str, preview_size: int = PREVIEW_SIZE, samples: int = PREVIEW_SAMPLES,
                        progress: bool = True, render_previews: bool = False) -> str:
    """Write the library .blend with its previews (the stored ones where they apply, unless
    ``render_previews``); returns its path."""
    os.makedirs(os.path.join(folder, "previews"), exist_ok=True)
    work = os.path.join(folder, ".work")
    names = available_materials()
    previews = {}
    for name in _with_progress(names, progress):
        path = os.path.join(folder, "previews", preview_file_name(name))
        stored = None if render_previews else stored_preview(name, preview_size, samples)
        if stored is not None:
            shutil.copyfile(stored, path)
        else:
            render_preview_png(name, work, path, preview_size, samples)
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
    # a shade linked from the library still hands its medium to its tooth's Blend Volume: the save's handler gates
    # the groups too, but only where the extension's handlers are registered; this build must not depend on that
    gate_for_linking()
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
