"""The fabric's exact world light: the scene's world environment handed to the fabric shader.

Cycles gives OSL no access to the world, so the add-on reads it here: a world whose surface is a
Background node fed by a constant colour or by an equirectangular Environment Texture (no mapping).
Its radiance (colour x strength) becomes the importance-sampling tables of
``core.fabric.environment_sampling``, written as two EXRs into a content-addressed folder
``<tempdir>/material_structures_world/<sha1>/`` (identical content -> identical path, so OpenImageIO's
texture cache never serves stale tables; a reopened file re-extracts them), and the folder goes into
the script nodes' ``WorldTable`` input. Any other world (a sky texture, mapping nodes, mixes) leaves
``WorldTable`` empty, and the fabric takes world light through its fitted closures as before;
:func:`world_light_status` says which, for the material panel.
"""

from __future__ import annotations

import hashlib
import os
import tempfile

import numpy as np

from ...core.exr_io import write_exr
from ...core.fabric.environment_sampling import EnvironmentMapError, build_environment_table, shader_files
from ...render import blender_version, osl_flip_t

CACHE_DIR = "material_structures_world"
_cache: dict = {}  # world key -> (folder, width, height) or (None, reason)


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _image_radiance(image) -> np.ndarray:
    """An image's pixels as linear RGB (H, W, 3), row 0 = bottom."""
    w, h = image.size
    if w == 0 or h == 0:
        raise EnvironmentMapError(f"the world's image '{image.name}' has no pixels (file missing?)")
    buf = np.empty(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(buf)
    px = buf.reshape(h, w, image.channels)
    rgb = px[..., :3] if image.channels >= 3 else np.repeat(px[..., :1], 3, axis=2)
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        rgb = _srgb_to_linear(rgb.astype(np.float64)).astype(np.float32)
    return rgb


def _world_source(scene):
    """(key, radiance loader) of the scene's world, or (None, reason) when the shader cannot sample it."""
    world = scene.world
    if world is None:
        return None, "no world"
    tree = world.node_tree
    if blender_version()[0] < 5 and not world.use_nodes:  # 5.x worlds always use their nodes
        tree = None
    if tree is None:
        color = tuple(float(c) for c in world.color)
        return ("color", color), lambda: np.broadcast_to(np.float32(color), (2, 4, 3)).copy()
    out = next((n for n in tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None)
    out = out or next((n for n in tree.nodes if n.type == "OUTPUT_WORLD"), None)
    surface = out.inputs["Surface"] if out is not None else None
    if surface is None or not surface.is_linked:
        return None, "the world has no surface"
    bg = surface.links[0].from_node
    if bg.type != "BACKGROUND" or bg.inputs["Strength"].is_linked:
        return None, "the world is not a Background node with a fixed strength"
    strength = float(bg.inputs["Strength"].default_value)
    col = bg.inputs["Color"]
    if not col.is_linked:
        color = tuple(float(c) * strength for c in col.default_value[:3])
        return ("color", color), lambda: np.broadcast_to(np.float32(color), (2, 4, 3)).copy()
    tex = col.links[0].from_node
    if tex.type != "TEX_ENVIRONMENT" or tex.projection != "EQUIRECTANGULAR" or tex.image is None:
        return None, "the world's colour is not an equirectangular Environment Texture"
    if tex.inputs["Vector"].is_linked:
        return None, "the world's Environment Texture has a mapping"
    image = tex.image
    key = ("image", image.name, image.filepath, tuple(image.size), image.is_dirty,
           image.colorspace_settings.name, strength)
    return key, lambda: _image_radiance(image) * np.float32(strength)


def _write_tables(radiance: np.ndarray):
    table = build_environment_table(radiance)
    if table is None:
        return None, 0, 0
    files = shader_files(table)
    digest = hashlib.sha1()
    for name in sorted(files):
        digest.update(np.ascontiguousarray(files[name]).tobytes())
    folder = os.path.join(tempfile.gettempdir(), CACHE_DIR, digest.hexdigest()[:20])
    os.makedirs(folder, exist_ok=True)
    for name, arr in files.items():
        path = os.path.join(folder, name)
        if not os.path.exists(path):
            write_exr(path, arr)  # written under a temporary name, then renamed
    h, w = table.shape
    return folder, w, h


def world_tables(scene, build: bool = True) -> tuple[str, int, int, str]:
    """(folder, width, height, status) of the scene's world tables; folder "" when the shader cannot
    sample the world (status says why) or the world is black. ``build=False`` (panels) only reads
    what the last sync made."""
    key, load = _world_source(scene)
    if key is None:
        return "", 0, 0, load
    hit = _cache.get(key)
    if hit is None and not build:
        return "", 0, 0, "tables are made at the next render"
    if hit is None or (hit[0] and not all(os.path.exists(os.path.join(hit[0], f))
                                          for f in ("radiance.exr", "alias.exr"))):
        try:
            folder, w, h = _write_tables(load())
        except EnvironmentMapError as exc:
            return "", 0, 0, str(exc)
        hit = (folder or "", w, h)
        _cache.clear()  # one world at a time is plenty
        _cache[key] = hit
    folder, w, h = hit
    if not folder:
        return "", 0, 0, "the world is black"
    return folder, w, h, f"exact ({w} x {h} environment)"


def write_world_inputs(node, folder: str, width: int, height: int) -> None:
    """Point a fabric script node at the world tables (an older node without the inputs is skipped)."""
    if "WorldTable" not in node.inputs:
        return
    values = {"WorldTable": folder, "WorldWidth": width, "WorldHeight": height, "FlipT": osl_flip_t()}
    for name, value in values.items():
        if node.inputs[name].default_value != value:
            node.inputs[name].default_value = value


def world_light_status(scene) -> str:
    """One line for the panel: how world light reaches the fabric."""
    folder, _w, _h, status = world_tables(scene, build=False)
    if not folder and status.startswith("tables"):
        return f"World light: exact ({status})"
    return f"World light: {status}" if folder else f"World light: fitted closures ({status})"
