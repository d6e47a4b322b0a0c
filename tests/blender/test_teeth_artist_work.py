"""Teeth: an artist never loses work.

* Add Tooth From Mesh keeps what you see: the tooth has the source's world size (its scale, its parents'
  scale and the scene's unit scale counted once), location and rotation.
* A .blend saved while a background fit runs reopens with the fit idle (job state is not stored in the file).
* A fit applies to the teeth chosen in the panel's capture-tooth mapping; a fit that would apply to nothing
  does not start, and Apply Fit Result that applies to nothing is an error.
"""

from __future__ import annotations

import json
import os
import time
from types import SimpleNamespace

import bpy
import numpy as np
import pytest
from mathutils import Vector

from ._teeth_capture import assert_fit_applied, import_capture_scene, write_tiny_capture
from .fresh import run_fresh


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory):
    """A tiny synthetic capture (1 tooth "tooth0", 1 camera, 3 lights, 16 x 12 px) written by the core."""
    return write_tiny_capture(str(tmp_path_factory.mktemp("teeth-capture")), width=16, height=12, n_lights=3)


def _world_vertices(obj, n: int | None = None) -> np.ndarray:
    """World coordinates (Blender units) of the first ``n`` vertices of ``obj``'s mesh."""
    me = obj.data
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)[:n]
    m = np.array(obj.matrix_world)
    return co @ m[:3, :3].T + m[:3, 3]


# ---------------------------------------------------------------------------------------------------------------
# 7. Add Tooth From Mesh: the tooth is the size (and place, and orientation) of the mesh you see

MESH_CASES = {
    # id: (unit scale_length, mesh radius in Blender units, object scale, object rotation (rad),
    #      parent (scale, rotation) or None, expected world dimensions in Blender units)
    "8mm-sphere": (1.0, 0.004, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0), None, (0.008, 0.008, 0.008)),
    "scale2-rotated": (1.0, 0.004, (2.0, 2.0, 2.0), (0.4, -0.7, 1.2), None, (0.016, 0.016, 0.016)),
    "parented-nonuniform": (1.0, 0.004, (1.0, 1.0, 1.5), (0.0, 0.3, 0.0), (3.0, (0.2, 0.0, -0.5)),
                            (0.024, 0.024, 0.036)),
    "unit-scale-cm": (0.01, 0.4, (1.0, 1.0, 1.0), (0.0, 0.0, 0.9), None, (0.8, 0.8, 0.8)),
}


@pytest.mark.parametrize("case", list(MESH_CASES))
def test_tooth_from_mesh_keeps_world_size_place_and_rotation(addon_module, case):
    import bmesh

    unit, radius, scale, rot, parent, dims = MESH_CASES[case]
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.unit_settings.scale_length = unit
    me = bpy.data.meshes.new("Sphere")
    bm = bmesh.new()
    # 32 x 16: its bounding box is exactly 2 r on every axis (vertices at the poles, on the equator, at 90 deg)
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=radius)
    bmesh.ops.triangulate(bm, faces=bm.faces[:])
    bm.to_mesh(me)
    bm.free()
    src = bpy.data.objects.new("Sphere", me)
    scene.collection.objects.link(src)
    if parent is not None:
        empty = bpy.data.objects.new("Jaw", None)
        scene.collection.objects.link(empty)
        empty.scale = (parent[0],) * 3
        empty.rotation_euler = parent[1]
        empty.location = (0.05, 0.0, -0.02)
        src.parent = empty
    src.location = (0.01 * radius / 0.004, -0.02 * radius / 0.004, 0.03 * radius / 0.004)
    src.rotation_euler = rot
    src.scale = scale
    bpy.context.view_layer.update()
    src_world = _world_vertices(src)
    src_matrix = src.matrix_world.copy()
    bpy.context.view_layer.objects.active = src
    assert bpy.ops.material_structures.teeth_add_tooth(source="MESH") == {"FINISHED"}
    enamel = bpy.context.active_object
    dentin = enamel.ms_tooth.partner
    bpy.context.view_layer.update()

    mm_per_unit = 1000.0 * unit
    assert enamel.ms_tooth.mm_per_unit == pytest.approx(mm_per_unit, rel=1e-9)
    # what you see: the world dimensions of the mesh, within 1 %
    np.testing.assert_allclose(tuple(enamel.dimensions), dims, rtol=0.01)
    # ... vertex by vertex: the enamel's outer surface lies where the source's surface lay (float32 mm)
    size = max(dims)
    e_world = _world_vertices(enamel, len(src_world))
    np.testing.assert_allclose(e_world, src_world, atol=1e-5 * size)
    # the source's world location and rotation; scale 1 / mm_per_unit (millimetre mesh)
    loc, quat, _ = src_matrix.decompose()
    e_loc, e_quat, e_scale = enamel.matrix_world.decompose()
    np.testing.assert_allclose(tuple(e_loc), tuple(loc), atol=1e-6 * size)
    assert e_quat.rotation_difference(quat).angle == pytest.approx(0.0, abs=1e-4)
    np.testing.assert_allclose(tuple(e_scale), (1.0 / mm_per_unit,) * 3, rtol=1e-5)
    # the dentin core sits inside the enamel (the enamel is 1.1 - 1.8 mm thick)
    d_world = _world_vertices(dentin)
    lo, hi = src_world.min(axis=0), src_world.max(axis=0)
    assert (d_world > lo).all() and (d_world < hi).all()


