"""``make test-bare``: the built extension zip in a Python that holds only the ``bpy`` wheel (what a desktop
Blender's Python has), every operator of every panel used as a user would, then the saved file reopened in a
fresh process.

    .venv-bare/bin/python tests/bare/bare_blender.py ZIP WORK

The inputs a user brings are the samples shipped in the zip (``samples/``: a BTF, a teeth capture, the brush's
Data-Driven states), put into the panels by the Open Sample operator (``use_sample``) as a new user following
docs/getting-started.md would. ``WORK``: a scratch folder. The
first process installs the zip through ``extensions.package_install_files`` (its wheels with it), runs the
operators (fabric, scratches, teeth, the asset library, a small render of each), saves WORK/bare.blend and
what it expects to find there (WORK/expect.json); the second reopens the file and checks maps, scratch sets,
shape keys and fitted values. Prints the operators it ran and the time of each part.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

REPO = "bare"
ADDON = f"bl_ext.{REPO}.material_structures"
HEAVY = ("scipy", "numba", "llvmlite")  # bundled wheels: imported by the features that need them, never at enable

RAN: list[str] = []
TIMES: dict[str, float] = {}


def log(msg: str) -> None:
    print(f"[bare] {msg}", flush=True)


def start_blender(work: str):
    os.environ["BLENDER_USER_RESOURCES"] = os.path.join(work, "user")
    os.makedirs(os.environ["BLENDER_USER_RESOURCES"], exist_ok=True)
    import bpy

    return bpy


def add_repo(bpy, work: str):
    repo_dir = os.path.join(work, "extensions")
    os.makedirs(repo_dir, exist_ok=True)
    repos = bpy.context.preferences.extensions.repos
    if not any(r.module == REPO for r in repos):
        repos.new(name=REPO, module=REPO, custom_directory=repo_dir, source="USER")
    return repo_dir


def op(name: str, **kw) -> None:
    import bpy

    res = getattr(bpy.ops.material_structures, name)(**kw)
    assert res == {"FINISHED"}, f"{name}: {res}"
    if name not in RAN:
        RAN.append(name)


def op_in_node_editor(bpy, idname: str, material) -> None:
    """A node-editor operator (Add > Material Structures > ...) on ``material``'s tree: no editor exists
    without a window, so its execute() gets the editor's context (its edited tree and ID)."""
    from types import SimpleNamespace

    cls = bpy.types.Operator.bl_rna_get_subclass_py("MATERIAL_STRUCTURES_OT_" + idname.split(".", 1)[1])
    assert cls is not None, idname
    space = SimpleNamespace(type="NODE_EDITOR", edit_tree=material.node_tree, id=material)
    ctx = SimpleNamespace(space_data=space, scene=bpy.context.scene)
    assert cls.poll(ctx)
    fake = SimpleNamespace(bl_label=cls.bl_label, marker=cls.marker, marker_value=cls.marker_value)
    fake.group = lambda c: cls.group(fake, c)
    n = len(material.node_tree.nodes)
    assert cls.execute(fake, ctx) == {"FINISHED"}
    assert len(material.node_tree.nodes) == n + 1
    RAN.append(idname.split(".", 1)[1])


def mod(path: str):
    return sys.modules[f"{ADDON}.{path}"]


def plane(bpy, name: str, x: float):
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(x, 0.0, 0.0))
    obj = bpy.context.active_object
    obj.name = name
    return obj


def activate(bpy, obj) -> None:
    for o in bpy.context.selected_objects:
        o.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj


def image_sum(img) -> float:
    import numpy as np

    a = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(a)
    return float(a.astype(np.float64).sum())


def fabric_map_sums(bpy, mat) -> dict[str, float]:
    images = mod("addon.fabric.material").material_map_images(mat)
    return {k: image_sum(img) for k, img in sorted(images.items())}


def stroke(y: float = 0.5, n: int = 6) -> list[dict]:
    return [{"name": "", "location": (0, 0, 0), "uv": (0.15 + 0.7 * i / (n - 1), y), "pressure": 1.0}
            for i in range(n)]


