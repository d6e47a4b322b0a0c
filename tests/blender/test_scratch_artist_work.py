"""An artist's scratched-metal work survives (issue: an artist never loses work in Blender): each material
owns its scratch set (a second object's Generate or Import no longer replaces the first one's, before
or after save and reopen, old files included), World Lights is a real setting, Import/Export refuse
what they cannot read or write, long generations show progress and can be cancelled, a draw stroke
that adds nothing is an error."""

from __future__ import annotations

import hashlib
import os
import threading
import time

import bpy
import numpy as np
import pytest

from .fresh import run_fresh

SET_DIGESTS = """
import hashlib
import numpy as np
from material_structures.addon.scratch.editing import material_set, object_scratch_material
RESULT = {}
for obj in bpy.data.objects:
    found = material_set(object_scratch_material(obj))
    if found is not None:
        seg = np.asarray(found[1].segments, np.float32)
        RESULT[obj.name] = [found[0], int(seg.shape[0]), hashlib.sha1(seg.tobytes()).hexdigest(),
                            object_scratch_material(obj).name]
"""


def _digest(s) -> tuple[int, str]:
    seg = np.asarray(s.segments, np.float32)  # the packed tables are float32
    return int(seg.shape[0]), hashlib.sha1(seg.tobytes()).hexdigest()


def _set_of(obj):
    from material_structures.addon.scratch.editing import material_set, object_scratch_material

    found = material_set(object_scratch_material(obj))
    return None if found is None else found[1]


def _plane(scene, name, x=0.0):
    from material_structures import render as R

    obj = R.add_textured_plane(scene, 1.0, name=name)
    obj.location.x = x
    _activate(obj)
    return obj


def _activate(obj):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def _expected_wear(seed, count=500, patch_mm=20.0):
    """What Generate's defaults make for ``seed``, straight from the generator (no Blender data)."""
    from material_structures.addon.scratch.editing import generate_set

    return _digest(generate_set("WEAR", count, patch_mm, seed=seed))


@pytest.fixture
def scene(addon_module):
    from material_structures import render as R

    return R.reset_scene()