# ---------------------------------------------------------------------------------------------------------------
# 8. A .blend saved while a fit runs reopens idle

class _WindowManager:
    """Stand-in window manager: the modal Fit operator's invoke() headless (no window)."""

    def event_timer_add(self, step, window=None):
        return object()

    def event_timer_remove(self, timer):
        pass

    def modal_handler_add(self, op):
        return True

    def progress_begin(self, lo, hi):
        pass

    def progress_update(self, v):
        pass

    def progress_end(self):
        pass


_REOPEN_SNIPPET = """
from types import SimpleNamespace

class Layout:  # records the operators the Teeth panel draws
    def __init__(self):
        self.ops = []
    def operator(self, idname, **kw):
        self.ops.append(idname)
        return SimpleNamespace()
    def __getattr__(self, name):
        return lambda *a, **kw: self

fs = bpy.context.scene.ms_teeth_fit
r = {"running": fs.running, "progress": fs.progress, "status": fs.status, "iterations": fs.iterations,
     "capture_dir": fs.capture_dir, "fit_poll": bpy.ops.material_structures.teeth_fit.poll()}
try:
    r["cancel"] = sorted(bpy.ops.material_structures.teeth_fit_cancel())
except RuntimeError as exc:
    r["cancel"] = str(exc)
r["running_after_cancel"] = fs.running
layout = Layout()
bpy.types.VIEW3D_PT_material_structures_teeth.draw(SimpleNamespace(layout=layout), bpy.context)
r["panel"] = layout.ops
RESULT = r
"""


def test_fit_saved_while_running_reopens_idle(addon_module, capture_dir, tmp_path):
    import importlib

    ops = importlib.import_module(f"{addon_module}.addon.teeth.operators")  # the registered operators' module
    import_capture_scene(capture_dir)
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    fs.out_dir = str(tmp_path / "fit")
    fs.iterations = 10000
    fs.init = "SCENE"
    # what a click on "Fit Teeth to Capture" does (invoke: background fit + modal timer), headless
    wm = _WindowManager()
    context = SimpleNamespace(scene=bpy.context.scene, window_manager=wm, window=None, workspace=None,
                              screen=None, view_layer=bpy.context.view_layer)
    op = SimpleNamespace(report=lambda *a: None, _timer=None, _job=None, resume=False)  # the button: a new fit
    op._start = lambda ctx: ops.MS_OT_teeth_fit._start(op, ctx)
    op._cleanup = lambda ctx: ops.MS_OT_teeth_fit._cleanup(op, ctx)
    op._finish = lambda ctx, job, state: ops.MS_OT_teeth_fit._finish(op, ctx, job, state)
    path = str(tmp_path / "mid-fit.blend")
    try:
        assert ops.MS_OT_teeth_fit.invoke(op, context, None) == {"RUNNING_MODAL"}
        running_while_running = fs.running  # this session's live job
        fit_poll_while_running = bpy.ops.material_structures.teeth_fit.poll()
        assert bpy.ops.wm.save_as_mainfile(filepath=path, copy=True) == {"FINISHED"}
    finally:
        assert bpy.ops.material_structures.teeth_fit_cancel() == {"FINISHED"}
    # the modal operator's next timer tick ends it
    assert ops.MS_OT_teeth_fit.modal(op, context, SimpleNamespace(type="TIMER")) == {"CANCELLED"}
    assert not fs.running and bpy.ops.material_structures.teeth_fit.poll()

    r = run_fresh(_REOPEN_SNIPPET, blend=path)
    assert r["running"] is False, r
    assert r["progress"] == 0.0 and "iteration" not in r["status"], r
    assert r["fit_poll"] is True, r
    assert r["cancel"] == ["CANCELLED"], r  # a warning: nothing to cancel, and nothing stuck
    assert r["running_after_cancel"] is False, r
    assert "material_structures.teeth_fit" in r["panel"], r  # the Fit button is back
    assert "material_structures.teeth_fit_cancel" not in r["panel"], r
    # the user's settings are still in the file
    assert r["iterations"] == 10000 and r["capture_dir"] == capture_dir, r
    # while it ran, this session showed it running and offered no second fit
    assert running_while_running and not fit_poll_while_running


