"""Blender's habits are the specification: strokes are steps of Blender's undo, copies are copies, light links
follow what renders, no engine switch, no black render without OSL.

Operators run with ``undo=True`` (the second positional argument of ``bpy.ops`` calls), as the UI runs them:
each one then pushes its own undo step, and ``bpy.ops.ed.undo`` / ``redo`` walk them like Ctrl+Z / Ctrl+Shift+Z.
Stored data is checked by saving and reading the file back in a fresh process.
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from ._fabric_maps import material_maps, stroke_kwargs
from .fresh import run_fresh

STROKE_1 = [(0.15, 0.3), (0.35, 0.32), (0.55, 0.3)]
STROKE_2 = [(0.4, 0.7), (0.6, 0.72), (0.85, 0.7)]
READ_BASIS = """
from material_structures.addon.fabric.maps import images_to_maps
from material_structures.addon.fabric.material import material_map_images
RESULT = {o.name: images_to_maps(material_map_images(o.active_material)).basis.tolist()
          for o in bpy.data.objects if o.active_material is not None and o.active_material.node_tree is not None
          and material_map_images(o.active_material)}
"""


def _op(name: str, **kw):
    """Run ``material_structures.<name>`` as the UI does: EXEC with its own undo step."""
    return getattr(bpy.ops.material_structures, name)("EXEC_DEFAULT", True, **kw)


def _scene_with_planes(*names):
    from material_structures import render as R

    scene = R.reset_scene()
    objs = []
    for i, name in enumerate(names):
        obj = R.add_textured_plane(scene, 2.0, name=name)
        obj.location.x = 3.0 * i
        objs.append(obj)
    bpy.context.view_layer.objects.active = objs[0]
    bpy.ops.ed.undo_push(message="Set Up")
    return scene


def _activate(name):
    obj = bpy.data.objects[name]
    bpy.context.view_layer.objects.active = obj
    return obj


def _brush(uvs, mode="COMB"):
    brush = bpy.context.scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength = mode, 0.08, 1.0
    return _op("fabric_brush", **stroke_kwargs(uvs))


def _basis(name):
    return material_maps(bpy.data.objects[name]).basis.copy()


def _stored(tmp_path, tag):
    path = str(tmp_path / f"{tag}.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    return {k: np.asarray(v, dtype=np.float32) for k, v in run_fresh(READ_BASIS, blend=path).items()}


def test_strokes_are_undo_steps_and_undo_keeps_pixels_and_file_in_step(addon_module, tmp_path):
    """Items 1 and 2: Ctrl+Z after a stroke takes back the stroke (not the material), Ctrl+Shift+Z brings it back,
    undoing another edit leaves the strokes, and what the viewport shows is what the file stores."""
    _scene_with_planes("A", "B")
    assert _op("fabric_new_material", preset="VELVET") == {"FINISHED"}
    m0 = _basis("A")
    assert _brush(STROKE_1) == {"FINISHED"}
    m1 = _basis("A")
    assert _brush(STROKE_2) == {"FINISHED"}
    m2 = _basis("A")
    assert np.any(m1 != m0) and np.any(m2 != m1)

    bpy.ops.ed.undo()  # right after brushing: the last stroke goes, the material stays
    assert bpy.data.objects["A"].active_material is not None
    np.testing.assert_array_equal(_basis("A"), m1)
    bpy.ops.ed.redo()
    np.testing.assert_array_equal(_basis("A"), m2)

    bpy.data.objects["B"].location.x += 1.0  # another edit, then Ctrl+Z: the strokes stay, in view and in file
    bpy.ops.ed.undo_push(message="Move")
    bpy.ops.ed.undo()
    assert bpy.data.objects["B"].location.x == pytest.approx(3.0)
    np.testing.assert_array_equal(_basis("A"), m2)
    np.testing.assert_allclose(_stored(tmp_path, "after_move_undo")["A"], m2, atol=1e-6)

    bpy.ops.ed.undo()  # the second stroke: pixels and file both back to after the first
    np.testing.assert_array_equal(_basis("A"), m1)
    np.testing.assert_allclose(_stored(tmp_path, "after_stroke_undo")["A"], m1, atol=1e-6)
    bpy.ops.ed.undo()
    np.testing.assert_array_equal(_basis("A"), m0)
    bpy.ops.ed.undo()  # and only then the material
    assert bpy.data.objects["A"].active_material is None


def test_brushing_after_an_undo_paints_on_the_restored_maps(addon_module):
    """Item 3: no Undo Stroke button that raises after a global undo; a stroke after Ctrl+Z starts from the maps
    the undo restored (not from a stale copy that would bring the undone stroke back)."""
    assert not hasattr(bpy.types, "MATERIAL_STRUCTURES_OT_fabric_brush_undo")
    _scene_with_planes("A")
    assert _op("fabric_new_material", preset="VELVET") == {"FINISHED"}
    m0 = _basis("A")
    assert _brush(STROKE_1) == {"FINISHED"}
    only_1 = np.any(_basis("A") != m0, axis=-1)
    bpy.ops.ed.undo()
    assert _brush(STROKE_2) == {"FINISHED"}
    m2 = _basis("A")
    only_2 = np.any(m2 != m0, axis=-1)
    assert only_2.sum() > 20
    untouched_by_2 = only_1 & ~only_2
    assert untouched_by_2.sum() > 20
    np.testing.assert_array_equal(m2[untouched_by_2], m0[untouched_by_2])


def test_a_single_user_copy_gets_its_own_maps_on_first_stroke(addon_module, tmp_path):
    """Item 4: Shift+D + single-user material (a copy of the material: it points at the same images) ->
    brushing the copy leaves the original's maps alone, in the viewport and in the file."""
    _scene_with_planes("A", "B")
    assert _op("fabric_new_material", preset="CORDUROY") == {"FINISHED"}
    original = bpy.data.objects["A"].active_material
    before = _basis("A")
    copy = original.copy()  # Make Single User > Materials, the user-count button: Material.copy()
    bpy.data.objects["B"].data.materials.append(copy)
    bpy.ops.ed.undo_push(message="Make Single User")
    _activate("B")
    assert _brush(STROKE_1) == {"FINISHED"}
    assert np.any(_basis("B") != before)
    np.testing.assert_array_equal(_basis("A"), before)
    from material_structures.addon.fabric.material import material_closure_images, material_map_images

    mine = {i.name for i in [*material_map_images(copy).values(), *material_closure_images(copy).values()]}
    theirs = {i.name for i in [*material_map_images(original).values(), *material_closure_images(original).values()]}
    assert len(mine) == 12 and not mine & theirs
    stored = _stored(tmp_path, "copies")
    np.testing.assert_allclose(stored["A"], before, atol=1e-6)
    np.testing.assert_allclose(stored["B"], _basis("B"), atol=1e-6)


