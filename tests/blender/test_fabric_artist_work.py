"""An artist's fabric work survives: painted maps after save and reopen, re-imports, light links after
the material changes, and the EEVEE look follows the maps (issue: artists losing work in Blender)."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from ._fabric_maps import material_maps, stroke_kwargs, write_random_fabric_fit
from .fresh import run_fresh

UVS = [(0.2, 0.3), (0.35, 0.4), (0.5, 0.45), (0.7, 0.4)]
READ_MAPS = """
import numpy as np
from material_structures.addon.fabric.maps import images_to_maps
from material_structures.addon.fabric.material import material_map_images
RESULT = {}
for obj in bpy.data.objects:
    if obj.active_material is not None:
        m = images_to_maps(material_map_images(obj.active_material))
        RESULT[obj.name] = [m.kd.tolist(), m.basis.tolist()]
"""


def _fit_folder(tmp_path):
    write_random_fabric_fit(tmp_path / "fit", 24, 32, seed=3)
    return str(tmp_path / "fit")


def _plane(scene, name, x=0.0):
    from material_structures import render as R

    obj = R.add_textured_plane(scene, 2.0, name=name)
    obj.location.x = x
    bpy.context.view_layer.objects.active = obj
    return obj


def _plane_with_fit(tmp_path):
    """A fresh scene whose plane "A" wears the random fit (Import Fabric Maps); returns (fit folder, scene, A)."""
    from material_structures import render as R

    fit = _fit_folder(tmp_path)
    scene = R.reset_scene()
    a = _plane(scene, "A")
    assert bpy.ops.material_structures.fabric_import_maps(directory=fit) == {"FINISHED"}
    return fit, scene, a


def _brush(scene, mode="COMB", **kw):
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength = mode, 0.08, 1.0
    for k, v in kw.items():
        setattr(brush, k, v)
    return bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS))


def test_replayed_strokes_and_undo_survive_save_and_reopen(addon_module, tmp_path):

    fit, scene, a = _plane_with_fit(tmp_path)
    imported = material_maps(a)
    assert _brush(scene, "COMB") == {"FINISHED"}
    combed = material_maps(a)
    changed = np.any(combed.basis != imported.basis, axis=-1)
    assert changed.sum() > 20
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "painted.blend"))
    got = run_fresh(READ_MAPS, blend=str(tmp_path / "painted.blend"))
    np.testing.assert_allclose(np.asarray(got["A"][1]), combed.basis, atol=1e-6)

    # Ctrl+Z after a stroke (each stroke is one undo step): the undo is what gets saved.
    bpy.ops.ed.undo_push(message="Save")
    assert _brush(scene, "RECOLOR", kd=(0.0, 0.9, 0.0), ks=(0.0, 0.9, 0.0)) == {"FINISHED"}
    assert bpy.ops.ed.undo() == {"FINISHED"}
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "undone.blend"))
    got = run_fresh(READ_MAPS, blend=str(tmp_path / "undone.blend"))
    np.testing.assert_allclose(np.asarray(got["A"][0]), combed.kd, atol=1e-6)
    np.testing.assert_allclose(np.asarray(got["A"][1]), combed.basis, atol=1e-6)


def test_save_in_the_middle_of_a_stroke_keeps_the_painted_texels(addon_module, tmp_path):
    """The modal tool uploads each segment; a Ctrl+S before the button is released must save them."""
    from material_structures.addon.fabric.brushing import BrushSettings

    fit, scene, a = _plane_with_fit(tmp_path)
    from importlib import import_module

    brush_mod = import_module(f"{addon_module}.addon.fabric.brushing")
    session = brush_mod.session_for(a.active_material)
    session.begin_stroke()
    assert session.segment((0.2, 0.3), (0.7, 0.4), BrushSettings(mode="COMB", radius=0.08))
    session.flush()  # what the modal tool does per segment; the stroke is still open
    painted = material_maps(a).basis
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "mid.blend"))
    got = run_fresh(READ_MAPS, blend=str(tmp_path / "mid.blend"))
    np.testing.assert_allclose(np.asarray(got["A"][1]), painted, atol=1e-6)


def test_reimport_keeps_earlier_painting_and_materials_paint_separately(addon_module, tmp_path):

    fit, scene, a = _plane_with_fit(tmp_path)
    imported = material_maps(a)
    assert _brush(scene, "COMB") == {"FINISHED"}
    combed = material_maps(a)
    b = _plane(scene, "B", x=3.0)
    assert bpy.ops.material_structures.fabric_import_maps(directory=fit) == {"FINISHED"}
    np.testing.assert_array_equal(material_maps(a).basis, combed.basis)  # A's painting kept
    np.testing.assert_array_equal(material_maps(b).basis, imported.basis)  # B starts from the fit
    assert _brush(scene, "RECOLOR", kd=(0.0, 0.9, 0.0), ks=(0.0, 0.9, 0.0)) == {"FINISHED"}  # paints B
    np.testing.assert_array_equal(material_maps(a).kd, combed.kd)
    assert float(np.abs(material_maps(b).kd - imported.kd).max()) > 0.1


def test_stroke_that_misses_the_map_is_cancelled(addon_module, tmp_path):

    fit, scene, a = _plane_with_fit(tmp_path)
    before = material_maps(a)
    scene.material_structures.fabric_brush.radius = 0.01
    with pytest.raises(RuntimeError, match="changed no texel"):  # an ERROR report, CANCELLED
        bpy.ops.material_structures.fabric_brush(**stroke_kwargs([(3.0, 3.0), (3.5, 3.2)]))
    np.testing.assert_array_equal(material_maps(a).basis, before.basis)


def _lit_scene():
    from material_structures import render as R

    scene = R.reset_scene()
    R.configure_cycles(scene, resolution=(16, 16), samples=4)
    R.dark_world(scene)
    obj = _plane(scene, "Cloth")
    R.add_orthographic_camera(scene, 2.0)
    light = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "POINT"))
    light.data.energy = 100.0
    light.location = (0.3, -0.3, 2.0)
    scene.collection.objects.link(light)
    return scene, obj, light


def _excluded(light, obj) -> bool:
    coll = light.light_linking.receiver_collection
    if coll is None:
        return False
    return any(o.name == obj.name and e.light_linking.link_state == "EXCLUDE"
               for o, e in zip(coll.objects, coll.collection_objects, strict=True))


def test_plain_material_after_fabric_is_lit_again(addon_module):
    from material_structures import render as R

    scene, obj, light = _lit_scene()
    plain = R.new_material("Plain", clear=False)
    obj.data.materials.append(plain)
    reference = float(R.render_to_array(scene)[..., :3].mean())
    assert reference > 0.05
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    assert _excluded(light, obj)
    obj.material_slots[0].material = plain  # back to the plain material, as an artist would
    bpy.context.view_layer.update()
    assert not _excluded(light, obj)
    np.testing.assert_allclose(float(R.render_to_array(scene)[..., :3].mean()), reference, rtol=1e-6)
    assert light.light_linking.receiver_collection is None  # the link collection the fabric made is gone


def test_lamps_light_the_fabric_outside_cycles_osl(addon_module):
    """EEVEE (and Cycles without OSL) does not evaluate the exact path: no lamp may be linked off."""
    scene, obj, light = _lit_scene()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    assert _excluded(light, obj)
    scene.render.engine = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"
    bpy.context.view_layer.update()
    assert not _excluded(light, obj)
    scene.render.engine = "CYCLES"
    bpy.context.view_layer.update()
    assert _excluded(light, obj)


def test_viewport_look_follows_the_painted_maps(addon_module, tmp_path):
    """The EEVEE output reads the same maps: render it (with Cycles, OSL off: the lamp lights it as in
    EEVEE) before and after a green recolor."""
    from material_structures import render as R

    fit = _fit_folder(tmp_path)
    scene, obj, light = _lit_scene()
    assert bpy.ops.material_structures.fabric_import_maps(directory=fit) == {"FINISHED"}
    scene.cycles.shading_system = False  # the render (render_pre) lets the lamp reach the object again
    tree = obj.active_material.node_tree
    eevee = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target == "EEVEE")
    cycles = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target == "CYCLES")
    tree.links.new(eevee.inputs["Surface"].links[0].from_socket, cycles.inputs["Surface"])
    before = R.render_to_array(scene)[..., :3]
    assert not _excluded(light, obj)
    assert _brush(scene, "RECOLOR", kd=(0.0, 0.9, 0.0), ks=(0.0, 0.9, 0.0)) == {"FINISHED"}
    after = R.render_to_array(scene)[..., :3]
    greener = (after[..., 1] - after[..., 0]) - (before[..., 1] - before[..., 0])
    assert float(greener.max()) > 0.05, float(greener.max())
    assert _brush(scene, "COMB") == {"FINISHED"}
    combed = R.render_to_array(scene)[..., :3]
    assert float(np.abs(combed - after).max()) > 1e-3  # combing changes the viewport look too


def test_corduroy_preset_has_wales_like_the_library(addon_module):
    from material_structures.core.fabric.preset_maps import CORDUROY_WALES
    from material_structures.showcase.scenes_fabric import _preset_maps

    scene = bpy.context.scene
    obj = _plane(scene, "Bolster")
    assert bpy.ops.material_structures.fabric_new_material(preset="CORDUROY") == {"FINISHED"}
    maps = material_maps(obj)  # BTF frame (y down the image)
    q = maps.basis[0].astype(np.float64)  # one row across u
    lean_x = 2.0 * (q[:, 1] * q[:, 3] + q[:, 0] * q[:, 2])  # x component of the fibre axis
    flips = int(np.count_nonzero(np.diff(np.sign(lean_x[np.abs(lean_x) > 0.05])) != 0))
    assert flips >= 2 * CORDUROY_WALES - 1, flips  # leaning to either flank of every ridge
    library = _preset_maps("CORDUROY", seed=1)
    np.testing.assert_allclose(np.abs(maps.basis), np.abs(library.basis), atol=1e-6)


def test_viewport_samples_in_the_tab_are_cycles_own(addon_module):

    scene = bpy.context.scene
    scene.material_structures.preview_samples = 7
    assert scene.cycles.preview_samples == 7
    scene.cycles.preview_samples = 19
    assert scene.material_structures.preview_samples == 19


def _link_objects(path, names) -> list:
    with bpy.data.libraries.load(path, link=True) as (_, dst):
        dst.objects = list(names)
    for obj in dst.objects:
        bpy.context.scene.collection.objects.link(obj)
    return dst.objects


def _linked_set(tmp_path):
    """A new scene with a cloth and the lamp whose light the fabric's exact path left it out of, both linked from
    the file ``set.blend`` they were made in: (scene, cloth, lamp)."""
    scene, obj, light = _lit_scene()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    assert _excluded(light, obj)
    both = str(tmp_path / "set.blend")
    bpy.data.libraries.write(both, {light, obj}, fake_user=True)
    scene, _, light = _lit_scene()
    for o in (light, bpy.data.objects["Cloth"]):
        bpy.data.objects.remove(o)
    cloth, lamp = sorted(_link_objects(both, ["Cloth", "Key"]), key=lambda o: o.type != "MESH")
    return scene, cloth, lamp


def test_a_lamp_linked_from_another_file_is_left_as_it_is_and_lights_the_fabric_once(addon_module, tmp_path):
    """A lamp linked from another file: its light linking is read-only here (a change would not be saved, and the
    handlers raised trying). The fabric leaves it as it is: one without light links lights the fabric through Cycles'
    closures only (the exact path would light it a second time) and no link collection is made for it; one whose
    file already leaves the fabric out (the fabric made that link there) is evaluated by the exact path; with OSL
    off nothing is written either."""
    from material_structures.addon.fabric.material import sync_fabric_lamps

    scene, obj, light = _lit_scene()
    lamp_only = str(tmp_path / "lamp.blend")
    bpy.data.libraries.write(lamp_only, {light}, fake_user=True)
    bpy.data.objects.remove(light)
    (linked,) = _link_objects(lamp_only, ["Key"])
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    collections = len(bpy.data.collections)
    assert sync_fabric_lamps(scene) == 0
    bpy.context.view_layer.update()
    assert linked.light_linking.receiver_collection is None and len(bpy.data.collections) == collections

    scene, cloth, lamp = _linked_set(tmp_path)
    assert lamp.library is not None and _excluded(lamp, cloth)
    assert sync_fabric_lamps(scene) == 1
    scene.cycles.shading_system = False
    assert sync_fabric_lamps(scene) == 1  # evaluated nowhere now; its links stay as its file has them
    assert _excluded(lamp, cloth)


class _Layout:
    """Records what a panel's draw function writes."""

    def __init__(self):
        self.labels, self.alert = [], False

    def column(self, align=False):
        return self

    def label(self, text="", icon="NONE"):
        self.labels.append((text, icon))


