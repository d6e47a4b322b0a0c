"""The scene's world as an environment: what the shaders that sample world light themselves read.

Cycles gives OSL no access to the world, so the add-on reads it: a world whose surface is a Background
node fed by a constant colour or by an equirectangular Environment Texture, the latter optionally
through Texture Coordinate (Generated) -> Mapping (a rotation, uniform scale). :func:`world_source`
gives a key that changes with what the world shows (not with its strength or rotation), a loader of
its linear radiance and the lookup rotation M (lookup direction = M d), or why it cannot be read.
Users: the fabric's exact world light (``fabric/world_light.py``) and the scratch term's world lamps
(``scratch/world.py``).
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

from ..core.fabric.environment_sampling import EnvironmentMapError
from ..render import blender_version


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def image_radiance(image) -> np.ndarray:
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
            rgb = srgb_to_linear(rgb).astype(np.float32)
        elif space not in {"Non-Color", "Linear Rec.709", "Linear", "Raw"}:
            raise EnvironmentMapError(f"the world's 8-bit image '{image.name}' is in the {space} colour space; "
                                      "use an HDR image, or sRGB / Non-Color")
    return rgb


def euler_xyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """Blender's XYZ Euler rotation matrix (X applied first)."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    mx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    my = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    mz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return mz @ my @ mx


def mapping_rotation(vector_socket):
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
    r = euler_xyz(*ins["Rotation"].default_value)
    return r.T if node.vector_type == "TEXTURE" else r


def world_background(world):
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


def world_source(scene):
    """(key, radiance loader, M) of the scene's world, or (None, reason, identity) when the shader cannot
    sample it."""
    eye = np.eye(3)
    world = scene.world
    if world is None:
        return None, "no world", eye
    bg = world_background(world)
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
    rotation = mapping_rotation(tex.inputs["Vector"])
    if isinstance(rotation, str):
        return None, rotation, eye
    image = tex.image
    key = ("image", image.name, image.filepath, tuple(image.size), image.colorspace_settings.name,
           file_version(image), edit_version(image))
    return key, lambda: image_radiance(image), rotation


def file_version(image) -> tuple:
    """What tells the image's stored pixels from another's and changes when its file is replaced on disk (so
    Image > Reload of an edited HDRI gives new tables): the file's absolute path, modification time and size; a
    digest of a packed image's data (two files' packed images of one name and size are different images), taken
    once per packed data (packing again makes new data) until :func:`forget_packed` (a load, an undo)."""
    if image.packed_file is not None:
        ptr = image.packed_file.as_pointer()
        digest = _packed_digests.get(ptr)
        if digest is None:
            digest = _packed_digests[ptr] = hashlib.blake2b(image.packed_file.data, digest_size=16).hexdigest()
        return ("packed", image.packed_file.size, digest)
    import bpy

    path = image.filepath
    try:
        path = bpy.path.abspath(path, library=image.library)
        st = os.stat(path)
    except (OSError, ValueError):
        return (path,)
    return (path, st.st_mtime_ns, st.st_size)


def edit_version(image) -> tuple:
    """What changes when the image's pixels are edited in memory (painted, set from Python, generated): for an
    image with unsaved edits, a digest of its pixels. The digest is taken once and kept until
    :func:`forget_edits` (an update of the image, every render, undo, load): a lamp drag does not read the
    pixels on every step, and a render always sees the pixels as they are."""
    if not (image.is_dirty or image.source == "GENERATED"):
        return ()
    ptr = image.as_pointer()
    digest = _edit_digests.get(ptr)
    if digest is None:
        w, h = image.size
        buf = np.empty(w * h * image.channels, dtype=np.float32)
        if buf.size:
            image.pixels.foreach_get(buf)
        digest = hashlib.blake2b(buf, digest_size=16).hexdigest()
        _edit_digests[ptr] = digest
    return ("edits", digest)


_edit_digests: dict[int, str] = {}  # image pointer -> digest of its pixels (images with unsaved edits)
_packed_digests: dict[int, str] = {}  # packed file pointer -> digest of its data


def forget_edits(image=None) -> None:
    """Drop the pixel digest of ``image`` (of every image when None): the next key reads its pixels again."""
    if image is None:
        _edit_digests.clear()
    else:
        _edit_digests.pop(image.as_pointer(), None)


def forget_packed() -> None:
    """Drop the packed data's digests (a file opened, an undo: the pointers may name other data now)."""
    _packed_digests.clear()


def world_strength(scene) -> float:
    """The world Background's strength (1 for a world without nodes)."""
    bg = world_background(scene.world) if scene.world is not None else None
    if bg is None or isinstance(bg, str) or bg.type != "BACKGROUND":
        return 1.0
    return float(bg.inputs["Strength"].default_value)
