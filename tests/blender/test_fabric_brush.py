"""Brushing in Blender: a replayed stroke changes exactly what core brushing changes; Blender's undo (each stroke
is one step) restores."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from material_structures.core.fabric import brushing as core_brush

from ._fabric_maps import material_maps, stroke_kwargs, write_random_fabric_fit


@pytest.fixture(autouse=True)
def _small_fit_budget(monkeypatch, addon_module):
    """Random maps hold a distinct fibre geometry per texel: fit the closures on a coarse grid of them
    (in the enabled extension's modules, which the operators run)."""
    import importlib

    monkeypatch.setattr(importlib.import_module(f"{addon_module}.addon.fabric.material"), "FIT_KEY_BUDGET", 24)


def _closures(obj):
    from material_structures.addon.fabric.maps import images_to_closure_maps
    from material_structures.addon.fabric.material import material_closure_images

    return images_to_closure_maps(material_closure_images(obj.active_material))


def _setup(tmp_path, h=48, w=64, seed=3):
    from material_structures import render as R

    maps = write_random_fabric_fit(tmp_path / "fit", h, w, seed)
    scene = R.reset_scene()
    obj = R.add_textured_plane(scene, 2.0)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.material_structures.fabric_import_maps(directory=str(tmp_path / "fit")) == {"FINISHED"}
    from material_structures.addon.fabric.brushing import drop_sessions

    drop_sessions()
    bpy.ops.ed.undo_push(message="Set Up")
    return scene, obj, maps


def _undo(name="MS Plane"):
    """Ctrl+Z: the stroke's undo step is taken back; returns the object again (the undo replaced it)."""
    assert bpy.ops.ed.undo() == {"FINISHED"}
    return bpy.data.objects[name]


UVS = [(0.2, 0.3), (0.35, 0.4), (0.5, 0.45), (0.7, 0.4)]


def test_replayed_comb_stroke_matches_core_and_undo_restores(addon_module, tmp_path):
    scene, obj, maps = _setup(tmp_path)
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength, brush.fibre_length = "COMB", 0.06, 0.9, 1.5
    before = material_maps(obj)
    assert bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS)) == {"FINISHED"}
    after = material_maps(obj)

    h, w = maps.shape
    pts = np.array([(u * w, (1 - v) * h) for u, v in UVS])
    expected = core_brush.brush_stroke(before, pts, 0.06 * w, 0.9, 1.5)
    np.testing.assert_allclose(after.basis, expected.basis, atol=2e-6)
    changed = np.any(np.abs(after.basis - before.basis) > 0, axis=-1)
    reach = core_brush.stroke_weight_map((h, w), pts, 0.06 * w, 0.9) > 0
    assert changed.sum() > 50
    assert not np.any(changed & ~reach), "texels outside the stroke's capsules changed"
    for key in ("kd", "ks", "sigma"):
        np.testing.assert_array_equal(getattr(after, key), getattr(before, key))

    obj = _undo()
    np.testing.assert_array_equal(material_maps(obj).basis, before.basis)


def test_comb_stroke_refits_the_closures_of_its_texels_and_undo_restores_them(addon_module, tmp_path):
    from material_structures.core.fabric.closure_table import lookup_closure_texels

    scene, obj, _ = _setup(tmp_path)
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength, brush.fibre_length = "COMB", 0.06, 0.9, 1.5
    before, cm_before = material_maps(obj), _closures(obj)
    assert bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS)) == {"FINISHED"}
    after, cm_after = material_maps(obj), _closures(obj)
    changed = np.any(after.basis != before.basis, axis=-1)
    assert changed.sum() > 50
    # the stroke's texels hold the table's closures of their new geometry, the others are untouched
    wts, shp, scl = lookup_closure_texels(after.sigma[changed], after.basis[changed])
    np.testing.assert_allclose(cm_after.weights[changed], wts, atol=1e-6)
    np.testing.assert_allclose(cm_after.shape[changed], shp, atol=1e-6)
    np.testing.assert_allclose(cm_after.ggx_scale[changed], scl, atol=1e-6)
    np.testing.assert_array_equal(cm_after.weights[~changed], cm_before.weights[~changed])
    obj = _undo()
    cm_undone = _closures(obj)
    np.testing.assert_array_equal(cm_undone.weights, cm_before.weights)
    np.testing.assert_array_equal(cm_undone.shape, cm_before.shape)


def test_recolor_stroke_keeps_the_closures(addon_module, tmp_path):
    scene, obj, _ = _setup(tmp_path)
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.recolor_diffuse = "RECOLOR", 0.08, True
    cm_before = _closures(obj)
    assert bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS)) == {"FINISHED"}
    np.testing.assert_array_equal(_closures(obj).weights, cm_before.weights)


def test_world_space_stroke_equals_uv_stroke(addon_module, tmp_path):
    scene, obj, _ = _setup(tmp_path)
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength = "COMB", 0.05, 1.0
    before = material_maps(obj)
    world = [
        {"name": "", "uv": (0, 0), "location": (2 * u - 1, 2 * v - 1, 0.01), "pressure": 1.0} for u, v in UVS
    ]  # plane is 2 x 2
    assert bpy.ops.material_structures.fabric_brush(stroke=world, stroke_space="WORLD") == {"FINISHED"}
    via_world = material_maps(obj).basis.copy()
    obj = _undo()  # the brush settings were set after the last undo step: the undo took them back too
    np.testing.assert_array_equal(material_maps(obj).basis, before.basis)
    brush = bpy.context.scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength = "COMB", 0.05, 1.0
    bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS))
    np.testing.assert_allclose(material_maps(obj).basis, via_world, atol=1e-5)


def test_recolor_and_pressure(addon_module, tmp_path):
    scene, obj, _ = _setup(tmp_path)
    brush = scene.material_structures.fabric_brush
    brush.mode, brush.radius, brush.strength = "RECOLOR", 0.05, 1.0
    brush.recolor_diffuse, brush.recolor_specular = True, False
    brush.kd = (0.9, 0.1, 0.1)
    before = material_maps(obj)
    bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS, pressure=0.5))
    after = material_maps(obj)
    h, w = before.shape
    pts = np.array([(u * w, (1 - v) * h) for u, v in UVS])
    # one segment at a time, each with strength 0.5 (pressure) — the core recolor of each capsule
    expected = before
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        expected = core_brush.brush_edit(expected, a, b, 0.05 * w, 0.5, kd=(0.9, 0.1, 0.1))
    np.testing.assert_allclose(after.kd, expected.kd, atol=2e-6)
    np.testing.assert_array_equal(after.ks, before.ks)


def test_clear_errors(addon_module, tmp_path):
    scene, obj, _ = _setup(tmp_path)
    scene.material_structures.fabric_brush.mode = "DATA_DRIVEN"
    with pytest.raises(RuntimeError, match="brushing states"):
        bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS))
    scene.material_structures.fabric_brush.states_dir = str(tmp_path / "nowhere")
    with pytest.raises(RuntimeError, match="state_0"):
        bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS))
    scene.material_structures.fabric_brush.mode = "COMB"
    with pytest.raises(RuntimeError, match="at least 2 points"):
        bpy.ops.material_structures.fabric_brush(**stroke_kwargs(UVS[:1]))
