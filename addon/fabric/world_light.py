"""The fabric's exact world light: the scene's world environment handed to the fabric shader.

Cycles gives OSL no access to the world, so the add-on reads it here: a world whose surface is a
Background node fed by a constant colour or by an equirectangular Environment Texture, the latter
optionally through Texture Coordinate (Generated) -> Mapping (a rotation, uniform scale). Its radiance
becomes the importance-sampling tables of ``core.fabric.environment_sampling`` (piecewise constant,
at most 1024 texels wide), written as two EXRs into a content-addressed folder
``<tempdir>/material_structures_world-<user>/<sha1>/`` (identical content -> identical path, so
OpenImageIO's texture cache never serves stale tables; a reopened file re-extracts them), and the
folder goes into the script nodes' ``WorldTable`` input; the Background's strength and the Mapping's
rotation go into ``WorldStrength`` and ``WorldAxis*``, so turning or dimming the world rebuilds
nothing. Any other world (a sky texture, other mappings, mixes) leaves ``WorldTable`` empty, and the
fabric takes world light through its fitted closures as before; :func:`world_light_status` says
which, for the material panel. Tables are only made where they render (Cycles with OSL).
"""

from __future__ import annotations

import hashlib
import os
import tempfile

import numpy as np

from ...core.exr_io import write_exr
from ...core.fabric.environment_sampling import EnvironmentMapError, build_environment_table, shader_files
from ...render import blender_version, osl_flip_t
from ..lamp_sync import set_if_changed

CACHE_DIR = "material_structures_world"
_cache: dict = {}  # world key -> (folder, width, height, status); folder "" when it cannot be sampled


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
    space = image.colorspace_settings.name
    if not image.is_float:
        if space == "sRGB":
            rgb = _srgb_to_linear(rgb).astype(np.float32)
        elif space not in {"Non-Color", "Linear Rec.709", "Linear", "Raw"}:
            raise EnvironmentMapError(f"the world's 8-bit image '{image.name}' is in the {space} colour space; "
                                      "use an HDR image, or sRGB / Non-Color")
    return rgb


def _euler_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """Blender's XYZ Euler rotation matrix (X applied first)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx


def _mapping_rotation(vector_socket):
    """M with lookup direction = M d for the Environment Texture's Vector input: the identity when
    unlinked, a rotation for Texture Coordinate (Generated) -> Mapping (rotation, uniform scale, no
    offset); a reason string for anything else."""
    if not vector_socket.is_linked:
        return np.eye(3)
    link = vector_socket.links[0]
    node = link.from_node
    if node.type == "TEX_COORD" and link.from_socket.name == "Generated":
        return np.eye(3)
    if node.type != "MAPPING" or node.vector_type not in {"POINT", "VECTOR", "TEXTURE"}:
        return "the world's Environment Texture has a mapping other than a rotation"
    ins = node.inputs
    if any(ins[name].is_linked for name in ("Rotation", "Scale") if name in ins) or (
            "Location" in ins and ins["Location"].is_linked):
        return "the world's Mapping node is driven by other nodes"
    src = ins["Vector"].links[0] if ins["Vector"].is_linked else None
    if src is None or src.from_node.type != "TEX_COORD" or src.from_socket.name != "Generated":
        return "the world's Mapping node does not map the Generated direction"
    scale = np.asarray(ins["Scale"].default_value, float)
    if np.any(scale <= 0) or np.ptp(scale) > 1e-6 * scale.max():
        return "the world's Mapping node scales unevenly"
    if node.vector_type != "VECTOR" and np.any(np.asarray(ins["Location"].default_value) != 0):
        return "the world's Mapping node moves the direction"
    r = _euler_xyz(*ins["Rotation"].default_value)
    return r.T if node.vector_type == "TEXTURE" else r


def _world_background(world):
    """The node feeding the active World Output's Surface; None for a world without nodes (a colour),
    or a reason string when nothing feeds it."""
    tree = world.node_tree
    if tree is None or (blender_version()[0] < 5 and not world.use_nodes):  # 5.x worlds always use nodes
        return None
    out = next((n for n in tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None)
    out = out or next((n for n in tree.nodes if n.type == "OUTPUT_WORLD"), None)
    surface = out.inputs["Surface"] if out is not None else None
    if surface is None or not surface.is_linked:
        return "the world has no surface"
    return surface.links[0].from_node


def _world_source(scene):
    """(key, radiance loader, M) of the scene's world, or (None, reason, identity) when the shader cannot
    sample it."""
    eye = np.eye(3)
    world = scene.world
    if world is None:
        return None, "no world", eye
    bg = _world_background(world)
    if bg is None:
        color = tuple(float(c) for c in world.color)
        return ("color", color), lambda: np.broadcast_to(np.float32(color), (2, 4, 3)).copy(), eye
    if isinstance(bg, str):
        return None, bg, eye
    if bg.type != "BACKGROUND" or bg.inputs["Strength"].is_linked:
        return None, "the world is not a Background node with a fixed strength", eye
    col = bg.inputs["Color"]
    if not col.is_linked:
        color = tuple(float(c) for c in col.default_value[:3])
        return ("color", color), lambda: np.broadcast_to(np.float32(color), (2, 4, 3)).copy(), eye
    tex = col.links[0].from_node
    if tex.type != "TEX_ENVIRONMENT" or tex.projection != "EQUIRECTANGULAR" or tex.image is None:
        return None, "the world's colour is not an equirectangular Environment Texture", eye
    rotation = _mapping_rotation(tex.inputs["Vector"])
    if isinstance(rotation, str):
        return None, rotation, eye
    image = tex.image
    key = ("image", image.name, image.filepath, tuple(image.size), image.is_dirty, image.colorspace_settings.name,
           _file_version(image))
    return key, lambda: _image_radiance(image), rotation


def _file_version(image) -> tuple:
    """What changes when the image's file is replaced on disk (so Image > Reload of an edited HDRI gives new
    tables): its modification time and size; the packed size for a packed image."""
    if image.packed_file is not None:
        return ("packed", image.packed_file.size)
    import bpy

    try:
        st = os.stat(bpy.path.abspath(image.filepath, library=image.library))
    except (OSError, ValueError):
        return ()
    return (st.st_mtime_ns, st.st_size)


def world_strength(scene) -> float:
    """The world Background's strength (1 for a world without nodes)."""
    bg = _world_background(scene.world) if scene.world is not None else None
    if bg is None or isinstance(bg, str) or bg.type != "BACKGROUND":
        return 1.0
    return float(bg.inputs["Strength"].default_value)