# ---------------------------------------------------------------------------------------------------------------
# 9. A fit applies to the teeth the user mapped, never silently to nothing

def _add_incisor():
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.material_structures.teeth_add_tooth(kind="INCISOR", resolution=12) == {"FINISHED"}
    enamel = bpy.data.objects["Incisor Enamel"]
    assert enamel.ms_tooth.tooth_name == "Incisor"
    return enamel


def test_fit_refuses_to_start_when_no_capture_tooth_is_mapped(addon_module, capture_dir, tmp_path):
    enamel = _add_incisor()  # tooth name "Incisor"; the capture's tooth is "tooth0"
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    fs.out_dir = str(tmp_path / "fit")
    fs.iterations = 1
    t0 = time.perf_counter()
    with pytest.raises(RuntimeError, match="No capture tooth is mapped"):
        bpy.ops.material_structures.teeth_fit()
    assert time.perf_counter() - t0 < 5.0  # refused at once
    assert not os.path.exists(tmp_path / "fit" / "fit_log.txt")  # no fit was started
    assert not fs.running and not enamel.ms_tooth.has_fit
    # the mapping was read from the capture's scene.json: its tooth, not mapped (no name matches)
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [("tooth0", None)]


def test_fit_applies_to_the_mapped_tooth(addon_module, capture_dir, tmp_path):
    enamel = _add_incisor()
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    fs.out_dir = str(tmp_path / "fit")
    fs.iterations = 2
    fs.init = "PERTURBED"
    assert bpy.ops.material_structures.teeth_read_capture_teeth() == {"FINISHED"}
    assert [m.capture_tooth for m in fs.tooth_map] == ["tooth0"]
    fs.tooth_map[0].enamel = enamel  # the user's choice in the panel
    assert bpy.ops.material_structures.teeth_fit() == {"FINISHED"}
    assert_fit_applied(enamel, tmp_path / "fit")
    assert "Incisor" in fs.status


def test_apply_fit_result_uses_the_mapping_and_refuses_nothing(addon_module, capture_dir):
    from material_structures.core.teeth.scene import load_scene

    result = os.path.join(capture_dir, "scene.json")  # a teeth scene file like scene_fit.json
    t = load_scene(result).teeth[0]
    enamel = _add_incisor()
    node = enamel.active_material.node_tree.nodes["Enamel"]
    node.inputs["Sigma_t"].default_value = before = (5.0, 6.0, 7.0)  # not the file's values
    assert not np.allclose(before, t.enamel.sigma_t, rtol=1e-3)
    # nothing in this scene is called "tooth0" and nothing is mapped: an error, nothing changed
    with pytest.raises(RuntimeError, match="No capture tooth is mapped"):
        bpy.ops.material_structures.teeth_apply_fit_file(filepath=result)
    assert not enamel.ms_tooth.has_fit
    np.testing.assert_allclose(tuple(node.inputs["Sigma_t"].default_value), before, rtol=0)
    # setting the capture folder reads its teeth; the user maps tooth0 -> the incisor
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [("tooth0", None)]
    fs.tooth_map[0].enamel = enamel
    assert bpy.ops.material_structures.teeth_apply_fit_file(filepath=result) == {"FINISHED"}
    assert enamel.ms_tooth.has_fit
    np.testing.assert_allclose(tuple(enamel.ms_tooth.fitted), t.c, atol=1e-6)
    np.testing.assert_allclose(tuple(node.inputs["Sigma_t"].default_value), t.enamel.sigma_t, rtol=1e-6)