# -- item 3: a scratch set is owned by its material ---------------------------------------------------
def test_two_objects_keep_their_own_sets_after_save_and_reopen(scene, tmp_path):
    a = _plane(scene, "A")
    assert bpy.ops.material_structures.scratch_generate(seed=1) == {"FINISHED"}
    b = _plane(scene, "B", x=2.0)
    assert bpy.ops.material_structures.scratch_generate(seed=2) == {"FINISHED"}
    want = {"A": _expected_wear(1), "B": _expected_wear(2)}
    assert want["A"] != want["B"]
    assert _digest(_set_of(a)) == want["A"], "generating on B replaced A's scratches"
    assert _digest(_set_of(b)) == want["B"]
    assert a.active_material != b.active_material
    path = str(tmp_path / "two.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    got = run_fresh(SET_DIGESTS, blend=path)
    for name in ("A", "B"):
        assert tuple(got[name][1:3]) == want[name], f"{name} after reopening: {got[name]}"
    assert got["A"][0] == "Scratches" and got["B"][0] == "Scratches.001"  # uniquified like Blender names


def test_updating_a_material_changes_only_that_material(scene):
    a = _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(seed=1)
    b = _plane(scene, "B", x=2.0)
    bpy.ops.material_structures.scratch_generate(seed=2)
    # Regenerating A's material leaves B's alone.
    _activate(a)
    assert bpy.ops.material_structures.scratch_generate(seed=3) == {"FINISHED"}
    assert _digest(_set_of(a)) == _expected_wear(3)
    assert _digest(_set_of(b)) == _expected_wear(2)
    # C wears A's material: the user shares it on purpose, so C's Generate updates A too.
    c = _plane(scene, "C", x=4.0)
    c.data.materials.append(a.active_material)
    assert bpy.ops.material_structures.scratch_generate(seed=4) == {"FINISHED"}
    assert _digest(_set_of(a)) == _digest(_set_of(c)) == _expected_wear(4)
    # D wears a copy of B's material (Blender copies share the node group): D's Generate must not touch B.
    d = _plane(scene, "D", x=6.0)
    d.data.materials.append(b.active_material.copy())
    assert bpy.ops.material_structures.scratch_generate(seed=5) == {"FINISHED"}
    assert _digest(_set_of(d)) == _expected_wear(5)
    assert _digest(_set_of(b)) == _expected_wear(2), "the material copy's Generate changed the original"
    # Drawing on D changes D only.
    stroke = [{"name": "", "location": (0, 0, 0), "uv": (0.1 + 0.1 * i, 0.5), "pressure": 1.0} for i in range(5)]
    assert bpy.ops.material_structures.scratch_draw(stroke=stroke) == {"FINISHED"}
    assert _set_of(d).n_segments > _expected_wear(5)[0]
    assert _digest(_set_of(b)) == _expected_wear(2)


def test_appended_material_brings_and_keeps_its_own_set(scene, tmp_path):
    """A material appended from another file (the asset library, a colleague's file) whose set has the
    same name as one here: it renders its own set, and updating either leaves the other alone."""
    from material_structures import render as R

    _plane(scene, "W")
    assert bpy.ops.material_structures.scratch_generate(seed=7) == {"FINISHED"}
    bpy.data.objects["W"].active_material.use_fake_user = True
    lib = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=lib)

    scene = R.reset_scene()
    a = _plane(scene, "A")
    assert bpy.ops.material_structures.scratch_generate(seed=1) == {"FINISHED"}
    with bpy.data.libraries.load(lib, link=False) as (_src, dst):
        dst.materials = ["Scratched Metal Scratches"]
    b = _plane(scene, "B", x=2.0)
    b.data.materials.append(dst.materials[0])
    assert _digest(_set_of(b)) == _expected_wear(7), "the appended material shows another set"
    assert _digest(_set_of(a)) == _expected_wear(1)
    assert bpy.ops.material_structures.scratch_generate(seed=2) == {"FINISHED"}  # on B
    _activate(a)
    assert bpy.ops.material_structures.scratch_generate(seed=3) == {"FINISHED"}
    assert _digest(_set_of(a)) == _expected_wear(3)
    assert _digest(_set_of(b)) == _expected_wear(2)


def test_import_gives_each_material_its_own_set(scene, tmp_path):
    from material_structures.addon.scratch.editing import generate_set
    from material_structures.core.scratch.scratch_io import save_scratch_set

    src = generate_set("WEAR", 120, 20.0, seed=11)
    save_scratch_set(str(tmp_path / "worn.npz"), src)
    a = _plane(scene, "A")
    assert bpy.ops.material_structures.scratch_import(filepath=str(tmp_path / "worn.npz")) == {"FINISHED"}
    b = _plane(scene, "B", x=2.0)
    assert bpy.ops.material_structures.scratch_import(filepath=str(tmp_path / "worn.npz")) == {"FINISHED"}
    assert a.active_material != b.active_material
    assert bpy.ops.material_structures.scratch_generate(seed=2) == {"FINISHED"}  # on B
    assert _digest(_set_of(a)) == _digest(src), "B's Generate changed A's imported set"
    assert _digest(_set_of(b)) == _expected_wear(2)


OLD_FILE_RENDER = """
import hashlib
import numpy as np
from material_structures.render import render_to_array
from material_structures.addon.scratch.editing import material_set, object_scratch_material

def digests():
    out = {}
    for obj in bpy.data.objects:
        found = material_set(object_scratch_material(obj))
        if found is not None:
            seg = np.asarray(found[1].segments, np.float32)
            out[obj.name] = [int(seg.shape[0]), hashlib.sha1(seg.tobytes()).hexdigest()]
    return out

scene = bpy.context.scene
RESULT = {"loaded": digests(), "render": render_to_array(scene)[..., :3].tolist()}
if __GENERATE__:
    from material_structures import render as R
    b = R.add_textured_plane(scene, 1.0, name="B")
    b.location.x = 10.0  # outside the camera's view
    bpy.context.view_layer.objects.active = b
    RESULT["op"] = list(bpy.ops.material_structures.scratch_generate(seed=2, set_name="plate"))
    RESULT["after"] = digests()
    RESULT["render_after"] = render_to_array(scene)[..., :3].tolist()
    bpy.ops.wm.save_as_mainfile(filepath=__SAVE__)
"""


