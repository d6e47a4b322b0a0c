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

Plus generic scene pieces (lamps, cameras aimed at a point, a textured plane, the position pass of the
verification renders). The harness knows no material feature: it never imports ``addon`` or
``showcase`` (``tests/core/test_structure.py``). Import this package only where ``bpy`` is available.
"""

from .osl import OslScriptError, link_uv, load_osl_script
from .output import render_positions, render_to_array
from .scene import (
    add_lamp,
    add_orthographic_camera,
    add_textured_plane,
    configure_cycles,
    dark_world,
    denoise_for_display,
    ensure_node_tree,
    look_from,
    material_output,
    new_material,
    point_along,
    reset_scene,
    view_direction,
)
from .session import blender_version, ensure_bundled_paths, osl_flip_t, osl_shader_path

__all__ = [
    "OslScriptError",
    "add_lamp",
    "add_orthographic_camera",
    "add_textured_plane",
    "blender_version",
    "configure_cycles",
    "denoise_for_display",
    "dark_world",
    "ensure_bundled_paths",
    "ensure_node_tree",
    "link_uv",
    "load_osl_script",
    "look_from",
    "material_output",
    "new_material",
    "osl_flip_t",
    "osl_shader_path",
    "point_along",
    "render_positions",
    "render_to_array",
    "reset_scene",
    "view_direction",
]