@pytest.mark.parametrize("duplicate", ["duplicate_move", "duplicate_move_linked"])
def test_a_fit_applied_to_a_tooth_and_its_copy_gives_each_its_own_values(addon_module, capture_dir, tmp_path,
                                                                         duplicate):
    """A tooth copied with Shift+D keeps its original's Enamel and Dentin materials (Blender's default), one copied
    with Alt+D its mesh and with it the material slot: a two-tooth fit mapped onto the pair wrote both teeth into the
    same materials, the second tooth's values over the first's (both renders showed tooth1's enamel). Each fitted
    tooth now gets materials of its own (in the object's own slot where the mesh is shared), and its Blend Volume
    follows them. An Alt+D copy's dentin shared its original's mesh and shape keys: the first tooth rendered the
    second's dentin shape (its panel showing its own); each fitted dentin now gets a mesh of its own."""
    from importlib import import_module

    from material_structures.addon.teeth.materials import group_node
    from material_structures.core.teeth.dentin_blend_shapes import MODE_NAMES

    linked_materials = import_module(f"{addon_module}.addon.teeth.blend_volume").linked_materials
    blend_object = import_module(f"{addon_module}.addon.teeth.blend_volume").blend_object
    d = json.loads(open(os.path.join(capture_dir, "scene.json")).read())
    second = json.loads(json.dumps(d["teeth"][0]))
    second["name"] = "tooth1"
    second["enamel"]["sigma_t"] = [3.0, 3.0, 3.0]
    second["c"] = [-0.3, 0.3, -0.3]
    d["teeth"][0]["enamel"]["sigma_t"] = [0.5, 0.5, 0.5]
    d["teeth"].append(second)
    path = tmp_path / "two_fit.json"
    path.write_text(json.dumps(d))
    a = _add_incisor()
    getattr(bpy.ops.object, duplicate)(TRANSFORM_OT_translate={"value": (0.01, 0.0, 0.0)})
    bpy.context.view_layer.update()
    b = bpy.context.active_object
    assert b is not a and b.active_material == a.active_material  # the same materials
    assert (b.data == a.data) == (duplicate == "duplicate_move_linked")
    shared = a.active_material
    tooth_map = bpy.context.scene.ms_teeth_fit.tooth_map
    for name, obj in (("tooth0", a), ("tooth1", b)):
        m = tooth_map.add()
        m.capture_tooth, m.enamel = name, obj
    assert bpy.ops.material_structures.teeth_apply_fit_file(filepath=str(path)) == {"FINISHED"}
    bpy.context.view_layer.update()
    for obj, sigma_t, c in ((a, 0.5, d["teeth"][0]["c"]), (b, 3.0, second["c"])):
        node = group_node(obj.active_material)
        np.testing.assert_allclose(tuple(node.inputs["Sigma_t"].default_value), (sigma_t,) * 3, rtol=1e-6)
        np.testing.assert_allclose(tuple(obj.ms_tooth.fitted), c, atol=1e-6)
        dentin = obj.ms_tooth.partner
        assert linked_materials(blend_object(obj).active_material) == (obj.active_material, dentin.active_material)
        keys = dentin.data.shape_keys.key_blocks
        np.testing.assert_allclose([keys[n].value for n in MODE_NAMES], c, atol=1e-6)
        assert dentin.data.users == 1 and not dentin.data.use_fake_user
    # a dentin mesh of one tooth with a fake user (an artist's F) is its own: not copied again
    dentin = a.ms_tooth.partner
    dentin.data.use_fake_user = True
    mesh = dentin.data
    assert bpy.ops.material_structures.teeth_apply_fit_file(filepath=str(path)) == {"FINISHED"}
    assert dentin.data == mesh
    assert a.active_material != b.active_material and a.ms_tooth.partner.active_material != \
        b.ms_tooth.partner.active_material
    assert shared.name in {a.active_material.name, b.active_material.name}  # one tooth keeps it, one has a copy


def _eevee_tooth_colour(enamel) -> np.ndarray:
    """Mean RGB of the tooth's pixels in an EEVEE render (32 x 32, a sun, a black world, looking at the crown)."""
    from material_structures import render as R

    scene = bpy.context.scene
    scene.render.engine = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"
    scene.render.resolution_x = scene.render.resolution_y = 32
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.eevee.taa_render_samples = 4
    if scene.camera is None:
        R.dark_world(scene)
        sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
        sun.data.energy = 3.0
        scene.collection.objects.link(sun)
        lo, hi = np.min([enamel.matrix_world @ Vector(c) for c in enamel.bound_box], 0), \
            np.max([enamel.matrix_world @ Vector(c) for c in enamel.bound_box], 0)
        centre, size = (lo + hi) / 2, float(np.max(hi - lo))
        R.add_orthographic_camera(scene, 1.2 * size, location=(centre[0], centre[1] - 4 * size, centre[2]),
                                  rotation=(np.pi / 2, 0.0, 0.0))
    px = R.render_to_array(scene)
    alpha = px[..., 3] > 0.5
    assert alpha.sum() > 50, "the tooth is not in the picture"
    return px[alpha, :3].mean(axis=0)