def _old_file_snippet(generate: bool, save: str) -> str:
    return OLD_FILE_RENDER.replace("__GENERATE__", repr(generate)).replace("__SAVE__", repr(save))


def test_file_with_the_old_naming_loads_renders_and_keeps_its_set(scene, tmp_path):
    """A file from before: one group per set *name*, tables found by image name only. It reopens and
    renders as before, and a new set of the same name on another object leaves it alone."""
    from material_structures import render as R
    from material_structures.addon.scratch.material import create_scratched_metal, group_node, sync_scratch_lamps
    from material_structures.addon.scratch.verify import add_lamp, test_scratch_set

    R.configure_cycles(scene, resolution=(8, 8), samples=1, seed=0)
    R.dark_world(scene)
    s = test_scratch_set()
    mat = create_scratched_metal("Plate", s, "plate", scene=scene)
    group = group_node(mat).node_tree
    group_node(mat).inputs["Debug"].default_value = 1  # the scratch term alone: pixels depend on the set
    assert group.name == "Scratched Metal (plate)"
    for key in [k for k in group.keys() if k not in ("ms_scratch_set", "material_structures_scratch")]:
        del group[key]  # as written before: the marker and the metadata; images found by their names
    for image in bpy.data.images:
        image.use_fake_user = image.name.startswith("MS Scratch plate ")  # ... and kept by fake users
    assert sorted(i.name for i in bpy.data.images if i.name.startswith("MS Scratch plate ")) == [
        f"MS Scratch plate {t}" for t in ("cells", "grid", "params", "segments")]
    R.add_textured_plane(scene, 1.0, mat, name="A")
    R.look_from(R.add_orthographic_camera(scene, ortho_scale=0.9), R.view_direction(25.0, 200.0))
    add_lamp(scene, "POINT", (0.5, 0.3, 1.2), 200.0, radius=0.08)
    sync_scratch_lamps(scene)
    ref = R.render_to_array(scene)[..., :3]
    assert float(ref.max()) > 0.0  # scratch glints visible
    want_a = list(_digest(_set_of(bpy.data.objects["A"])))
    old = str(tmp_path / "old.blend")
    bpy.ops.wm.save_as_mainfile(filepath=old)

    new = str(tmp_path / "new.blend")
    got = run_fresh(_old_file_snippet(True, new), blend=old)
    assert got["loaded"]["A"] == want_a
    np.testing.assert_allclose(np.asarray(got["render"]), ref, rtol=0, atol=1e-6)
    assert got["op"] == ["FINISHED"]
    assert got["after"]["A"] == want_a, "a new set named like the old file's replaced it"
    assert got["after"]["B"] == list(_expected_wear(2))
    np.testing.assert_allclose(np.asarray(got["render_after"]), ref, rtol=0, atol=1e-6)
    again = run_fresh(_old_file_snippet(False, ""), blend=new)
    assert again["loaded"] == {"A": want_a, "B": list(_expected_wear(2))}
    np.testing.assert_allclose(np.asarray(again["render"]), ref, rtol=0, atol=1e-6)


# -- 10b: World Lights ------------------------------------------------------------------------------
class _Recorder:
    """Stand-in for a panel's layout: records every prop() drawn."""

    def __init__(self):
        self.props = []

    def prop(self, data, name, **kw):
        self.props.append((data, name, kw.get("text")))

    def __getattr__(self, _name):
        return lambda *a, **k: self