def test_a_linked_lamp_that_leaves_its_cloth_unlit_here_is_named_in_the_panel(addon_module, tmp_path):
    """A lamp and a cloth linked together from a file where the fabric's exact path left the cloth out of the lamp's
    light: here, without Open Shading Language, nothing lights the cloth with that lamp and its links are
    read-only. The fabric panel names the lamp and what lights the cloth (OSL on, or the lamp made local); made
    local, the lamp lights the cloth through Cycles' closures."""
    from material_structures import render as R
    from material_structures.addon.fabric.material import lamps_leaving_fabric_unlit, sync_fabric_lamps
    from material_structures.addon.fabric.panels import draw_unlit_warnings

    scene, cloth, lamp = _linked_set(tmp_path)
    assert scene.cycles.shading_system and sync_fabric_lamps(scene) == 1
    assert lamps_leaving_fabric_unlit(scene) == []  # the exact path lights it
    layout = _Layout()
    draw_unlit_warnings(layout, scene, cloth)
    assert layout.labels == []
    lit = float(R.render_to_array(scene)[..., :3].mean())
    assert lit > 0.01
    # four lamps of this file before it by name: the shader evaluates those four, and "Key" lights nothing
    extra = []
    for i in range(4):
        extra.append(bpy.data.objects.new(f"A{i}", bpy.data.lights.new(f"A{i}", "POINT")))
        extra[-1].location = (5.0, 5.0, -5.0)
        scene.collection.objects.link(extra[-1])
    sync_fabric_lamps(scene)
    assert [(lamp_.name, [o.name for o in objs]) for lamp_, objs in lamps_leaving_fabric_unlit(scene)] == [
        ("Key", ["Cloth"])]
    for o in extra:
        bpy.data.objects.remove(o)
    sync_fabric_lamps(scene)
    assert lamps_leaving_fabric_unlit(scene) == []

    scene.cycles.shading_system = False
    sync_fabric_lamps(scene)
    assert [(lamp_.name, [o.name for o in objs]) for lamp_, objs in lamps_leaving_fabric_unlit(scene)] == [
        ("Key", ["Cloth"])]
    assert float(R.render_to_array(scene)[..., :3].mean()) < 0.02 * lit  # unlit: what the panel warns of
    draw_unlit_warnings(layout, scene, cloth)
    assert layout.labels == [("Lamp 'Key' from set.blend leaves this object unlit here", "ERROR"),
                             ("Its file's light links are for the exact path: turn on Open Shading Language",
                              "NONE")] and layout.alert

    with bpy.context.temp_override(selected_objects=[lamp], active_object=lamp):
        assert bpy.ops.object.make_local(type="ALL") == {"FINISHED"}
    lamp = bpy.data.objects["Key"]
    assert lamp.library is None
    sync_fabric_lamps(scene)
    assert lamps_leaving_fabric_unlit(scene) == [] and not _excluded(lamp, bpy.data.objects["Cloth"])
    assert float(R.render_to_array(scene)[..., :3].mean()) > 0.5 * lit  # the closures' light

    # an exclusion the artist made in the other file (not the fabric's) is theirs: no warning for it
    scene2, cloth2, rim = _lit_scene()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    scene2.cycles.shading_system = False
    sync_fabric_lamps(scene2)
    own = bpy.data.collections.new("Rim receivers")
    own.objects.link(cloth2)
    rim.light_linking.receiver_collection = own
    own.collection_objects[0].light_linking.link_state = "EXCLUDE"
    rim.name = cloth2.name = "Theirs"
    artist = str(tmp_path / "artist.blend")
    bpy.data.libraries.write(artist, {rim, cloth2}, fake_user=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    scene, _, light = _lit_scene()
    bpy.data.objects.remove(light)
    bpy.data.objects.remove(bpy.data.objects["Cloth"])
    scene.cycles.shading_system = False
    theirs = _link_objects(artist, ["Theirs", "Theirs.001"])
    rim, cloth2 = sorted(theirs, key=lambda o: o.type != "LIGHT")
    assert rim.library is not None and _excluded(rim, cloth2)  # unlit by it, as its file chose
    assert lamps_leaving_fabric_unlit(scene) == []

    # a lamp its file hides from renders lights nothing anywhere: no warning, OSL on or off
    scene3, _, light3 = _lit_scene()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    light3.hide_render = True
    light3.name, bpy.data.objects["Cloth"].name = "Hidden", "Cloth3"
    hidden = str(tmp_path / "hidden.blend")
    bpy.data.libraries.write(hidden, {light3, bpy.data.objects["Cloth3"]}, fake_user=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    scene, _, light = _lit_scene()
    bpy.data.objects.remove(light)
    bpy.data.objects.remove(bpy.data.objects["Cloth"])
    lamp3, cloth3 = sorted(_link_objects(hidden, ["Hidden", "Cloth3"]), key=lambda o: o.type != "LIGHT")
    assert lamp3.hide_render and _excluded(lamp3, cloth3)
    for osl in (True, False):
        scene.cycles.shading_system = osl
        assert lamps_leaving_fabric_unlit(scene) == []


def test_a_finished_background_fit_is_an_undo_step_of_its_own(addon_module, tmp_path):
    """Fit BTF runs in the background and makes its material when the fit ends, after the operator returned: that
    material is one undo step of its own (Edit > Undo History: Fabric Fit). Without it, Ctrl+Z took the fitted
    material back together with the artist's last edit before it."""
    from types import SimpleNamespace

    from material_structures import render as R
    from material_structures.addon.fabric.operators import _watch

    fit = _fit_folder(tmp_path)
    scene = R.reset_scene()
    cloth = _plane(scene, "Cloth")
    bpy.ops.ed.undo_push(message="Cloth")
    cloth.location.x = 1.0
    bpy.ops.ed.undo_push(message="Move")
    job = SimpleNamespace(out_dir=fit, log_path="fit_log.txt", last_line="", settled=False, outcome="",
                          is_alive=lambda: False, poll=lambda: "FINISHED")
    assert _watch(job, scene.name, "Cloth")() is None  # the timer's last tick: the fit has ended
    assert bpy.data.objects["Cloth"].active_material is not None
    bpy.ops.ed.undo()  # Ctrl+Z: the fitted material goes, the move stays
    assert bpy.data.objects["Cloth"].active_material is None
    assert bpy.data.objects["Cloth"].location.x == 1.0


def test_a_new_fabric_material_never_builds_on_a_group_linked_from_another_file(addon_module, tmp_path):
    """A file that links a cloth from another file holds that file's "SGGX Fabric" group: New Fabric Material built
    its new local material on it (found by name), so the material lost its shader once the other file moved, and
    the add-on's upgrades to the group were never saved. It now gets this file's own group."""
    scene = bpy.context.scene
    _plane(scene, "Cloth")
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    _link_objects(path, ["Cloth"])
    linked = [g for g in bpy.data.node_groups if g.name == "SGGX Fabric"]
    assert len(linked) == 1 and linked[0].library is not None
    plane = _plane(bpy.context.scene, "Mine", x=3.0)
    assert bpy.ops.material_structures.fabric_new_material(preset="CORDUROY") == {"FINISHED"}
    group = next(n for n in plane.active_material.node_tree.nodes if n.type == "GROUP").node_tree
    assert group.name == "SGGX Fabric" and group.library is None


def test_a_lamp_copy_sharing_its_receiver_collection_does_not_undo_the_lamps_exclusion(addon_module):
    """A lamp with the artist's own light links (the backdrop left out), copied with Shift+D (the copy shares the
    receiver collection) and the copy hidden from renders: each sync, the copy's pass took back the cloth's exclusion
    the first lamp needs, so that lamp lit the cloth twice (through the shader and through Cycles). The copy now
    gets a collection of its own, with the artist's links."""
    from material_structures.addon.fabric.material import sync_fabric_lamps

    scene, cloth, key = _lit_scene()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    backdrop = bpy.data.objects.new("Backdrop", bpy.data.meshes.new("Backdrop"))
    scene.collection.objects.link(backdrop)
    mine = bpy.data.collections.new("Key Receivers")
    mine.objects.link(backdrop)
    mine.collection_objects[0].light_linking.link_state = "EXCLUDE"
    key.light_linking.receiver_collection = mine
    sync_fabric_lamps(scene)
    assert _excluded(key, cloth) and _excluded(key, backdrop)
    copy = key.copy()  # what Shift+D makes of the lamp object
    scene.collection.objects.link(copy)
    copy.hide_render = True
    assert copy.light_linking.receiver_collection == mine
    for _ in range(2):
        sync_fabric_lamps(scene)
        assert _excluded(key, cloth) and _excluded(key, backdrop)
        assert not _excluded(copy, cloth) and _excluded(copy, backdrop)
    assert copy.light_linking.receiver_collection != key.light_linking.receiver_collection