def test_eevee_shows_the_teeth_own_colour_and_follows_the_sliders(addon_module):
    """EEVEE (Blender's default engine, and Material Preview) renders a tooth through a Principled stand-in. It kept
    Principled's defaults (base 0.8, the orange skin radius 1 / 0.2 / 0.1) until a fit was applied, and then the
    fit's values: the Albedo and Sigma_t sliders an artist turns on the material changed nothing in EEVEE. The
    stand-in now reads the material's own values, whatever sets them."""
    from material_structures.addon.teeth.materials import DEFAULTS, STAND_IN_NODE, group_node

    enamel = _add_incisor()
    mat = enamel.active_material
    assert STAND_IN_NODE not in mat.node_tree.nodes  # in the group, fed by the material's inputs
    node = group_node(mat)
    np.testing.assert_allclose(tuple(node.inputs["Albedo"].default_value)[:3], DEFAULTS["Enamel"]["albedo"])
    before = _eevee_tooth_colour(enamel)
    assert before[0] / before[2] < 1.6, before  # not the orange of Principled's skin defaults (measured 7.0)
    node.inputs["Albedo"].default_value = (0.95, 0.45, 0.45, 1.0)  # as an artist turns the slider
    after = _eevee_tooth_colour(enamel)
    assert after[0] / after[1] > 1.3 * before[0] / before[1], (before, after)


def _file_with_the_materials_own_stand_in(path) -> None:
    """An incisor saved in the layout older versions made: the enamel material's own Principled feeding its EEVEE
    output, the group without its stand-in."""
    from material_structures.addon.teeth.materials import EEVEE_OUTPUT, STAND_IN_NODE, group_node

    mat = _add_incisor().active_material
    group = group_node(mat).node_tree
    own = mat.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
    own.name = STAND_IN_NODE
    mat.node_tree.links.new(own.outputs[0], mat.node_tree.nodes["EEVEE Output"].inputs["Surface"])
    group.interface.remove(next(s for s in group.interface.items_tree
                                if s.item_type == "SOCKET" and s.name == EEVEE_OUTPUT))
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def _eevee_fed_by_the_group(mat) -> bool:
    from material_structures.addon.teeth.materials import EEVEE_OUTPUT, STAND_IN_NODE, group_node

    fed = mat.node_tree.nodes["EEVEE Output"].inputs["Surface"].links[0].from_socket
    return STAND_IN_NODE not in mat.node_tree.nodes and fed.node == group_node(mat) and fed.name == EEVEE_OUTPUT


def test_a_file_with_the_materials_own_stand_in_moves_onto_the_groups(addon_module, tmp_path):
    """A file saved before the stand-in was part of the group: loading it links its EEVEE output to the group's
    stand-in and removes the material's own Principled node (which no slider reached). A material appended from
    such a file moves onto it when a fit is written into it (before, the fit changed nothing in EEVEE)."""
    from material_structures.addon.teeth.materials import set_volume
    from material_structures.core.teeth.scene import VolumeMaterial

    path = tmp_path / "old.blend"
    _file_with_the_materials_own_stand_in(path)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    assert _eevee_fed_by_the_group(bpy.data.objects["Incisor Enamel"].active_material)
    _file_with_the_materials_own_stand_in(path)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(str(path), link=False) as (_src, dst):
        dst.materials = ["Enamel Incisor"]
    (mat,) = dst.materials
    assert not _eevee_fed_by_the_group(mat)  # appended as it was
    set_volume(mat, VolumeMaterial(sigma_t=(1.0, 1.0, 1.0), albedo=(0.2, 0.9, 0.2), g1=0.5, g2=0.5, beta=1.0))
    assert _eevee_fed_by_the_group(mat)


def _blend_volumes():
    return [o for o in bpy.data.objects if o.ms_tooth.role == "BLEND"]