def _env_world(scene):
    from .test_scratch_world import env_world

    env_world(scene, pack=True)  # saved with the file


def _scratched_plane_under_an_environment(scene):
    """Plane "A" with a 20-scratch metal, the world an environment image (World Lights left off)."""
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
        if scene.world.node_tree is None:  # 4.5
            scene.world.use_nodes = True
    _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=20, seed=1)
    _env_world(scene)


def test_world_lights_is_a_setting_drawn_always_and_read_by_the_shader(scene):
    from types import SimpleNamespace

    from material_structures.addon.scratch.material import scratch_script_nodes, sync_scratch_lamps
    from material_structures.addon.scratch.panels import MATERIAL_PT_material_structures_scratch as Panel

    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
        if scene.world.node_tree is None:  # 4.5
            scene.world.use_nodes = True
    obj = _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=20, seed=1)
    assert "ms_scratch_world_lamps" not in scene.keys()
    layout = _Recorder()
    Panel.draw(SimpleNamespace(layout=layout), SimpleNamespace(material=obj.active_material, scene=scene))
    drawn = [(name, text) for data, name, text in layout.props if data == scene.material_structures]
    assert ("scratch_world_lamps", "World Lights") in drawn, layout.props

    rna = scene.material_structures.bl_rna.properties["scratch_world_lamps"]
    assert rna.name == "World Lights" and rna.hard_min == 0 and rna.hard_max == 4
    _env_world(scene)
    node = next(scratch_script_nodes())
    sync_scratch_lamps(scene)
    assert node.inputs["Lamp1Type"].default_value == 0  # 0 = off, the default
    scene.material_structures.scratch_world_lamps = 2
    sync_scratch_lamps(scene)
    assert node.inputs["Lamp1Type"].default_value == 1  # the sun region as a sphere lamp
    assert node.inputs["Lamp1Radius"].default_value > 0


def test_world_lights_read_the_environment_once_not_on_every_lamp_move(scene, monkeypatch):
    """With World Lights on, every lamp move (a depsgraph update) syncs the scratch lamps: the environment image is
    read and reduced once (a 2K one took 0.13 s, a 4K one 0.49 s on every step of a lamp drag), again only for
    another image, and the strength still follows every change."""
    from material_structures.addon import world_environment as E
    from material_structures.addon.scratch import world as W
    from material_structures.addon.scratch.material import scratch_script_nodes, sync_scratch_lamps

    _scratched_plane_under_an_environment(scene)
    scene.material_structures.scratch_world_lamps = 2
    reads = []
    real = E.image_radiance
    monkeypatch.setattr(E, "image_radiance", lambda image: reads.append(image.name) or real(image))
    W.__dict__.get("_downsampled", {}).clear()  # a cold cache
    node = next(scratch_script_nodes())
    colours = []
    for step in range(3):
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0 + step
        sync_scratch_lamps(scene)
        colours.append(node.inputs["Lamp1Color"].default_value[0])
    assert reads == ["Env"]
    assert colours[1] == pytest.approx(2.0 * colours[0]) and colours[2] == pytest.approx(3.0 * colours[0])
    tex = next(n for n in scene.world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
    tex.image = tex.image.copy()
    sync_scratch_lamps(scene)
    assert len(reads) == 2


def test_generate_acts_on_the_active_material_of_an_object_with_two(scene):
    """An object wearing two scratched metals: Generate, Import and Export act on the active one, the one whose
    material panel the artist is in (before: on the first slot's, replacing a set the artist did not touch)."""
    from material_structures.addon.scratch.editing import material_set

    a = _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=50, seed=1, set_name="Brass")
    b = _plane(scene, "B", x=3.0)
    bpy.ops.material_structures.scratch_generate(count=50, seed=2, set_name="Steel")
    brass, steel = a.active_material, b.active_material
    _activate(a)
    bpy.ops.object.material_slot_add()
    a.material_slots[1].material = steel
    a.active_material_index = 1
    before = _digest(material_set(brass)[1])
    assert bpy.ops.material_structures.scratch_generate(count=300, seed=3) == {"FINISHED"}
    assert material_set(steel)[1].n_scratches == 300
    assert _digest(material_set(brass)[1]) == before
    a.active_material_index = 0
    assert _set_of(a).n_scratches == 50  # the first slot's, now active


