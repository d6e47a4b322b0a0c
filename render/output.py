"""Render to a float EXR and read it back (the module build's Render Result has no pixels)."""

from __future__ import annotations

import os
import tempfile

import numpy as np

from ..core.exr_io import read_exr
from .scene import material_output, new_material


def render_to_array(scene=None, path: str | None = None, channels: str = "RGBA") -> np.ndarray:
    """Render ``scene`` with Cycles into a 32-bit EXR at ``path`` (a temp file when None) and return
    its pixels as float32 ``(H, W, C)``, row 0 = top of the image."""
    import bpy

    scene = scene or bpy.context.scene
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # 5.x groups formats by media type
        settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    settings.color_mode = "RGBA" if "A" in channels else "RGB"
    settings.exr_codec = "ZIP"
    scene.render.use_file_extension = False
    cleanup = path is None
    if path is None:
        fd, path = tempfile.mkstemp(suffix=".exr", prefix="ms-render-")
        os.close(fd)
    scene.render.filepath = path
    try:
        bpy.ops.render.render(write_still=True, scene=scene.name)
        return read_exr(path, channels=list(channels), allow_nan=True)
    finally:
        if cleanup and os.path.exists(path):
            os.remove(path)


def render_positions(scene, obj) -> np.ndarray:
    """``obj`` re-rendered with emission = its shading position (world space), film transparent:
    (H, W, 4), alpha = coverage. The points a verification evaluates its reference at."""
    mat = new_material("Position")
    tree = mat.node_tree
    geo = tree.nodes.new("ShaderNodeNewGeometry")
    em = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(geo.outputs["Position"], em.inputs["Color"])
    tree.links.new(em.outputs[0], material_output(mat).inputs["Surface"])
    obj.data.materials[0] = mat
    scene.render.film_transparent = True
    return render_to_array(scene)
