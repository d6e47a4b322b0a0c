"""Open Sample (``material_structures.use_sample``, issue 67): the shipped samples go into the panels at once, a
fit's output going to the extension's user folder, never into the installed extension."""

from __future__ import annotations

import os
import sys

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLES = os.path.realpath(os.path.join(ROOT, "samples"))


def _real(path: str) -> str:
    return os.path.realpath(bpy.path.abspath(path))


def test_sample_states_fill_the_data_driven_folder(addon_module):
    brushing = sys.modules[f"{addon_module}.addon.fabric.brushing"]
    assert bpy.ops.material_structures.use_sample(sample="STATES") == {"FINISHED"}
    folder = bpy.context.scene.material_structures.fabric_brush.states_dir
    assert _real(folder) == os.path.join(SAMPLES, "brush_states")
    assert len(brushing.load_brush_states(folder).states) == 8


def test_sample_capture_fills_the_fit_panel_and_imports_its_tooth(addon_module):
    scene = bpy.context.scene
    assert bpy.ops.material_structures.use_sample(sample="CAPTURE") == {"FINISHED"}
    fs = scene.ms_teeth_fit
    assert _real(fs.capture_dir) == os.path.join(SAMPLES, "teeth_capture")
    assert fs.tooth_map and all(m.enamel is not None for m in fs.tooth_map)
    assert not _real(fs.out_dir).startswith(os.path.realpath(ROOT)), fs.out_dir
    n = len(scene.objects)
    assert bpy.ops.material_structures.use_sample(sample="CAPTURE") == {"FINISHED"}
    assert len(scene.objects) == n  # its tooth is there already: not imported twice


def test_fit_sample_btf_gives_the_active_mesh_a_fabric_material(addon_module):
    fit_job = sys.modules[f"{addon_module}.addon.fabric.fit_job"]
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    obj = bpy.context.active_object
    assert bpy.ops.material_structures.use_sample(sample="BTF") == {"FINISHED"}
    mat = obj.active_material
    assert mat is not None and mat.get("material_structures_fabric") and mat.name.startswith("Fabric fabric_btf_fit")
    job = fit_job.current_job()
    assert job.state() == "FINISHED"
    assert not os.path.realpath(job.out_dir).startswith(os.path.realpath(ROOT)), job.out_dir
    assert os.path.isfile(os.path.join(job.out_dir, "params.json"))
