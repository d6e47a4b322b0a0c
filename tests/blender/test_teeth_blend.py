"""Teeth: the enamel/dentin sigmoid blend of the fit's model (eq. 5.15) in Cycles, through each tooth's Blend
Volume (addon/teeth/blend_volume.py), made by Add Tooth, From Mesh, Import Teeth Scene and Apply Fit Result,
with the dentin shape keys live."""

from __future__ import annotations

import os

import bpy
import numpy as np
import pytest


def _blend_setup(enamel):
    from material_structures.addon.teeth.blend_volume import BLEND_INPUT, blend_object
    from material_structures.addon.teeth.materials import group_node

    obj = blend_object(enamel)
    assert obj is not None, f"{enamel.name} has no Blend Volume"
    dentin = enamel.ms_tooth.partner
    flags = [group_node(o.active_material).inputs[BLEND_INPUT].default_value for o in (enamel, dentin)]
    return obj, flags


def _evaluated_grids(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    dg.update()
    for inst in dg.object_instances:
        if inst.object.type == "VOLUME" and inst.object.original.name == obj.name:
            return sorted(g.name for g in inst.object.data.grids), np.array(inst.object.bound_box)
    return [], None


def _scene_file(tmp_path, spread):
    from material_structures.core.teeth.scene import save_scene
    from material_structures.core.teeth.synthetic import make_scene

    ts = make_scene(n_teeth=1, resolution=16)
    ts.blend_spread = spread
    path = os.path.join(str(tmp_path), "scene.json")
    save_scene(ts, path)
    return ts, path


def test_every_way_of_making_a_tooth_gives_it_a_blend_volume(addon_module, tmp_path):
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.material_structures.teeth_add_tooth(source="TEMPLATE", kind="INCISOR", resolution=16) == {"FINISHED"}
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.004, location=(0.02, 0, 0))
    assert bpy.ops.material_structures.teeth_add_tooth(source="MESH") == {"FINISHED"}
    _, path = _scene_file(tmp_path, 0.34)
    assert bpy.ops.material_structures.teeth_import_scene(filepath=path) == {"FINISHED"}
    teeth = [o for o in bpy.context.scene.objects if o.ms_tooth.role == "ENAMEL"]
    assert len(teeth) == 3
    for enamel in teeth:
        obj, flags = _blend_setup(enamel)
        assert flags == [1.0, 1.0]  # the materials give their volumes to the Blend Volume
        grids, _ = _evaluated_grids(obj)
        assert grids == ["ms_m", "ms_o", "ms_q"]


def test_apply_fit_result_drives_the_blend_and_shape_keys_move_it(addon_module, tmp_path):
    """Apply Fit Result writes the fit into the Enamel/Dentin materials; the Blend Volume's material follows by
    drivers (exact to float32), takes the file's spread, and its grids follow the dentin's shape keys."""
    from material_structures.addon.teeth.blend_volume import SPREAD, blend_object
    from material_structures.addon.teeth.materials import group_node
    from material_structures.core.teeth.scene import save_scene

    bpy.ops.wm.read_homefile(use_empty=True)
    ts, path = _scene_file(tmp_path, 0.34)
    assert bpy.ops.material_structures.teeth_import_scene(filepath=path) == {"FINISHED"}
    fit = ts.copy()
    t = fit.teeth[0]
    t.enamel.sigma_t = np.array([0.7, 0.8, 1.9])
    t.enamel.g1 = 0.31
    t.dentin.albedo = np.array([0.81, 0.72, 0.63])
    t.dentin.beta = 0.55
    t.c = np.array([0.0, 0.0, 0.6])
    fit.blend_spread = 0.5
    fit_path = os.path.join(str(tmp_path), "scene_fit.json")
    save_scene(fit, fit_path)
    assert bpy.ops.material_structures.teeth_apply_fit_file(filepath=fit_path) == {"FINISHED"}
    enamel = next(o for o in bpy.context.scene.objects if o.ms_tooth.role == "ENAMEL")
    obj = blend_object(enamel)
    _, box_fit = _evaluated_grids(obj)
    node = group_node(obj.active_material)
    assert tuple(node.inputs["Enamel Sigma_t"].default_value) == pytest.approx((0.7, 0.8, 1.9), abs=1e-6)
    assert node.inputs["Enamel G1"].default_value == pytest.approx(0.31, abs=1e-6)
    assert tuple(node.inputs["Dentin Albedo"].default_value)[:3] == pytest.approx((0.81, 0.72, 0.63), abs=1e-6)
    assert node.inputs["Dentin Beta"].default_value == pytest.approx(0.55, abs=1e-6)
    assert node.inputs[SPREAD].default_value == pytest.approx(0.5, abs=1e-6)
    # the dentin's shape keys are live: the grids (their bounds, in the tooth's mm) follow the occlusal slider
    # (c from 0.6 to -0.6 moves the dentin's occlusal end by about 1.2 mm; the bounds step by whole voxels)
    enamel.ms_tooth.set_coefficients((0.0, 0.0, -0.6))
    _, box_moved = _evaluated_grids(obj)
    assert np.abs(box_moved - box_fit).max() > 0.5


def test_blend_at_a_narrow_spread_renders_the_sharp_model(addon_module):
    """A spread of 0.02 mm (the Blend Volume on) renders the two-tooth check scene as the sharp meshes do: image
    means within 5 % per channel (32 x 20 px, 64 spp; measured -2.2 %, -2.2 %, -0.3 % at 32 spp on 5.2)."""
    from material_structures.addon.teeth import verify as V
    from material_structures.addon.teeth.blend_volume import blend_object
    from material_structures.render import render_to_array

    means = []
    for spread in (1e-6, 0.02):
        ts, cam, light = V.check_scene(2, 16, 32, 20)
        ts.blend_spread = spread
        scene = V.reset_scene()
        V.dark_world(scene)
        out = V.build_teeth_scene(ts, scene.collection, mm_per_unit=1.0)
        assert all(blend_object(e).hide_render == (spread < 0.01) for e, _ in out["teeth"])
        V.add_camera(scene, cam, mm_per_unit=1.0)
        V.add_point_light(scene, light, mm_per_unit=1.0)
        V.configure_teeth_cycles(scene, 64, 0, 64)
        means.append(render_to_array(scene)[:, :, :3].mean(axis=(0, 1)))
    assert means[1] == pytest.approx(means[0], rel=0.05)