def _write_tables(radiance: np.ndarray):
    table = build_environment_table(radiance)
    if table is None:
        return None, 0, 0
    files = shader_files(table)
    digest = hashlib.sha1()
    for name in sorted(files):
        digest.update(np.ascontiguousarray(files[name]).tobytes())
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    folder = os.path.join(tempfile.gettempdir(), f"{CACHE_DIR}-{user}", digest.hexdigest()[:20])
    os.makedirs(folder, exist_ok=True)
    for name, arr in files.items():
        path = os.path.join(folder, name)
        if not os.path.exists(path):
            write_exr(path, arr)  # written under a temporary name, then renamed
    os.utime(folder)  # in use: kept by _prune_tables of every session
    _prune_tables(os.path.dirname(folder), keep=folder)
    h, w = table.shape
    return folder, w, h


PRUNE_AFTER_S = 14 * 24 * 3600  # table folders no session has used for this long are removed


def _prune_tables(root: str, keep: str, now: float | None = None) -> None:
    """Remove the table folders under ``root`` unused for ``PRUNE_AFTER_S`` (each HDRI ever lit with
    leaves up to 12 MB here); ``keep`` and anything that cannot be removed stay."""
    import shutil
    import time

    now = time.time() if now is None else now
    try:
        entries = list(os.scandir(root))
    except OSError:
        return
    for entry in entries:
        try:
            if entry.path != keep and entry.is_dir(follow_symlinks=False) and \
                    now - entry.stat(follow_symlinks=False).st_mtime > PRUNE_AFTER_S:
                shutil.rmtree(entry.path, ignore_errors=True)
        except OSError:
            continue


def world_light_inputs(scene, build: bool = True, tables: bool = True):
    """(folder, width, height, status, M, strength) of the scene's world, parsed once: the tables'
    folder ("" when the shader cannot sample the world, status says why, or the world is black),
    the lookup rotation M (lookup direction = M d) and the Background's strength. ``build=False``
    (panels) only reads what the last sync made; ``tables=False`` (no Cycles + OSL) makes none. A
    failure (a bad image, a full disk) is remembered for that world, so it is tried again only when
    the world changes."""
    key, load, rotation = _world_source(scene)
    strength = world_strength(scene)
    if not tables:
        return "", 0, 0, "not rendered with Cycles and OSL", rotation, strength
    if key is None:
        return "", 0, 0, load, rotation, strength
    if not strength > 0:
        return "", 0, 0, "the world is black", rotation, strength
    hit = _cache.get(key)
    if hit is None and not build:
        return "", 0, 0, "tables are made at the next render", rotation, strength
    if hit is None or (hit[0] and not all(os.path.exists(os.path.join(hit[0], f))
                                          for f in ("radiance.exr", "alias.exr"))):
        try:
            folder, w, h = _write_tables(load())
            status = f"exact ({w} x {h} environment)" if folder else "the world is black"
        except EnvironmentMapError as exc:
            folder, w, h, status = None, 0, 0, str(exc)
        except (OSError, MemoryError, ValueError) as exc:  # temp folder, disk, EXR writer
            folder, w, h, status = None, 0, 0, f"the world's tables could not be written ({exc})"
        hit = (folder or "", w, h, status)
        _cache.clear()  # one world at a time is plenty
        _cache[key] = hit
    return (*hit, rotation, strength)


def world_tables(scene, build: bool = True) -> tuple[str, int, int, str]:
    """(folder, width, height, status) of :func:`world_light_inputs`."""
    return world_light_inputs(scene, build)[:4]


def write_world_inputs(node, folder: str, width: int, height: int, rotation=None, strength: float = 1.0) -> None:
    """Point a fabric script node at the world tables; ``rotation`` M (lookup direction = M d) goes in
    as its rows (an older node without the inputs is skipped); an unchanged world writes nothing
    (``lamp_sync.set_if_changed``)."""
    if "WorldTable" not in node.inputs:
        return
    m = np.eye(3) if rotation is None else np.asarray(rotation, float)
    values = {"WorldTable": folder, "WorldWidth": width, "WorldHeight": height, "FlipT": osl_flip_t(),
              "WorldStrength": float(strength),
              "WorldAxisX": tuple(m[0]), "WorldAxisY": tuple(m[1]), "WorldAxisZ": tuple(m[2])}
    for name, value in values.items():
        if name in node.inputs:
            set_if_changed(node, name, value)


def world_light_status(scene) -> str:
    """One line for the panel: how world light reaches the fabric."""
    folder, _w, _h, status = world_tables(scene, build=False)
    if not folder and status.startswith("tables are made"):
        return f"World light: exact ({status})"
    return f"World light: {status}" if folder else f"World light: fitted closures ({status})"