def test_a_blend_volume_goes_where_its_tooth_goes_and_with_it(addon_module):
    """The Blend Volume (hidden, not selectable) stayed in its first collection when its tooth was moved to another
    (the tooth rendered hollow, frame mean 0.037 for 0.115, once the old collection was excluded) or linked into
    another scene, and stayed when the tooth was deleted, rendering the deleted tooth's inside (0.124) and saved
    with the file. It now moves with its tooth and leaves the scene with it (kept as the enamel's child: a tooth
    put back finds it, spread and all), and no update makes it again for the deleted tooth."""
    enamel = _add_incisor()
    dentin = enamel.ms_tooth.partner
    scene, layer = bpy.context.scene, bpy.context.view_layer
    (blend,) = _blend_volumes()
    teeth = bpy.data.collections.new("Teeth")
    scene.collection.children.link(teeth)
    for obj in (enamel, dentin):  # Object > Collection > Move to Collection
        teeth.objects.link(obj)
        scene.collection.objects.unlink(obj)
    layer.update()
    assert [c.name for c in blend.users_collection] == ["Teeth"]
    other = bpy.data.scenes.new("Other")  # Object > Link/Transfer Data > Link Objects to Scene
    for obj in (enamel, dentin):
        other.collection.objects.link(obj)
    layer.update()
    assert blend.name in other.objects
    for obj in (enamel, dentin):  # a script takes the tooth out of every collection for a while, then puts it back
        for coll in list(obj.users_collection):
            coll.objects.unlink(obj)
    layer.update()
    assert blend.users_collection == ()
    for obj in (enamel, dentin):
        teeth.objects.link(obj)
    layer.update()
    assert _blend_volumes() == [blend] and [c.name for c in blend.users_collection] == ["Teeth"]
    for obj in teeth.objects:
        obj.select_set(obj == enamel)  # what a click on a tooth selects
    assert bpy.ops.object.delete() == {"FINISHED"}
    layer.update()
    for _ in range(3):  # later updates (objects added, moved) make no Blend Volume for the deleted tooth
        scene.collection.objects.link(bpy.data.objects.new("Empty", None))
        layer.update()
    assert not any(o.ms_tooth.role == "BLEND" for sc in bpy.data.scenes for o in sc.objects)
    assert _blend_volumes() == [blend] and blend.users_collection == ()  # dropped with the tooth when saved
    assert len([m for m in bpy.data.materials if m.name.startswith("Blend ")]) == 1


def _link_an_incisor(tmp_path, prepare=None) -> list:
    """A new file that links the Enamel and Dentin of an incisor saved in another (not its hidden Blend Volume;
    ``prepare(enamel)`` first, in the other file). Returns the linked objects."""
    enamel = _add_incisor()
    if prepare is not None:
        prepare(enamel)
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (_src, dst):
        dst.objects = ["Incisor Enamel", "Incisor Dentin"]
    for obj in dst.objects:
        bpy.context.scene.collection.objects.link(obj)
    return list(dst.objects)


def _save_an_incisor_in_a_collection(tmp_path, name: str) -> str:
    """The path of a file holding an incisor in the collection ``name``; an empty file open."""
    _add_incisor()
    collection = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(collection)
    for obj in list(bpy.context.scene.collection.objects):
        collection.objects.link(obj)
        bpy.context.scene.collection.objects.unlink(obj)
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def test_a_tooth_linked_from_another_file_without_its_blend_volume_gets_one(addon_module, tmp_path):
    """File > Link of a tooth's Enamel and Dentin (what one sees; the Blend Volume is hidden) rendered it hollow:
    its materials give their medium to a Blend Volume, and none came with it. It now gets one of this file's."""
    _link_an_incisor(tmp_path)
    bpy.context.view_layer.update()
    (blend,) = _blend_volumes()
    assert blend.library is None and blend.parent == bpy.data.objects["Incisor Enamel"]
    assert blend.name in bpy.context.scene.objects and not blend.hide_render


def test_the_light_paths_warning_sees_a_tooth_linked_as_a_collection_instance(addon_module, tmp_path):
    """File > Link of a collection makes an instance whose objects are not the scene's: the Teeth panel did not warn
    that Blender's default light paths render such a tooth half as bright (0.054 against 0.115)."""
    from importlib import import_module

    from material_structures.addon.teeth.scene_build import short_light_paths

    scene_has_teeth = import_module(f"{addon_module}.addon.teeth.panels").scene_has_teeth
    path = _save_an_incisor_in_a_collection(tmp_path, "Tooth")
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    assert short_light_paths(scene) and not scene_has_teeth(scene)
    with bpy.data.libraries.load(path, link=True) as (_src, dst):
        dst.collections = ["Tooth"]
    instance = bpy.data.objects.new("Tooth", None)
    instance.instance_type, instance.instance_collection = "COLLECTION", dst.collections[0]
    scene.collection.objects.link(instance)
    assert not any(o.ms_tooth.role == "ENAMEL" for o in scene.objects) and scene_has_teeth(scene)
    outer = bpy.data.collections.new("Set")  # an instance inside an instanced collection (a set dressing)
    scene.collection.objects.unlink(instance)
    outer.objects.link(instance)
    dressing = bpy.data.objects.new("Set", None)
    dressing.instance_type, dressing.instance_collection = "COLLECTION", outer
    scene.collection.objects.link(dressing)
    assert scene_has_teeth(scene)


