"""Headless Cycles render harness (needs ``bpy``).

Every module-build quirk from the platform notes is handled here, once:

* bundled site-packages (``oslquery``) on ``sys.path`` before any script node: :func:`ensure_bundled_paths`
* engine = Cycles and OSL enabled *before* a script's filepath is set, sockets asserted:
  :func:`load_osl_script`
* CPU, fixed seed, fixed samples, denoising off, tiny pixel filter: :func:`configure_cycles`
* a world that adds no light: :func:`dark_world`
* UV from a Texture Coordinate node (OSL ``u, v`` are not the UV map): :func:`link_uv`
* the empty ``Render Result``: render to a 32-bit EXR and read it back: :func:`render_to_array`
* texture ``t`` orientation differs between 5.x and 4.5: :func:`osl_flip_t`

Import this package only where ``bpy`` is available.
"""

from .osl import OslScriptError, link_uv, load_osl_script
from .output import render_to_array
from .scene import (
    add_orthographic_camera,
    add_textured_plane,
    configure_cycles,
    dark_world,
    ensure_node_tree,
    new_material,
    reset_scene,
)
from .session import blender_version, ensure_bundled_paths, osl_flip_t, osl_shader_path

__all__ = [
    "OslScriptError",
    "add_orthographic_camera",
    "add_textured_plane",
    "blender_version",
    "configure_cycles",
    "dark_world",
    "ensure_bundled_paths",
    "ensure_node_tree",
    "link_uv",
    "load_osl_script",
    "new_material",
    "osl_flip_t",
    "osl_shader_path",
    "render_to_array",
    "reset_scene",
]