def render_only(bpy, objs, path: str) -> float:
    """A 32 x 32 Cycles render of ``objs`` alone (4 samples, seen from above); returns the mean of its pixels
    (finite, > 0)."""
    import numpy as np
    from mathutils import Vector

    scene = bpy.context.scene
    corners = [o.matrix_world @ Vector(c) for o in objs for c in o.bound_box]
    lo = Vector([min(c[i] for c in corners) for i in range(3)])
    hi = Vector([max(c[i] for c in corners) for i in range(3)])
    size = max(hi - lo)
    cam = scene.camera  # orthographic, looking down at the objects
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 1.3 * size
    cam.data.clip_start, cam.data.clip_end = 1e-3 * size, 10.0 * size
    cam.location = (lo + hi) / 2 + Vector((0.0, 0.0, 3.0 * size))
    cam.rotation_euler = (0.0, 0.0, 0.0)
    keep = {o.name for o in objs} | {"Bare Camera", "Bare Light"}
    for o in scene.objects:
        o.hide_render = o.name not in keep
    r = scene.render
    r.resolution_x = r.resolution_y = 32
    r.resolution_percentage = 100
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    r.image_settings.file_format = "OPEN_EXR"
    r.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    a = np.empty(len(img.pixels), dtype=np.float32)
    img.pixels.foreach_get(a)
    bpy.data.images.remove(img)
    rgb = a.reshape(-1, 4)[:, :3]
    assert np.isfinite(rgb).all(), path
    assert rgb.mean() > 0, path
    for o in scene.objects:
        o.hide_render = False
    return float(rgb.mean())