def test_new_materials_on_a_linked_object_are_one_line_and_leave_nothing_behind(scene, tmp_path):
    """Generate Scratches and New Fabric Material on an object linked from another file raised a traceback
    ("MaterialSlot.material is read-only") and left the new material's group and images in the file."""
    _plane(scene, "Plate")
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (_src, dst):
        dst.objects = ["Plate"]
    plate = dst.objects[0]
    bpy.context.scene.collection.objects.link(plate)
    bpy.context.view_layer.objects.active = plate
    before = (len(bpy.data.materials), len(bpy.data.images), len(bpy.data.node_groups))
    for op, kwargs in ((bpy.ops.material_structures.scratch_generate, {"count": 20}),
                       (bpy.ops.material_structures.fabric_new_material, {"preset": "PLUSH"})):
        with pytest.raises(RuntimeError) as info:
            op(**kwargs)
        msg = str(info.value)
        assert "Traceback" not in msg and "'Plate' is linked from" in msg and "Make Local" in msg, msg
    assert (len(bpy.data.materials), len(bpy.data.images), len(bpy.data.node_groups)) == before


def test_a_scratch_group_whose_script_node_was_deleted_breaks_only_itself(scene):
    """Deleting the script node inside one scratched metal's group made every scratch sync raise StopIteration:
    the other scratched materials stopped following their lamps, Generate on them failed, and the load handlers
    stopped half way. Now the other materials go on, and Generate on the broken one says why in one line."""
    from material_structures.addon.scratch.material import scratch_script_nodes

    a = _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=30, set_name="Broken")
    b = _plane(scene, "B", x=3.0)
    bpy.ops.material_structures.scratch_generate(count=30, set_name="Fine")
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    scene.collection.objects.link(lamp)
    group = a.active_material.node_tree.nodes["Scratched Metal"].node_tree
    group.nodes.remove(next(n for n in group.nodes if n.type == "SCRIPT"))
    lamp.location = (1.0, 2.0, 3.0)
    bpy.context.view_layer.update()  # the depsgraph handlers sync the lamps
    fine = next(scratch_script_nodes())
    assert tuple(fine.inputs["Lamp1Position"].default_value) == pytest.approx((1.0, 2.0, 3.0))
    _activate(b)
    assert bpy.ops.material_structures.scratch_generate(count=40) == {"FINISHED"}
    _activate(a)
    before = _digest(_set_of(a))
    for replace in (False, True):
        with pytest.raises(RuntimeError, match="has lost its scratch script node") as info:
            bpy.ops.material_structures.scratch_generate(count=40, replace=replace)
        assert "Traceback" not in str(info.value)
        assert _digest(_set_of(a)) == before  # refused before anything changed


def test_draw_scratches_poll_reads_no_set(scene, monkeypatch, addon_module):
    """The poll runs on every redraw of the Scratches panels: it read and checked the whole set there (30 ms at
    10 000 scratches, 200 ms at 50 000: the interface stuttered). It now only looks for the set."""
    from importlib import import_module

    editing = import_module(f"{addon_module}.addon.scratch.editing")
    _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=20)
    reads = []
    real = editing.load_group_set
    monkeypatch.setattr(editing, "load_group_set", lambda group: reads.append(group.name) or real(group))
    assert bpy.ops.material_structures.scratch_draw.poll()
    assert reads == []
    bpy.context.active_object.active_material = None
    assert not bpy.ops.material_structures.scratch_draw.poll()


WORLD_LIGHTS = """
from material_structures.addon.scratch.material import scratch_script_nodes, sync_scratch_lamps
scene = bpy.context.scene
sync_scratch_lamps(scene)
RESULT = [scene.material_structures.scratch_world_lamps, next(scratch_script_nodes()).inputs["Lamp1Type"].default_value]
"""


