"""Built-in library scenes: the OSL pipeline test card and the grey studio ball."""

from __future__ import annotations

import os

import bpy
import numpy as np

from ..core.exr_io import write_exr
from ..render import (
    add_orthographic_camera,
    add_textured_plane,
    ensure_node_tree,
    link_uv,
    load_osl_script,
    material_output,
    new_material,
    osl_flip_t,
)
from .registry import LibraryScene, register_scene
from .stage import add_studio_stage


def test_card_texels(size: int = 8) -> np.ndarray:
    """A small float colour chart: hue across columns, brightness up the rows (row 0 = top)."""
    cols = np.linspace(0.0, 1.0, size, endpoint=False)
    rows = np.linspace(1.0, 0.1, size)
    phase = 2.0 * np.pi * cols
    rgb = 0.5 + 0.5 * np.stack([np.cos(phase), np.cos(phase - 2.094), np.cos(phase + 2.094)], axis=-1)
    return (rows[:, None, None] * rgb[None, :, :]).astype(np.float32)


def build_test_card(scene, workdir: str) -> None:
    """The OSL pipeline test card: an exact per-texel EXR lookup shown as emission."""
    path = os.path.abspath(os.path.join(workdir, "test_card_texels.exr"))
    texels = test_card_texels()
    write_exr(path, texels)
    mat = new_material("MS Test Card")
    tree = mat.node_tree
    node = load_osl_script(
        tree,
        "ms_texel_lookup",
        scene,
        inputs=["File", "UV", "Width", "Height", "FlipT"],
        outputs=["Emission"],
    )
    node.inputs["File"].default_value = path
    node.inputs["Height"].default_value, node.inputs["Width"].default_value = texels.shape[:2]
    node.inputs["FlipT"].default_value = osl_flip_t()
    link_uv(tree, node)
    tree.links.new(node.outputs["Emission"], material_output(mat).inputs["Surface"])
    mat.cycles.emission_sampling = "NONE"
    add_textured_plane(scene, 2.0, mat)
    add_orthographic_camera(scene, 2.0 * max(1.0, scene.render.resolution_x / scene.render.resolution_y))


def build_studio_ball(scene, workdir: str) -> None:
    """A principled shader ball under an area lamp: the preview stage materials are shown on."""
    add_studio_stage(scene)
    mat = bpy.data.materials.new("MS Studio Grey")
    bsdf = next(n for n in ensure_node_tree(mat).nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.6, 0.6, 0.62, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.35
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0.0, 0.0, 0.8), segments=48, ring_count=24)
    ball = bpy.context.active_object
    ball.data.materials.append(mat)
    for poly in ball.data.polygons:
        poly.use_smooth = True


register_scene(LibraryScene("test-card", "OSL test card", build_test_card, resolution=(128, 128), samples=4))
register_scene(LibraryScene("studio-ball", "Studio ball (grey)", build_studio_ball, samples=32))