# -- the first process: install, use every panel, save -------------------------------------------------
def use(zip_path: str, work: str) -> None:
    t0 = time.perf_counter()
    bpy = start_blender(work)
    import addon_utils

    add_repo(bpy, work)
    res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo=REPO, enable_on_install=True)
    assert res == {"FINISHED"}, res
    assert addon_utils.check(ADDON)[1], f"{ADDON} is not enabled"
    heavy = [m for m in HEAVY if m in sys.modules]
    assert not heavy, f"enabling the extension imported {heavy}: import them where a feature needs them"
    TIMES["install + enable"] = time.perf_counter() - t0
    expect: dict = {}

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    op("setup_cycles_osl")
    bpy.ops.object.camera_add(location=(0.0, 0.0, 3.0))
    cam = bpy.context.active_object
    cam.name = "Bare Camera"
    scene.camera = cam
    bpy.ops.object.light_add(type="SUN", location=(0.5, -0.5, 2.0), rotation=(0.4, 0.2, 0.0))
    bpy.context.active_object.name = "Bare Light"
    bpy.context.active_object.data.energy = 3.0

    # -- fabric -----------------------------------------------------------------------------------------
    t = time.perf_counter()
    fabric = {}
    for i, preset in enumerate(("VELVET", "CORDUROY", "PLUSH")):
        obj = plane(bpy, f"Fabric {preset}", 1.2 * i)
        op("fabric_new_material", preset=preset)
        fabric[preset] = obj
    velvet = fabric["VELVET"]
    activate(bpy, velvet)
    brush = scene.material_structures.fabric_brush
    brush.radius, brush.strength = 0.08, 1.0
    op("use_sample", sample="STATES")  # the Data-Driven mode's Open Sample States
    samples = mod("addon.operators")
    assert os.path.isdir(os.path.join(brush.states_dir, "state_7")), brush.states_dir
    mat = velvet.active_material
    sums = fabric_map_sums(bpy, mat)
    for i, mode in enumerate(("COMB", "RECOLOR", "SMOOTH", "ANISOTROPY", "DATA_DRIVEN")):
        brush.mode = mode
        brush.recolor_diffuse = True
        before = sums
        op("fabric_brush", stroke=stroke(0.2 + 0.15 * i))
        sums = fabric_map_sums(bpy, mat)
        assert sums != before, f"the {mode} stroke changed no map"
    before_last = before
    mat_name = mat.name
    assert bpy.ops.ed.undo() == {"FINISHED"}  # each stroke is one step of Blender's undo
    mat = bpy.data.materials[mat_name]  # the undo replaced every datablock: look them up again
    scene = bpy.context.scene
    fabric = {preset: bpy.data.objects[f"Fabric {preset}"] for preset in fabric}
    assert fabric_map_sums(bpy, mat) == before_last, "Ctrl+Z did not take the last stroke back"
    op("fabric_brush", stroke=stroke(0.8))  # one more stroke: the saved file keeps it
    expect["fabric_maps"] = {mat.name: fabric_map_sums(bpy, mat)}
    saved = os.path.join(work, "saved_maps")
    op("fabric_save_maps", directory=saved)
    assert os.path.isfile(os.path.join(saved, "params.json"))
    imported = plane(bpy, "Fabric Imported", 3.6)
    op("fabric_import_maps", directory=saved)
    assert imported.active_material is not None and imported.active_material.get("material_structures_fabric")
    op("fabric_sync_lamps")
    op_in_node_editor(bpy, "material_structures.fabric_add_group_node", fabric["CORDUROY"].active_material)
    TIMES["fabric"] = time.perf_counter() - t

    t = time.perf_counter()
    sample_btf = samples.sample_path("BTF")
    fitted = plane(bpy, "Fabric Fitted", 4.8)
    op("use_sample", sample="BTF")  # the Fabric panel's Fit Sample: Fit BTF on the shipped sample BTF
    fmat = fitted.active_material
    assert fmat is not None and fmat.get("material_structures_fabric") and \
        fmat.name.startswith("Fabric fabric_btf_fit"), fmat
    fj = mod("addon.fabric.fit_job")
    job = fj.current_job()
    assert job.done_iterations == job.iterations > 0 and job.state() == "FINISHED", job.status_text()
    assert job.out_dir.startswith(work) and not job.out_dir.startswith(os.path.dirname(sample_btf)), job.out_dir
    expect["fabric_maps"][fmat.name] = fabric_map_sums(bpy, fmat)
    picked = plane(bpy, "Fabric Picked", 6.0)  # Fit BTF with the folder picked in the file browser
    op("fabric_fit_btf", directory=sample_btf, out_dir=os.path.join(work, "btf_fit"))
    assert picked.active_material is not None and picked.active_material.name.startswith("Fabric btf_fit")
    expect["fabric_maps"][picked.active_material.name] = fabric_map_sums(bpy, picked.active_material)
    job = fj.FabricFitJob(sample_btf, os.path.join(work, "btf_fit_cancelled"), workers=1).start()
    fj.set_current_job(job)
    # at once: the 16 x 16 BTF's fit ends within a second (its closures come from the table), and a cancel
    # after the end is "No fabric fit is running"
    op("fabric_fit_cancel")
    assert job.poll() == "CANCELLED", job.poll()
    TIMES["fabric fits (16 x 16 sample BTF, twice) + cancel"] = time.perf_counter() - t

    # -- scratches ----------------------------------------------------------------------------------------
    t = time.perf_counter()
    metal = plane(bpy, "Scratched", 0.0)
    metal.location.y = 1.2
    editing = mod("addon.scratch.editing")
    counts = []
    for i, pattern in enumerate(("WEAR", "POLISH", "HAIRLINE")):  # the second and third add to the set
        op("scratch_generate", pattern=pattern, count=100, seed=i, replace=i == 0)
        counts.append(editing.material_set(editing.object_scratch_material(metal))[1].n_scratches)
    assert counts[0] > 0 and counts[0] < counts[1] < counts[2], counts  # (a generator drops what misses the patch)
    n_generated = counts[-1]
    op("scratch_draw", stroke=stroke(0.5))
    s = editing.material_set(editing.object_scratch_material(metal))[1]
    assert s.n_scratches == n_generated + 1, s.n_scratches
    npz, tables = os.path.join(work, "scratches.npz"), os.path.join(work, "scratch_tables")
    op("scratch_export", filepath=npz)
    op("scratch_export", filepath=tables)
    for i, path in enumerate((npz, tables)):
        o = plane(bpy, f"Scratch Import {i}", 1.2 + 1.2 * i)
        o.location.y = 1.2
        op("scratch_import", filepath=path)
        assert editing.material_set(editing.object_scratch_material(o))[1].n_scratches == s.n_scratches
    op("scratch_sync_lamps")
    expect["scratch_sets"] = {
        o.name: editing.material_set(editing.object_scratch_material(o))[1].n_scratches
        for o in scene.objects if editing.object_scratch_material(o) is not None}
    TIMES["scratches"] = time.perf_counter() - t

    # -- teeth --------------------------------------------------------------------------------------------
    t = time.perf_counter()
    teeth = []
    for i, kind in enumerate(("INCISOR", "CANINE", "PREMOLAR", "MOLAR")):
        scene.cursor.location = (1.2 * i, 2.4, 0.0)
        op("teeth_add_tooth", source="TEMPLATE", kind=kind, resolution=16)
        teeth.append(bpy.context.active_object)
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.004, location=(4.8, 2.4, 0.0))
    op("teeth_add_tooth", source="MESH")
    teeth.append(bpy.context.active_object)
    inc = teeth[0]
    activate(bpy, inc)
    inc.ms_tooth.buccal, inc.ms_tooth.proximal, inc.ms_tooth.occlusal = 0.3, -0.2, 0.1  # the sliders
    activate(bpy, teeth[1])
    op("teeth_set_dentin", coefficients=(0.1, 0.2, -0.3))
    for kind in ("enamel", "dentin", "gingiva"):
        op_in_node_editor(bpy, f"material_structures.teeth_add_{kind}_node", inc.active_material)
    # the Teeth panel's Open Sample: the sample capture's folder, an output folder, its tooth imported (no tooth
    # of this scene has its name)
    n_objects = len(scene.objects)
    op("use_sample", sample="CAPTURE")
    fs = scene.ms_teeth_fit
    capture = samples.sample_path("CAPTURE")
    assert fs.capture_dir == capture and len(scene.objects) > n_objects, (fs.capture_dir, capture)
    assert fs.out_dir.startswith(work), fs.out_dir
    op("teeth_map_by_position")  # the sample's one tooth to a tooth of this scene; reading again keeps that choice
    assert fs.tooth_map[0].enamel is not None, "Map by Position mapped no tooth"
    op("teeth_read_capture_teeth")
    target = fs.tooth_map[0].enamel
    assert target is not None, "Read Capture Teeth mapped no tooth"
    fs.iterations = 2
    TIMES["teeth editing"] = time.perf_counter() - t
    t = time.perf_counter()
    op("teeth_fit")  # the panel's defaults but 2 iterations; blocks without a window
    tf = mod("addon.teeth.fit_job")
    job = tf.current_job()
    assert job.state() == "FINISHED" and job.done_iterations == 2, job.ended_text()
    assert target.ms_tooth.has_fit and "done" in fs.last_result, fs.last_result
    TIMES["teeth fit (2 iterations)"] = time.perf_counter() - t
    activate(bpy, target)
    op("teeth_apply_fitted")
    assert tuple(round(x, 6) for x in target.ms_tooth.coefficients()) == tuple(
        round(x, 6) for x in target.ms_tooth.fitted)
    op("teeth_apply_fit_file", filepath=job.result_path)
    op("teeth_import_scene", filepath=job.result_path)  # the fitted scene beside the others
    scene.cycles.volume_bounces = 0  # Blender's default: the panel's Set Light Paths raises it again
    op("teeth_light_paths")
    assert scene.cycles.volume_bounces == 256, scene.cycles.volume_bounces
    t = time.perf_counter()
    job = tf.FitJob(capture, os.path.join(work, "teeth_fit_cancelled"), iterations=1000, init="scene").start()
    tf.set_current_job(job)
    deadline = time.time() + 120
    while job.done_iterations < 1 and job.is_alive() and time.time() < deadline:
        time.sleep(0.2)
    assert job.is_alive(), job.last_line
    op("teeth_fit_cancel")
    assert job.poll() == "CANCELLED"
    TIMES["teeth fit cancelled"] = time.perf_counter() - t
    expect["teeth"] = {
        o.name: {"c": list(o.ms_tooth.coefficients()), "fitted": list(o.ms_tooth.fitted), "has_fit": o.ms_tooth.has_fit,
                 "keys": {k.name: k.value for k in (o.data.shape_keys.key_blocks if o.data.shape_keys else [])}}
        for o in scene.objects if o.ms_tooth.role == "ENAMEL"}
    expect["teeth_materials"] = {
        m.name: {f"{n.name}.{s.identifier}": float(s.default_value) for n in m.node_tree.nodes if n.type == "GROUP"
                 for s in n.inputs if s.type == "VALUE"}
        for m in bpy.data.materials if m.node_tree is not None and m.get("material_structures_teeth")}
    assert any(e["has_fit"] for e in expect["teeth"].values())

    # -- asset library, renders ---------------------------------------------------------------------------
    op("register_asset_library")
    assert mod("addon.operators").library_registered(bpy.context.preferences)
    t = time.perf_counter()
    renders = {"fabric": [fabric["VELVET"], fitted], "scratches": [metal], "teeth": [target]}
    for name, objs in renders.items():
        partners = [o.ms_tooth.partner for o in objs if o.ms_tooth.partner is not None]
        # a tooth's Blend Volume (its medium with the blended enamel/dentin boundary) renders with it
        blends = [o for o in bpy.context.scene.objects if getattr(o, "ms_tooth", None) is not None
                  and o.ms_tooth.role == "BLEND" and o.ms_tooth.partner in objs + partners]
        mean = render_only(bpy, objs + partners + blends, os.path.join(work, f"render_{name}.exr"))
        log(f"render {name}: mean {mean:.4g}")
    TIMES["renders (3 x 32 x 32, 4 spp)"] = time.perf_counter() - t

    blend = os.path.join(work, "bare.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    with open(os.path.join(work, "expect.json"), "w") as f:
        json.dump(expect, f)
    registered = sorted(c.bl_idname.split(".", 1)[1] for c in mod("addon").CLASSES
                        if issubclass(c, bpy.types.Operator))
    missing = [o for o in registered if o not in RAN]
    log(f"operators run ({len(RAN)} of {len(registered)} registered): {', '.join(RAN)}")
    assert not missing, f"operators not exercised: {missing}"
    for k, v in TIMES.items():
        log(f"time {k}: {v:.1f} s")


# -- the second process: reopen and check -------------------------------------------------------------
def reload(work: str) -> None:
    import numpy as np

    bpy = start_blender(work)
    import addon_utils

    add_repo(bpy, work)
    addon_utils.enable(ADDON, default_set=True)
    assert addon_utils.check(ADDON)[1]
    bpy.ops.wm.open_mainfile(filepath=os.path.join(work, "bare.blend"))
    with open(os.path.join(work, "expect.json")) as f:
        expect = json.load(f)
    for name, sums in expect["fabric_maps"].items():
        got = fabric_map_sums(bpy, bpy.data.materials[name])
        assert got.keys() == sums.keys(), (name, got.keys())
        for k in sums:
            assert abs(got[k] - sums[k]) <= 1e-6 * max(1.0, abs(sums[k])), (name, k, got[k], sums[k])
    editing = mod("addon.scratch.editing")
    for name, n in expect["scratch_sets"].items():
        found = editing.material_set(editing.object_scratch_material(bpy.data.objects[name]))
        assert found is not None and found[1].n_scratches == n, (name, n)
    for name, e in expect["teeth"].items():
        st = bpy.data.objects[name].ms_tooth
        np.testing.assert_allclose(st.coefficients(), e["c"], atol=1e-6)
        np.testing.assert_allclose(tuple(st.fitted), e["fitted"], atol=1e-6)
        assert st.has_fit == e["has_fit"], name
        keys = bpy.data.objects[name].data.shape_keys
        got = {k.name: k.value for k in (keys.key_blocks if keys else [])}
        assert got.keys() == e["keys"].keys() and all(abs(got[k] - v) < 1e-6 for k, v in e["keys"].items()), name
    for name, vals in expect["teeth_materials"].items():
        m = bpy.data.materials[name]
        got = {f"{n.name}.{s.identifier}": float(s.default_value) for n in m.node_tree.nodes if n.type == "GROUP"
               for s in n.inputs if s.type == "VALUE"}
        assert got == vals, name
    log(f"reloaded: {len(expect['fabric_maps'])} fabric materials' maps, {len(expect['scratch_sets'])} scratch "
        f"sets, {len(expect['teeth'])} teeth (shape keys, fitted values) and {len(expect['teeth_materials'])} "
        "teeth materials survived")


def main(argv: list[str]) -> int:
    if argv[:1] == ["--reload"]:
        reload(argv[1])
        return 0
    zip_path, work = (os.path.abspath(a) for a in argv[:2])
    import shutil

    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    # the Blender processes' temporary files (their user folders, the .oso files Blender's OSL script nodes
    # compile and never delete) stay in the work folder, not the machine's /tmp
    os.makedirs(os.path.join(work, "tmp"))
    os.environ["TMPDIR"] = os.path.join(work, "tmp")
    t0 = time.perf_counter()
    # a process per part: bpy imports once per process, and the reopened file must not see this one's state
    r = subprocess.run([sys.executable, __file__, "--use", zip_path, work])
    if r.returncode != 0:
        return r.returncode
    r = subprocess.run([sys.executable, __file__, "--reload", work])
    if r.returncode != 0:
        return r.returncode
    log(f"test-bare passed in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--use"]:
        use(*sys.argv[2:4])
        sys.exit(0)
    sys.exit(main(sys.argv[1:]))