def test_world_lights_set_the_old_way_keep_working_after_reopen(scene, tmp_path):
    _scratched_plane_under_an_environment(scene)
    scene["ms_scratch_world_lamps"] = 1  # how files and scripts set it before
    path = str(tmp_path / "old_world.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    assert run_fresh(WORLD_LIGHTS, blend=path) == [1, 1]


# -- 10d, 10e: Import / Export paths ------------------------------------------------------------------
def test_import_of_a_file_inside_an_exr_table_folder_imports_the_folder(scene, tmp_path):
    from material_structures.addon.scratch.editing import generate_set
    from material_structures.core.scratch.scratch_io import save_scratch_set

    src = generate_set("WEAR", 40, 20.0, seed=6)
    save_scratch_set(str(tmp_path / "tables"), src)
    a = _plane(scene, "A")
    picked = tmp_path / "tables" / "segment_params.exr"
    assert bpy.ops.material_structures.scratch_import(filepath=str(picked)) == {"FINISHED"}
    assert _digest(_set_of(a)) == _digest(src)
    (tmp_path / "notes.txt").write_text("not a scratch set")
    with pytest.raises(RuntimeError) as info:
        bpy.ops.material_structures.scratch_import(filepath=str(tmp_path / "notes.txt"))
    msg = str(info.value)
    assert "pickle" not in msg.lower() and ".npz" in msg and "EXR" in msg, msg
    assert _digest(_set_of(a)) == _digest(src)


def test_export_to_a_path_with_another_extension_is_refused(scene, tmp_path):
    _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=20, seed=1)
    for name in ("set.exr", "set.png"):
        with pytest.raises(RuntimeError, match="extension"):
            bpy.ops.material_structures.scratch_export(filepath=str(tmp_path / name))
        assert not os.path.exists(tmp_path / name), f"{name} was written anyway"
    assert bpy.ops.material_structures.scratch_export(filepath=str(tmp_path / "set.npz")) == {"FINISHED"}
    assert bpy.ops.material_structures.scratch_export(filepath=str(tmp_path / "tables")) == {"FINISHED"}
    assert os.path.isfile(tmp_path / "set.npz") and os.path.isfile(tmp_path / "tables" / "meta.exr")


# -- 10h: progress and cancel -------------------------------------------------------------------------
class _Ev:
    def __init__(self, type_, value="NOTHING"):
        self.type, self.value = type_, value


def _modal_stub(count, seed):
    """The Generate operator's modal methods on a stand-in (INVOKE needs a window; background has none)."""
    from material_structures.addon.scratch.operators import MS_OT_scratch_generate as Op

    class Stub:
        pattern, patch_mm, angle_deg, fine_wear, replace, set_name = "WEAR", 20.0, 0.0, False, True, "Scratches"
        length_um, width_um, depth_um = (300.0, 4000.0), (0.8, 6.0), (0.8, 6.0)
        reports: list = []

        def report(self, kind, text):
            self.reports.append((set(kind), text))

    op = Stub()
    op.count, op.seed = count, seed
    for name in dir(Op):
        if name.startswith("_") and not name.startswith("__") and callable(getattr(Op, name)):
            setattr(op, name, getattr(Op, name).__get__(op))
    op.modal = Op.modal.__get__(op)
    return op