def test_strokes_belong_to_their_material_across_renames(addon_module):
    """Item 5: brush A, rename its material, give B a new fabric material (it takes the old name) and brush it:
    Ctrl+Z takes back B's stroke and leaves A's."""
    _scene_with_planes("A", "B")
    assert _op("fabric_new_material", preset="VELVET") == {"FINISHED"}
    a0 = _basis("A")
    assert _brush(STROKE_1) == {"FINISHED"}
    a1 = _basis("A")
    old_name = bpy.data.objects["A"].active_material.name
    bpy.data.objects["A"].active_material.name = "Renamed Velvet"
    bpy.ops.ed.undo_push(message="Rename")
    _activate("B")
    assert _op("fabric_new_material", preset="VELVET") == {"FINISHED"}
    assert bpy.data.objects["B"].active_material.name == old_name
    b0 = _basis("B")
    assert _brush(STROKE_2) == {"FINISHED"}
    np.testing.assert_array_equal(_basis("A"), a1)
    bpy.ops.ed.undo()
    np.testing.assert_array_equal(_basis("B"), b0)
    np.testing.assert_array_equal(_basis("A"), a1)
    assert np.any(a1 != a0)


def test_a_fabric_material_made_plain_is_lit_again(addon_module):
    """Item 6: delete the fabric nodes and connect a Principled BSDF -> the lamp is no longer linked off the
    object, and a render does not bring the link back."""
    from material_structures import render as R
    from material_structures.addon.fabric.material import fabric_group_node

    scene = _scene_with_planes("A")
    R.configure_cycles(scene, resolution=(8, 8), samples=1, osl=True)
    R.add_orthographic_camera(scene, 2.2)
    lamp = R.add_lamp(scene, "POINT", location=(0, 0, 3), power=100.0)
    assert _op("fabric_new_material", preset="VELVET") == {"FINISHED"}
    obj = bpy.data.objects["A"]

    def excluded():
        coll = lamp.light_linking.receiver_collection
        if coll is None:
            return False
        return any(o.name == "A" and e.light_linking.link_state == "EXCLUDE"
                   for o, e in zip(coll.objects, coll.collection_objects, strict=True))

    R.render_to_array(scene)
    assert excluded()  # the exact path evaluates the lamp itself
    mat = obj.active_material
    tree = mat.node_tree
    tree.nodes.remove(fabric_group_node(mat))
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    out = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target == "CYCLES")
    tree.links.new(bsdf.outputs[0], out.inputs["Surface"])
    bpy.context.view_layer.update()
    assert not excluded()
    img = R.render_to_array(scene)
    assert not excluded()
    assert img[..., :3].mean() > 1e-3


