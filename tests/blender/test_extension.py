"""The extension's structure: manifest, zip build and install, registration."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import bpy
import pytest

from material_structures.cli.build import build, validate

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_manifest_validates():
    validate(ROOT)  # raises with the validator's message when invalid


def test_built_zip_installs_and_enables(tmp_path):
    """Build the zip, install it into a fresh user extension repo in a new interpreter, enable it."""
    zip_path = build(str(tmp_path / "dist"))
    assert os.path.basename(zip_path).startswith("material_structures-")
    script = textwrap.dedent(
        f"""
        import os, sys, tempfile
        os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp()
        import bpy, addon_utils
        repo_dir = tempfile.mkdtemp()
        repo = bpy.context.preferences.extensions.repos.new(
            name="ziptest", module="ziptest", custom_directory=repo_dir, source="USER")
        res = bpy.ops.extensions.package_install_files(
            filepath={zip_path!r}, repo=repo.module, enable_on_install=True)
        assert res == {{"FINISHED"}}, res
        name = "bl_ext.ziptest.material_structures"
        assert name in sys.modules, sorted(m for m in sys.modules if m.startswith("bl_ext"))
        assert addon_utils.check(name)[1], "not loaded"
        assert os.path.isfile(os.path.join(repo_dir, "material_structures", "blender_manifest.toml"))
        assert hasattr(bpy.types, "VIEW3D_PT_material_structures")
        assert "setup_cycles_osl" in dir(bpy.ops.material_structures)
        print("ZIP-INSTALL-OK")
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert "ZIP-INSTALL-OK" in proc.stdout, proc.stdout[-3000:] + proc.stderr[-3000:]


def _classes(module_name: str) -> list[type]:
    return list(sys.modules[f"{module_name}.addon"].CLASSES)


def test_register_unregister_twice(addon_module):
    root = sys.modules[addon_module]
    classes = _classes(addon_module)
    assert len(classes) >= 4
    assert all(cls.is_registered for cls in classes)
    for _ in range(2):
        root.unregister()
        assert not any(cls.is_registered for cls in classes)
        assert not hasattr(bpy.types.Scene, "material_structures")
        root.register()
        assert all(cls.is_registered for cls in classes)
        assert hasattr(bpy.types.Scene, "material_structures")


def test_enabling_with_a_file_open_does_what_opening_it_does(addon_module, tmp_path, monkeypatch):
    """An artist opens a file, then installs, enables or updates the extension: the file got none of the work that
    opening it does (here, on another machine: the scratch tables were not extracted, and a Rendered viewport
    showed the metal without its scratches until the first F12 render). Enabling now queues that work once, and
    records it as an undo step: Ctrl+Z of the next action keeps it."""
    import importlib
    import shutil
    import tempfile

    from material_structures.addon.scratch.material import create_scratched_metal, group_node, script_node
    from material_structures.addon.scratch.verify import test_scratch_set

    root = sys.modules[addon_module]
    handlers = importlib.import_module(f"{addon_module}.addon.handlers")
    tables = importlib.import_module(f"{addon_module}.addon.scratch.tables")
    bpy.ops.wm.read_homefile(use_empty=True)
    mat = create_scratched_metal("Plate", test_scratch_set(), "plate", scene=bpy.context.scene)
    bpy.ops.mesh.primitive_plane_add()
    bpy.context.active_object.data.materials.append(mat)
    shutil.rmtree(script_node(group_node(mat).node_tree).inputs["TableDir"].default_value)  # another machine's
    path = str(tmp_path / "scratched.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    other = tmp_path / "other-machine-tmp"
    other.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(other))
    root.unregister()
    try:
        bpy.ops.wm.open_mainfile(filepath=path)
    finally:
        root.register()
    bpy.ops.ed.undo_push(message="Opened")  # the step a desktop Blender records when it opens a file
    assert not os.path.isdir(tables.cache_root())
    # no timer without a window (none would run it, and one left registered hangs bpy 4.5's exit)
    assert bpy.app.background and not bpy.app.timers.is_registered(handlers.after_enable)
    handlers.after_enable()  # what the timer runs with a window, once Blender's event loop turns

    def table_folder():
        return script_node(group_node(bpy.data.materials["Plate"]).node_tree).inputs["TableDir"].default_value

    folder = table_folder()
    assert os.path.isfile(os.path.join(folder, "cell_params.exr")) and folder.startswith(tables.cache_root())
    bpy.data.objects["Plane"].location.x += 1.0
    bpy.ops.ed.undo_push(message="Move")
    bpy.ops.ed.undo()
    assert table_folder() == folder
    # Blender's start: the extension registers, then the startup file loads (its handlers run): the timer then
    # does nothing again
    ran = []
    monkeypatch.setattr(handlers, "HANDLERS", [(bpy.app.handlers.load_post, lambda: ran.append(1))])
    bpy.ops.wm.read_homefile(use_empty=True)
    handlers.after_enable()
    assert ran == []


def test_disabling_stops_running_fits_and_their_timers(addon_module, tmp_path, monkeypatch):
    """A fit running when the extension was disabled ran on (a core busy, its Cancel button gone) and its timer
    then built the fitted material with the extension off; at Blender's quit the fit ran on, orphaned, until its
    next output line. Disabling now stops both; quitting signals the fit."""
    import atexit
    import importlib
    import time

    root = sys.modules[addon_module]
    background_job = importlib.import_module(f"{addon_module}.addon.background_job")
    job = background_job.BackgroundJob([sys.executable, "-c", "import time; time.sleep(120)"], str(tmp_path)).start()
    background_job.set_current_job("test", job)
    ticks = []
    background_job.watch(lambda: ticks.append(1) or 0.5, first_interval=60.0)
    (tick,) = background_job._WATCHES
    t0 = time.perf_counter()
    root.unregister()
    try:
        assert not job.is_alive() and job.cancelled and time.perf_counter() - t0 < 12.0
        assert not bpy.app.timers.is_registered(tick) and ticks == []
    finally:
        at_exit = []
        monkeypatch.setattr(atexit, "register", at_exit.append)
        root.register()
        monkeypatch.undo()
        atexit.register(background_job.stop_at_exit)
        background_job.set_current_job("test", None)
    assert at_exit == [background_job.stop_at_exit]  # what Blender's quit runs
    job = background_job.BackgroundJob([sys.executable, "-c", "import time; time.sleep(120)"], str(tmp_path)).start()
    background_job.set_current_job("test", job)
    try:
        background_job.stop_at_exit()
        job.proc.wait(timeout=10)
        assert not job.is_alive()
    finally:
        job.cancel()
        background_job.set_current_job("test", None)


def test_operator_ids_are_namespaced(addon_module):
    ops = [c for c in _classes(addon_module) if issubclass(c, bpy.types.Operator)]
    assert ops
    assert all(c.bl_idname.startswith("material_structures.") for c in ops)


def test_setup_operator_enables_osl(addon_module):
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"
    assert bpy.ops.material_structures.setup_cycles_osl() == {"FINISHED"}
    assert scene.render.engine == "CYCLES"
    assert scene.cycles.shading_system is True
    assert scene.cycles.device == "CPU"


@pytest.mark.parametrize("field", ["id", "version", "blender_version_min", "license"])
def test_manifest_fields(field):
    import tomllib

    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        manifest = tomllib.load(f)
    expected = {
        "id": "material_structures",
        "blender_version_min": "4.5.0",
        "license": ["SPDX:GPL-3.0-or-later"],
    }
    if field == "version":
        import material_structures

        assert manifest["version"] == material_structures.__version__
    else:
        assert manifest[field] == expected[field]
