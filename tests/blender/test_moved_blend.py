"""A .blend using every library material renders identically after it is moved to another folder (or
machine) and after the extension is reinstalled elsewhere: the shaders are embedded in the file."""

from __future__ import annotations

import os
import shutil

import bpy
import numpy as np

from .fresh import run_fresh

RENDER = """
from material_structures.render import render_to_array
scene = bpy.context.scene
engine = (scene.render.engine, scene.cycles.shading_system)  # as saved: loading must not change it
scene.render.engine, scene.cycles.shading_system = "CYCLES", True
RESULT = {"engine": engine, "pixels": render_to_array(scene).tolist(),
          "external": [n.name for m in bpy.data.materials if m.node_tree for n in m.node_tree.nodes
                       if n.type == "SCRIPT" and n.mode == "EXTERNAL"]
                      + [n.name for g in bpy.data.node_groups for n in g.nodes
                         if n.type == "SCRIPT" and n.mode == "EXTERNAL"]}
"""


SAME_AS_A1 = {"Dentin Shade A3 (yellowish)", "Dentin Shade C2 (greyish)"}


def _library_scene(work: str) -> list[str]:
    """One small sphere per library material in a row, a point and an area light, a camera."""
    from material_structures import render as R
    from material_structures.addon.fabric.material import sync_fabric_lamps
    from material_structures.showcase import library
    from material_structures.showcase.library import MATERIALS

    scene = R.reset_scene()
    R.configure_cycles(scene, resolution=(160, 24), samples=4)
    R.dark_world(scene, 0.2)
    # every library material but two of the three dentin shades (the same node groups and scripts with other
    # values; each tooth material costs seconds of Cycles volume set-up per render)
    names = [n for n in library.available_materials() if n not in SAME_AS_A1]
    for i, name in enumerate(names):
        mat = MATERIALS[name].build(scene, work)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(i - (len(names) - 1) / 2, 0.0, 0.0),
                                             segments=24, ring_count=12)
        obj = bpy.context.active_object
        obj.data.materials.append(mat)
    light = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "POINT"))
    light.data.energy = 300.0
    light.location = (1.0, -3.0, 3.0)
    scene.collection.objects.link(light)
    area = bpy.data.objects.new("Fill", bpy.data.lights.new("Fill", "AREA"))
    area.data.energy = 200.0
    area.location = (-2.0, -2.0, 2.0)
    scene.collection.objects.link(area)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = len(names) + 0.2
    cam.location = (0.0, -10.0, 0.0)
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sync_fabric_lamps(scene)
    return names


def test_moved_blend_renders_identically(addon_module, tmp_path):
    names = _library_scene(str(tmp_path / "work"))
    saved = tmp_path / "project" / "scene.blend"
    saved.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(saved))
    before = run_fresh(RENDER, blend=str(saved))
    ref = np.asarray(before["pixels"])
    assert before["external"] == []
    # Every material is visible: its sphere's column block is lit (not black, as a lost shader renders).
    w = ref.shape[1] // len(names)
    means = [float(ref[8:16, i * w + w // 3 : i * w + 2 * w // 3, :3].mean()) for i in range(len(names))]
    assert min(means) > 0.003, dict(zip(names, means, strict=True))  # a lost shader renders 0

    # Moved one folder deeper, opened with the extension installed in another folder and another
    # temporary folder (another machine: the scratch tables' cache is gone).
    moved = tmp_path / "elsewhere" / "deeper" / "scene.blend"
    moved.parent.mkdir(parents=True)
    shutil.copy(saved, moved)
    shutil.rmtree(saved.parent)
    other_tmp = tmp_path / "other-tmp"
    other_tmp.mkdir()
    after = run_fresh(RENDER, blend=str(moved), repo_dir=str(tmp_path / "other-repo"),
                      env={"TMPDIR": str(other_tmp)})
    diff = np.abs(np.asarray(after["pixels"]) - ref)
    assert float(diff.max()) == 0.0, {n: float(diff[:, i * w:(i + 1) * w].max()) for i, n in enumerate(names)}
    assert os.listdir(other_tmp), "the scratch tables were not re-extracted into the new temporary folder"


def test_file_from_before_embedding_is_converted_on_load(addon_module, tmp_path):
    """A file whose script node points into the extension folder (as saved before shaders were
    embedded) renders after a move: loading it embeds the installed extension's shader."""
    from material_structures import render as R
    from material_structures.render.osl import compile_script_node
    from material_structures.render.session import osl_shader_path

    scene = bpy.context.scene
    R.configure_cycles(scene, resolution=(8, 8), samples=1)
    R.dark_world(scene)
    mat = R.new_material("Old")
    tree = mat.node_tree
    R.ensure_bundled_paths()
    node = tree.nodes.new("ShaderNodeScript")
    node.mode = "EXTERNAL"
    node.filepath = osl_shader_path("ms_constant_emission")
    compile_script_node(node, scene)
    node.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    out = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    obj = R.add_textured_plane(scene, 2.0)
    obj.data.materials.append(mat)
    R.add_orthographic_camera(scene, 2.0)
    scene.render.engine = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"
    scene.cycles.shading_system = False
    saved = tmp_path / "a" / "old.blend"
    saved.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(saved), relative_remap=True)
    moved = tmp_path / "b" / "c" / "old.blend"
    moved.parent.mkdir(parents=True)
    shutil.copy(saved, moved)
    got = run_fresh(RENDER, blend=str(moved), repo_dir=str(tmp_path / "other-repo"))
    assert got["external"] == []
    assert got["engine"][1] is False and got["engine"][0] != "CYCLES"  # the user's engine, untouched by loading
    np.testing.assert_allclose(np.asarray(got["pixels"])[..., :3].mean(axis=(0, 1)), [0.2, 0.4, 0.6], atol=1e-4)