def test_nothing_switches_the_render_engine(addon_module):
    """Item 8: in an EEVEE scene, New Fabric Material and Generate Scratches leave the engine and the shading
    system as they were."""
    scene = _scene_with_planes("A", "B")
    scene.render.engine = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0) else "BLENDER_EEVEE"
    scene.cycles.shading_system = False
    engine = scene.render.engine
    assert _op("fabric_new_material", preset="PLUSH") == {"FINISHED"}
    _activate("B")
    assert _op("scratch_generate", count=50) == {"FINISHED"}
    assert (scene.render.engine, scene.cycles.shading_system) == (engine, False)


@pytest.mark.parametrize("preset", ["VELVET", "CORDUROY"])
def test_closure_path_without_osl_is_the_fast_preview(addon_module, preset):
    """Item 7: without OSL the fabric renders the closures Fast Preview renders with OSL, built from Cycles' own
    nodes (fitted mix; SigmaScale 1.5 and Anisotropy 0.5 the fixed approximation): same pixels within 1e-5."""
    from material_structures import render as R
    from material_structures.addon.fabric.material import fabric_group_node

    scene = _scene_with_planes("A")
    R.configure_cycles(scene, resolution=(32, 32), samples=16, osl=True)
    cam = R.add_orthographic_camera(scene, 2.2)
    R.look_from(cam, R.view_direction(40, 20))
    R.add_lamp(scene, "SUN", power=3.0, location=(0, 0, 5), target=(0.3, 0.2, 0))
    R.dark_world(scene, 0.3)
    assert _op("fabric_new_material", preset=preset) == {"FINISHED"}
    node = fabric_group_node(bpy.data.objects["A"].active_material)
    node.inputs["FastPreview"].default_value = 1
    for scale, anisotropy in ((1.0, 0.0), (1.5, 0.0), (1.0, 0.5)):
        node.inputs["SigmaScale"].default_value, node.inputs["Anisotropy"].default_value = scale, anisotropy
        scene.cycles.shading_system = True
        with_osl = R.render_to_array(scene)[..., :3]
        scene.cycles.shading_system = False
        without = R.render_to_array(scene)[..., :3]
        assert with_osl.mean() > 0.05
        np.testing.assert_allclose(without, with_osl, atol=1e-5)


def test_generated_scratches_are_undo_steps(addon_module):
    """Generate twice (the second replaces the set in the same images), Ctrl+Z: the stored set and the table
    images the shader reads are the first set again; Ctrl+Shift+Z brings the second back."""
    from material_structures.addon.scratch.editing import material_set, object_scratch_material

    _scene_with_planes("A")

    def stored():
        s = material_set(object_scratch_material(bpy.data.objects["A"]))[1]
        return s.segments.copy(), s.n_scratches

    assert _op("scratch_generate", count=60, seed=1) == {"FINISHED"}
    first = stored()
    assert _op("scratch_generate", count=60, seed=2) == {"FINISHED"}
    second = stored()
    assert first[0].shape != second[0].shape or np.any(first[0] != second[0])
    bpy.ops.ed.undo()
    np.testing.assert_array_equal(stored()[0], first[0])
    bpy.ops.ed.redo()
    np.testing.assert_array_equal(stored()[0], second[0])


def test_polishing_circles_say_why_they_are_fewer_than_asked(addon_module, capfd):
    """Item 9: Polishing Circles with Count 300 gives fewer scratches (arcs wholly outside the patch are
    clipped away): the report says how many and why."""
    _scene_with_planes("A")
    assert _op("scratch_generate", pattern="POLISH", count=300) == {"FINISHED"}
    out = "".join(capfd.readouterr())
    assert "of the 300 generated lie wholly outside the 20 mm patch and were left out" in out, out