def test_generate_10k_headless_modal_progress_and_cancel(scene):
    from material_structures.addon.scratch import operators as ops

    a = _plane(scene, "A")
    t = time.perf_counter()
    assert bpy.ops.material_structures.scratch_generate(count=10_000, seed=3) == {"FINISHED"}  # EXEC, no window
    exec_s = time.perf_counter() - t
    s = _set_of(a)
    assert s.n_scratches >= 9_900
    before = _digest(s)

    # The modal path: the generation runs beside Blender, TIMER events show the progress, ESC cancels.
    op = _modal_stub(10_000, 4)
    ctx = bpy.context
    assert op._start_job(ctx) is True
    assert op.modal(ctx, _Ev("ESC", "PRESS")) == {"CANCELLED"}
    assert not any(th.name == ops.JOB_THREAD_NAME for th in threading.enumerate()), "the job still runs"
    assert _digest(_set_of(a)) == before, "a cancelled generation changed the set"

    op = _modal_stub(10_000, 5)
    assert op._start_job(ctx) is True
    shown, deadline = [], time.perf_counter() + max(120.0, 6 * exec_s)
    while True:
        res = op.modal(ctx, _Ev("TIMER"))
        shown.append(op._job.fraction)
        if res != {"RUNNING_MODAL"} or time.perf_counter() > deadline:
            break
        assert op.modal(ctx, _Ev("MOUSEMOVE")) == {"PASS_THROUGH"}  # the viewport stays usable
        time.sleep(0.05)
    assert res == {"FINISHED"}, op.reports
    assert len(shown) > 5 and shown[-1] == 1.0
    assert all(b >= a for a, b in zip(shown, shown[1:], strict=False))
    assert len(set(shown)) > 3, shown  # the bar moved
    after = _set_of(a)
    assert after.n_scratches >= 9_900 and _digest(after) != before  # seed 5's set replaced seed 3's


# -- draw stroke that adds nothing ----------------------------------------------------------------------
def test_draw_stroke_that_misses_or_adds_nothing_is_cancelled(scene):
    a = _plane(scene, "A")
    bpy.ops.material_structures.scratch_generate(count=20, seed=1)
    before, n_before = _digest(_set_of(a)), _set_of(a).n_scratches
    far = [{"name": "", "location": (5.0 + 0.1 * i, 5.0, 3.0), "uv": (0, 0), "pressure": 1.0} for i in range(5)]
    with pytest.raises(RuntimeError, match="does not touch"):
        bpy.ops.material_structures.scratch_draw(stroke=far, stroke_space="WORLD")
    outside = [{"name": "", "location": (0, 0, 0), "uv": (1.5 + 0.1 * i, 1.7), "pressure": 1.0} for i in range(5)]
    with pytest.raises(RuntimeError, match="adds no scratch"):
        bpy.ops.material_structures.scratch_draw(stroke=outside)
    assert _digest(_set_of(a)) == before
    on = [{"name": "", "location": (-0.4 + 0.2 * i, 0.1, 0.0), "uv": (0, 0), "pressure": 1.0} for i in range(5)]
    assert bpy.ops.material_structures.scratch_draw(stroke=on, stroke_space="WORLD") == {"FINISHED"}
    assert _set_of(a).n_scratches == n_before + 1