def test_a_fit_applied_to_a_linked_tooth_is_one_line_and_changes_nothing(addon_module, capture_dir, tmp_path):
    """A tooth linked from another file is read-only here: Apply Fit Result says so, naming the file, before it
    changes anything."""
    _link_an_incisor(tmp_path)
    bpy.context.view_layer.update()  # the linked tooth gets a Blend Volume of this file's
    enamel = bpy.data.objects["Incisor Enamel"]
    m = bpy.context.scene.ms_teeth_fit.tooth_map.add()
    m.capture_tooth, m.enamel = "tooth0", enamel
    before = (len(bpy.data.materials), len(bpy.data.objects))
    with pytest.raises(RuntimeError, match="make it local") as info:
        bpy.ops.material_structures.teeth_apply_fit_file(filepath=os.path.join(capture_dir, "scene.json"))
    assert "is linked from" in str(info.value) and "Traceback" not in str(info.value)
    assert (len(bpy.data.materials), len(bpy.data.objects)) == before
    # Fit refuses it before the fit (it ran to its end, then applied nothing)
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir, fs.out_dir, fs.iterations = capture_dir, str(tmp_path / "fit"), 1
    with pytest.raises(RuntimeError, match="Cannot fit into this tooth: .* make it local"):
        bpy.ops.material_structures.teeth_fit()
    assert not fs.running and not os.path.exists(tmp_path / "fit" / "fit_log.txt")


def test_the_dentin_shape_of_a_linked_tooth_is_refused_in_one_line(addon_module, tmp_path):
    """Set Dentin Shape and Apply Fitted Coefficients on a tooth linked from another file said FINISHED and showed
    the new shape, which was gone when the file was opened again (the shape keys are the library's). Both now say
    why, as Apply Fit Result does, and change nothing."""
    from material_structures.core.teeth.dentin_blend_shapes import MODE_NAMES

    def fitted(enamel):
        enamel.ms_tooth.fitted = (0.2, -0.15, 0.1)
        enamel.ms_tooth.has_fit = True

    linked = _link_an_incisor(tmp_path, fitted)
    enamel = bpy.data.objects["Incisor Enamel"]
    bpy.context.view_layer.objects.active = enamel
    for op, kwargs in ((bpy.ops.material_structures.teeth_set_dentin, {"coefficients": (0.5, 0.4, 0.3)}),
                       (bpy.ops.material_structures.teeth_apply_fitted, {})):
        with pytest.raises(RuntimeError, match="make it local") as info:
            op(**kwargs)
        assert "is linked from" in str(info.value) and "Traceback" not in str(info.value)
    keys = enamel.ms_tooth.partner.data.shape_keys.key_blocks
    assert [keys[n].value for n in MODE_NAMES] == [0.0, 0.0, 0.0]
    # made local as objects, the dentin's mesh (its shape keys) still linked: the refusal names the mesh
    from material_structures.addon.teeth.scene_build import linked_tooth_reason

    local = {o.name: o.make_local() for o in linked}
    enamel = local["Incisor Enamel"]
    assert enamel.ms_tooth.partner.data.library is not None
    assert linked_tooth_reason(enamel).startswith("the dentin mesh 'Incisor Dentin' of 'Incisor Dentin' is linked")


def test_a_library_override_of_a_tooth_is_refused_its_settings_would_not_be_saved(addon_module, tmp_path):
    """An overridden tooth (a linked character's teeth made editable) took a fit and the panel showed it, and the
    tooth's settings (its coefficients, fitted values, dentin partner) were gone at the next open: an override
    keeps only what it overrides. Fits and the dentin sliders refuse it, in one line."""
    from material_structures.addon.teeth.scene_build import linked_tooth_reason

    path = _save_an_incisor_in_a_collection(tmp_path, "Teeth")
    with bpy.data.libraries.load(path, link=True) as (_src, dst):
        dst.collections = ["Teeth"]
    scene = bpy.context.scene
    scene.collection.children.link(dst.collections[0])
    dst.collections[0].override_hierarchy_create(scene, bpy.context.view_layer, do_fully_editable=True)
    enamel = next(o for o in scene.objects if o.name.startswith("Incisor Enamel") and o.override_library)
    assert "is a library override, whose tooth settings a save does not keep" in linked_tooth_reason(enamel)
    bpy.context.view_layer.objects.active = enamel
    with pytest.raises(RuntimeError, match="library override"):
        bpy.ops.material_structures.teeth_set_dentin(coefficients=(0.5, 0.4, 0.3))


