"""OSL through the render harness: compile, sockets, exact emission, texel orientation."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from material_structures import render as R
from material_structures.core.exr_io import write_exr
from material_structures.render.scene import material_output


def _emission_plane_scene(resolution, shader, **sockets):
    scene = R.reset_scene()
    R.configure_cycles(scene, resolution=resolution, samples=4, seed=1)
    R.dark_world(scene)
    mat = R.new_material("T")
    node = R.load_osl_script(mat.node_tree, shader, scene, inputs=list(sockets), outputs=["Emission"])
    for name, value in sockets.items():
        if name == "UV":
            R.link_uv(mat.node_tree, node)
        else:
            node.inputs[name].default_value = value
    mat.node_tree.links.new(node.outputs["Emission"], material_output(mat).inputs["Surface"])
    mat.cycles.emission_sampling = "NONE"
    R.add_textured_plane(scene, 2.0, mat)
    R.add_orthographic_camera(scene, 2.0)
    return scene


def test_constant_emission_renders_exactly():
    color = (0.125, 0.5, 2.75)
    scene = _emission_plane_scene((8, 8), "ms_constant_emission", Color=(*color, 1.0))
    img = R.render_to_array(scene)
    assert img.shape == (8, 8, 4)
    np.testing.assert_array_equal(img[..., :3], np.broadcast_to(np.float32(color), (8, 8, 3)))


def test_texel_lookup_exact_and_oriented(tmp_path):
    """4x4 texels with distinct values per texel and channel: each pixel shows its texel exactly.

    Row 0 of the file is the top row of the image (UV v = 1), on 5.2 and on 4.5.
    """
    rng = np.random.default_rng(7)
    texels = rng.uniform(0.0, 4.0, size=(4, 4, 3)).astype(np.float32)
    path = str(tmp_path / "texels.exr")
    write_exr(path, texels)
    scene = _emission_plane_scene(
        (4, 4), "ms_texel_lookup", File=path, UV=None, Width=4, Height=4, FlipT=R.osl_flip_t()
    )
    img = R.render_to_array(scene)
    np.testing.assert_array_equal(img[..., :3], texels)


def test_missing_socket_is_reported():
    scene = bpy.context.scene
    mat = R.new_material("T")
    with pytest.raises(R.OslScriptError, match="NoSuchSocket"):
        R.load_osl_script(mat.node_tree, "ms_constant_emission", scene, inputs=["NoSuchSocket"])


def test_broken_shader_is_reported(tmp_path):
    bad = tmp_path / "broken.osl"
    bad.write_text("shader broken(output color C = 0) { C = undefined_function(); }\n")
    scene = R.reset_scene()
    mat = R.new_material("T")
    with pytest.raises(R.OslScriptError):
        R.load_osl_script(mat.node_tree, str(bad), scene, outputs=["C"])


def test_compiling_an_embedded_script_leaves_no_file_behind():
    """Cycles compiles an internal script through a temporary .osl and .oso and removes only the .osl: loading a
    shader twice (a compile each) leaves the system's temporary folder as it was, with the bytecode in the node."""
    import glob
    import os
    import tempfile

    folder = tempfile.gettempdir()
    before = set(glob.glob(os.path.join(folder, "*.os[lo]")))
    scene = bpy.context.scene
    for name in ("A", "B"):
        node = R.load_osl_script(R.new_material(name).node_tree, "ms_constant_emission", scene, inputs=["Color"])
        assert node.mode == "INTERNAL" and "ms_constant_emission" in node.bytecode
    assert set(glob.glob(os.path.join(folder, "*.os[lo]"))) == before
    assert tempfile.gettempdir() == folder