def test_draw_on_a_material_linked_from_another_file_says_make_it_local(scene, tmp_path):
    """A scratched metal linked (not appended) from another file is read-only here, as Blender keeps linked data:
    a stroke drawn on it was kept in memory only and lost on save. Draw Scratches is unavailable on it and says why
    in one line; the linked set is unchanged."""
    a = _plane(scene, "A")
    assert bpy.ops.material_structures.scratch_generate(count=20, seed=1) == {"FINISHED"}
    mat = a.active_material
    name = mat.name
    lib = str(tmp_path / "metals.blend")
    bpy.data.libraries.write(lib, {mat}, fake_user=True)
    a.data.materials.clear()
    bpy.data.materials.remove(mat)
    with bpy.data.libraries.load(lib, link=True) as (_, dst):
        dst.materials = [name]
    a.data.materials.append(dst.materials[0])
    before = _digest(_set_of(a))
    stroke = [{"name": "", "location": (0, 0, 0), "uv": (0.1 + 0.1 * i, 0.5), "pressure": 1.0} for i in range(5)]
    with pytest.raises(RuntimeError, match="linked from another file: make it local"):
        bpy.ops.material_structures.scratch_draw(stroke=stroke)
    assert _digest(_set_of(a)) == before
    # as the message says: Make Local (the material; its node group, which holds the set, stays linked until the
    # first edit gives the material its own copy), then the stroke is kept through save and reopen
    for o in bpy.context.view_layer.objects:
        o.select_set(o == a)
    assert bpy.ops.object.make_local(type="SELECT_OBDATA_MATERIAL") == {"FINISHED"}
    assert bpy.ops.material_structures.scratch_draw(stroke=stroke) == {"FINISHED"}
    n = _set_of(a).n_scratches
    path = str(tmp_path / "local.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    assert _set_of(bpy.data.objects["A"]).n_scratches == n == 21


def test_a_scratch_cache_that_cannot_be_written_is_one_line_and_changes_nothing(scene, tmp_path, monkeypatch):
    """A full or read-only temporary folder (here a file where the cache folder goes): Generate raised
    NotADirectoryError as a traceback, with the new set stored in the file while the shader kept reading the old
    tables (a new material left four packed images behind). Now one line, nothing changed."""
    import importlib
    import shutil
    import tempfile

    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    cache_root = importlib.import_module("material_structures.addon.scratch.tables").cache_root
    open(cache_root(), "w").close()
    obj = _plane(scene, "A")
    before = (len(bpy.data.images), len(bpy.data.node_groups), len(bpy.data.materials))
    with pytest.raises(RuntimeError, match="cannot write the scratch tables to .*point TMPDIR") as info:
        bpy.ops.material_structures.scratch_generate(count=50)
    assert "Traceback" not in str(info.value)
    assert (len(bpy.data.images), len(bpy.data.node_groups), len(bpy.data.materials)) == before
    assert not obj.material_slots or obj.active_material is None
    os.remove(cache_root())
    assert bpy.ops.material_structures.scratch_generate(count=50, seed=1) == {"FINISHED"}
    mat = obj.active_material
    before = _digest(_set_of(obj))
    shutil.rmtree(cache_root())
    open(cache_root(), "w").close()  # the temporary folder full again
    with pytest.raises(RuntimeError, match="cannot write the scratch tables"):
        bpy.ops.material_structures.scratch_generate(count=50, seed=2)
    assert obj.active_material == mat and _digest(_set_of(obj)) == before  # the old set, as stored


def test_scratch_caches_unused_for_two_weeks_are_removed_and_tables_go_with_their_set(scene, tmp_path, monkeypatch):
    """Every scratch set ever rendered left a cache folder (78 MB for 10 000 scratches) for good, and its table
    images stayed in the file with fake users after the material was deleted, through a purge. Folders unused for
    two weeks are now removed; the images go with their set."""
    import importlib
    import tempfile
    import time

    from material_structures.addon.common import CACHE_UNUSED_S

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    cache_root = importlib.import_module("material_structures.addon.scratch.tables").cache_root
    old = os.path.join(cache_root(), "0123456789abcdef")
    os.makedirs(old)
    past = time.time() - CACHE_UNUSED_S - 60
    os.utime(old, (past, past))
    obj = _plane(scene, "A")
    assert bpy.ops.material_structures.scratch_generate(count=50) == {"FINISHED"}
    assert not os.path.exists(old) and len(os.listdir(cache_root())) == 1
    # a folder in use (an open file's, rendered) is marked so, though nothing is extracted (before: pruned under
    # the open file two weeks after its extraction)
    (folder,) = [os.path.join(cache_root(), n) for n in os.listdir(cache_root())]
    os.utime(folder, (past, past))
    importlib.import_module("material_structures.addon.scratch.material").ensure_tables_extracted()
    assert time.time() - os.stat(folder).st_mtime < 60
    assert not any(i.use_fake_user for i in bpy.data.images if i.name.startswith("MS Scratch"))
    obj.data.materials.clear()  # the scratched material taken off
    bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=False, do_recursive=True)  # File > Clean Up > Purge
    assert [i.name for i in bpy.data.images if i.name.startswith("MS Scratch")] == []
