"""Fit BTF from the fabric panel: the fit runs in a background process (JSON progress per tile), its maps
become a new fabric material on the active mesh; cancel stops it; a folder without a BTF is one line."""

from __future__ import annotations

import os
import sys

import bpy
import pytest

from material_structures.cli import main


@pytest.fixture(scope="module")
def btf_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("btf") / "velvet"
    assert main(["fabric", "synth", "--out", str(d), "--width", "16", "--height", "16", "--lights", "8",
                 "--views", "8"]) == 0
    return str(d)


def _plane():
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    return bpy.context.active_object


def test_fit_btf_makes_a_fabric_material(addon_module, btf_dir, tmp_path):
    fit_job = sys.modules[f"{addon_module}.addon.fabric.fit_job"]  # the enabled add-on's (its current job)
    obj = _plane()
    out = str(tmp_path / "fit")
    assert bpy.ops.material_structures.fabric_fit_btf(directory=btf_dir, out_dir=out) == {"FINISHED"}
    mat = obj.active_material
    assert mat is not None and mat.get("material_structures_fabric") and mat.name == "Fabric fit"
    job = fit_job.current_job()
    assert job.state() == "FINISHED" and job.done_iterations == job.iterations == 1  # 16 x 16 texels: one tile
    assert os.path.isfile(os.path.join(out, "params.json")) and os.path.isfile(job.log_path)
    assert "tile 1/1" in job.status_text()


def test_fit_btf_default_output_is_beside_the_btf(addon_module, btf_dir):
    from material_structures.addon.fabric import fit_job

    assert fit_job.default_out_dir(btf_dir + os.sep) == btf_dir + "_fit"
    assert fit_job.fit_command(btf_dir, "/o", workers=3)[-4:] == ["/o", "--no-dask", "--workers", "3"]


def test_fit_btf_cancel_and_errors(addon_module, btf_dir, tmp_path):
    fit_job = sys.modules[f"{addon_module}.addon.fabric.fit_job"]
    _plane()
    with pytest.raises(RuntimeError, match="no btf.json"):
        bpy.ops.material_structures.fabric_fit_btf(directory=str(tmp_path))
    # a BTF that is not one, an output over the input: refused before the output folder and its log are made
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "btf.json").write_text("{")
    with pytest.raises(RuntimeError, match="not valid JSON"):
        bpy.ops.material_structures.fabric_fit_btf(directory=str(bad), out_dir=str(tmp_path / "bad_fit"))
    assert not (tmp_path / "bad_fit").exists()
    before = sorted(os.listdir(btf_dir))
    with pytest.raises(RuntimeError, match="Output Folder .* would write over the BTF folder"):
        bpy.ops.material_structures.fabric_fit_btf(directory=btf_dir, out_dir=btf_dir)
    assert sorted(os.listdir(btf_dir)) == before  # no fit_log.txt in the BTF
    assert bpy.ops.material_structures.fabric_fit_cancel() == {"CANCELLED"}  # a warning: nothing runs
    job = fit_job.FabricFitJob(btf_dir, str(tmp_path / "cancelled"), workers=1).start()
    fit_job.set_current_job(job)
    # at once: the small BTF's fit ends within a second (its closures come from the table), while its
    # process takes longer than this to start
    assert job.is_alive(), job.last_line
    assert not bpy.ops.material_structures.fabric_fit_btf.poll()  # one fit at a time
    assert bpy.ops.material_structures.fabric_fit_cancel() == {"FINISHED"}
    assert job.poll() == "CANCELLED"
    assert "cancelled" in job.ended_text()


def test_background_process_sees_blender_site_packages(addon_module):
    """The fits' process gets this process's paths (the extension's wheels) and Blender's own site-packages
    (OpenImageIO reads the EXRs where the OpenEXR package is missing)."""
    bj = sys.modules[f"{addon_module}.addon.background_job"]
    paths = bj.child_path()
    assert paths[0] == bj.package_parent()
    assert any(os.path.isdir(os.path.join(p, "OpenImageIO")) for p in paths), paths
    assert bj.progress_event('{"progress": "fit", "iteration": 3}') == {"progress": "fit", "iteration": 3}
    assert bj.progress_event('{"loss": 1}') is None and bj.progress_event("fit tiles: 50%") is None


def test_fit_btf_from_the_file_browser_ends_in_a_timer(addon_module, btf_dir, tmp_path):
    """In a desktop Blender the operator returns at once; a timer redraws the panel while the fit runs and
    makes the material when it ends (here the timer's function is called as Blender would)."""
    ops = sys.modules[f"{addon_module}.addon.fabric.operators"]
    fit_job = sys.modules[f"{addon_module}.addon.fabric.fit_job"]
    obj = _plane()
    job = fit_job.FabricFitJob(btf_dir, str(tmp_path / "fit"), workers=1).start()
    tick = ops._watch(job, bpy.context.scene.name, obj.name)
    assert tick() == 0.5  # running: call again in half a second
    job.wait()
    assert tick() is None and job.settled and job.outcome.startswith("done: Fabric fit")
    assert obj.active_material is not None and obj.active_material.get("material_structures_fabric")


def test_a_fit_that_has_not_reported_its_tiles_says_starting(addon_module, btf_dir, tmp_path):
    """Issue 63, item 9: the panel first showed "tile 0/1" (a count nobody reported); until the fit says how
    many tiles it has, the status says it is starting, then counts the reported tiles."""
    from material_structures.addon.fabric import fit_job

    job = fit_job.FabricFitJob(btf_dir, str(tmp_path / "fit"), workers=1)  # not started
    assert job.status_text().startswith("Fabric fit: starting") and "0/1" not in job.status_text()
    job.on_event({"progress": "fit", "iteration": 0, "iterations": 4})
    assert "tile 0/4" in job.status_text()