def test_a_tooth_from_a_mesh_in_edit_mode_is_the_mesh_as_edited(addon_module):
    """From Mesh with the source in Edit Mode read the mesh as it was when Edit Mode began: with a UV map a
    traceback (TypeError from the UV layer), without one a tooth of the old shape."""
    import bmesh

    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.004, segments=16, ring_count=8)
    src = bpy.context.active_object
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(src.data)
    for v in bm.verts:
        v.co.z *= 3.0  # the crown stretched in Edit Mode
    bmesh.update_edit_mesh(src.data)
    assert bpy.ops.material_structures.teeth_add_tooth(source="MESH") == {"FINISHED"}
    bpy.context.view_layer.update()
    enamel = next(o for o in bpy.data.objects if o.ms_tooth.role == "ENAMEL")
    x, _y, z = enamel.dimensions
    assert z / x == pytest.approx(3.0, rel=0.02)


def test_teeth_added_while_a_linked_collection_is_active_go_into_the_scene(addon_module, capture_dir, tmp_path):
    """With a collection linked from another file active (read-only here), Import Teeth Scene raised "Collection
    'Lib' is linked" with a traceback and Add Tooth refused: both left their meshes and materials in the file. As
    Blender's Add menu does, the teeth now go into the scene's own collection."""
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.scene.collection.children.link(bpy.data.collections.new("Lib"))
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (_src, dst):
        dst.collections = ["Lib"]
    scene, layer = bpy.context.scene, bpy.context.view_layer
    scene.collection.children.link(dst.collections[0])
    layer.active_layer_collection = layer.layer_collection.children["Lib"]
    assert bpy.context.collection.library is not None
    assert bpy.ops.material_structures.teeth_add_tooth(kind="INCISOR", resolution=12) == {"FINISHED"}
    assert bpy.ops.material_structures.teeth_import_scene(
        filepath=os.path.join(capture_dir, "scene.json")) == {"FINISHED"}
    assert len(bpy.data.objects) > 3 and all(o.name in scene.objects for o in bpy.data.objects)
    assert {c.name for o in bpy.data.objects for c in o.users_collection} == {scene.collection.name}


def test_mapping_is_prefilled_where_names_match(addon_module, capture_dir):
    enamel = import_capture_scene(capture_dir)  # tooth name "tooth0", as in the capture
    assert bpy.ops.material_structures.teeth_add_tooth(kind="MOLAR", resolution=8) == {"FINISHED"}
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = capture_dir
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [("tooth0", enamel)]
    # a choice the user made survives reading the capture again
    molar = bpy.data.objects["Molar Enamel"]
    fs.tooth_map[0].enamel = molar
    assert bpy.ops.material_structures.teeth_read_capture_teeth() == {"FINISHED"}
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [("tooth0", molar)]


def test_map_by_position_finds_each_capture_tooth_in_a_moved_renamed_set(addon_module, tmp_path):
    """Three capture teeth built into the scene, all renamed "Incisor" and moved 30 mm as a set: Map by Position
    maps every capture tooth to the tooth built from it (Read Capture Teeth, by name, maps none), in one undo step."""
    from material_structures.addon.teeth.scene_build import build_teeth_scene
    from material_structures.core.teeth.scene import save_scene
    from material_structures.core.teeth.synthetic import make_scene

    ts = make_scene(n_teeth=3, resolution=8)
    save_scene(ts, str(tmp_path / "scene.json"))
    out = build_teeth_scene(ts, bpy.context.scene.collection, mm_per_unit=1000.0)
    built = {t.name: enamel for t, (enamel, _) in zip(ts.teeth, out["teeth"], strict=True)}
    for enamel in built.values():
        enamel.ms_tooth.tooth_name = "Incisor"  # no name matches the capture's, and all three share one
        enamel.location.x += 0.03
        enamel.location.z -= 0.01
    fs = bpy.context.scene.ms_teeth_fit
    fs.capture_dir = str(tmp_path)
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [(t.name, None) for t in ts.teeth]
    bpy.context.view_layer.objects.active = built[ts.teeth[0].name]
    bpy.ops.ed.undo_push(message="before mapping")
    assert bpy.ops.material_structures.teeth_map_by_position("EXEC_DEFAULT", True) == {"FINISHED"}  # as the UI
    assert [(m.capture_tooth, m.enamel) for m in fs.tooth_map] == [(t.name, built[t.name]) for t in ts.teeth]
    bpy.ops.ed.undo()
    fs = bpy.context.scene.ms_teeth_fit
    assert all(m.enamel is None for m in fs.tooth_map)


def test_map_by_position_without_a_capture_is_one_line(addon_module, tmp_path):
    bpy.context.scene.ms_teeth_fit.capture_dir = str(tmp_path)  # no scene.json
    with pytest.raises(RuntimeError, match="cannot read the capture's teeth: no scene.json"):
        bpy.ops.material_structures.teeth_map_by_position()