# -- item 7: library materials in a factory-default scene ------------------------------------------------------
# Each library material on its own sphere in Blender's factory startup scene (its lamp, camera and world),
# rendered at 16 spp: Cycles with OSL and Fast Preview (the reference look), Cycles with OSL (exact paths),
# Cycles without OSL (Blender's default: the closure path from Cycles' own nodes) and EEVEE. Tolerances on the
# mean of the 16 x 16 pixels at each sphere's centre, relative to the Fast Preview look:
#   Cycles without OSL: fabric and teeth 2 % (the same closures, 16-spp noise of paths that consume random
#   numbers differently: measured 0.45 %; test_closure_path_without_osl_is_the_fast_preview shows the closures
#   equal to 1e-5 where the noise is shared); scratched metals 10 % (the base metal without its scratches;
#   measured 1.3-3.2 %).
#   Cycles with OSL: 15 % (exact lamp and world terms instead of the closures; measured 0.1-4 %).
#   EEVEE: non-black and within a factor 8 of the Fast Preview look after dividing by a grey diffuse sphere's
#   own EEVEE / Cycles ratio (measured 0.998: the lighting agrees). EEVEE shows the viewport look (a Principled
#   BSDF from the same maps), which is a sketch, not the model: measured 1.1x (metals, satin) to 6.6x (brushed
#   velvet seen head-on, where the pile is darkest; EEVEE renders sheen and volumes its own way, and even the
#   closure path's nodes give 4.8x there).
RENDER_LIBRARY = """
import numpy as np
from material_structures import render as R
bpy.ops.wm.read_homefile(use_factory_startup=True)
scene = bpy.context.scene
factory_engine = scene.render.engine
with bpy.data.libraries.load({path!r}) as (src, dst):
    dst.materials = list(src.materials)
mats = list(dst.materials)
grey = bpy.data.materials.new("Reference Grey")
mats.append(grey)
for o in list(scene.objects):
    if o.type == "MESH":
        bpy.data.objects.remove(o)
cols = 4
rows = (len(mats) + cols - 1) // cols
for i, m in enumerate(mats):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=((i % cols) - 1.5, (rows - 1) / 2 - i // cols, 0))
    bpy.context.object.data.materials.append(m)
    bpy.ops.object.shade_smooth()
cam = scene.camera
cam.data.type = "ORTHO"
cam.data.ortho_scale = 4.2
cam.location, cam.rotation_euler = (0, 0, 10), (0, 0, 0)
bpy.data.objects["Light"].location = (2, -3, 6)
scene.render.resolution_x, scene.render.resolution_y = 160, 40 * rows
scene.cycles.samples, scene.cycles.use_denoising, scene.cycles.seed = 16, False, 0
scene.view_settings.view_transform = "Standard"

def centres(img):
    h, w = img.shape[:2]
    out = []
    for i in range(len(mats)):
        r, c = i // cols, i % cols
        cy, cx = (2 * r + 1) * h // (2 * rows), (2 * c + 1) * w // (2 * cols)
        out.append(float(img[cy - 8:cy + 8, cx - 8:cx + 8, :3].mean()))
    return out

RESULT = {{"names": [m.name for m in mats], "factory_engine": factory_engine}}
for tag, engine, osl, fast in (("fast", "CYCLES", True, 1), ("osl", "CYCLES", True, 0), ("svm", "CYCLES", False, 0),
                               ("eevee", factory_engine, False, 0)):
    scene.render.engine, scene.cycles.shading_system = engine, osl
    for m in mats:
        for node in m.node_tree.nodes:
            if node.type == "GROUP" and "FastPreview" in node.inputs:
                node.inputs["FastPreview"].default_value = fast
    RESULT[tag] = centres(R.render_to_array(scene))
"""


@pytest.mark.slow
def test_library_materials_render_in_every_engine_of_a_default_scene(addon_module, tmp_path_factory):
    """Item 7 (acceptance): every library material appended into a factory-default scene renders non-black in
    Cycles without OSL, Cycles with OSL and EEVEE, within the stated tolerances of its Fast Preview look."""
    pytest.importorskip("PIL")
    from material_structures.showcase.asset_library import build_asset_library

    folder = str(tmp_path_factory.mktemp("library"))
    path = build_asset_library(folder, preview_size=16, samples=1, progress=False)
    got = run_fresh(RENDER_LIBRARY.format(path=path))
    names = got["names"]
    fast, osl, svm, eevee = (np.asarray(got[k]) for k in ("fast", "osl", "svm", "eevee"))
    grey = names.index("Reference Grey")
    calib = eevee[grey] / fast[grey]
    for i, name in enumerate(names):
        assert min(fast[i], osl[i], svm[i], eevee[i]) > 2e-3, f"{name} renders black: {got}"
        metal = "Wear" in name or "Circles" in name
        assert svm[i] == pytest.approx(fast[i], rel=0.10 if metal else 0.02), name
        assert osl[i] == pytest.approx(fast[i], rel=0.15), name
        ratio = (eevee[i] / calib) / fast[i]
        assert 1 / 8 < ratio < 8.0, f"{name}: EEVEE {eevee[i]:.4f} vs Cycles {fast[i]:.4f} (grey ratio {calib:.3f})"
