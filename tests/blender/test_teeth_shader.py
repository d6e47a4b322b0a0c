"""Teeth materials in Cycles: the OSL enamel boundary against eq. 5.1-5.2, the node groups, and the
Cycles-vs-core cross-check on a small scene (the full-size acceptance run is slow-marked)."""

from __future__ import annotations

import math
import os

import bpy
import numpy as np
import pytest

from material_structures.core.teeth.fresnel import fresnel_dielectric


def _emitter(scene, name, center, normal, color, size=1.0):
    from mathutils import Vector

    from material_structures import render as R

    mat = R.new_material(name)
    tree = mat.node_tree
    out = R.scene.material_output(mat)
    em = tree.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    em.inputs["Strength"].default_value = 1.0
    tree.links.new(em.outputs[0], out.inputs["Surface"])
    obj = R.add_textured_plane(scene, size, mat, name)
    obj.location = center
    obj.rotation_euler = Vector((0, 0, 1)).rotation_difference(Vector(normal)).to_euler()
    return obj


@pytest.mark.parametrize("theta_deg", [25.0, 60.0, 75.0])
def test_enamel_boundary_reflection_and_straight_transmission(addon_module, theta_deg):
    """Boundary plane tilted by theta under an orthographic view: the straight-through ray sees a red emitter
    (pixel R = a_t (1 - F)), the mirror ray a green one (pixel G = F); eq. 5.1-5.2 with eta 1.631."""
    from material_structures import render as R
    from material_structures.addon.teeth.materials import _load_boundary_script

    scene = bpy.context.scene
    R.configure_cycles(scene, resolution=(4, 4), samples=512, seed=3)
    R.dark_world(scene)
    a_t = 0.8
    mat = R.new_material("Boundary")
    script = _load_boundary_script(mat.node_tree, scene)
    script.inputs["At"].default_value = (a_t, a_t, a_t, 1.0)
    script.inputs["Eta"].default_value = 1.631
    mat.node_tree.links.new(script.outputs["BSDF"], R.scene.material_output(mat).inputs["Surface"])
    plane = R.add_textured_plane(scene, 1.0, mat, "Boundary")
    th = math.radians(theta_deg)
    plane.rotation_euler = (th, 0.0, 0.0)  # normal (0, -sin, cos)
    r = np.array([0.0, -math.sin(2 * th), math.cos(2 * th)])  # mirror direction of the view ray (0, 0, -1)
    _emitter(scene, "Through", (0.0, 0.0, -2.0), (0, 0, 1), (1.0, 0.0, 0.0))
    _emitter(scene, "Mirror", tuple(2.0 * r), tuple(-r), (0.0, 1.0, 0.0))
    R.add_orthographic_camera(scene, 0.2)
    rgb = R.render_to_array(scene)[:, :, :3].reshape(-1, 3).mean(axis=0)
    F = float(fresnel_dielectric(math.cos(th), 1.631))
    # 16 px x 512 spp: a binary closure choice per sample, relative std < 0.5 % for these weights
    assert rgb[0] == pytest.approx(a_t * (1.0 - F), rel=0.02)
    assert rgb[1] == pytest.approx(F, rel=0.06, abs=0.004)
    assert rgb[2] == pytest.approx(0.0, abs=1e-6)


def test_node_groups_and_add_menu(addon_module):
    from material_structures.addon.nodes import MENU_ENTRIES
    from material_structures.addon.teeth.materials import ensure_group

    groups = (("Enamel", ["Surface", "Volume", "EEVEE Surface"]), ("Dentin", ["Volume"]),
              ("Gingiva", ["Surface", "Volume", "EEVEE Surface"]))
    for kind, outputs in groups:
        g = ensure_group(kind, bpy.context.scene)
        outs = [s.name for s in g.interface.items_tree if s.item_type == "SOCKET" and s.in_out == "OUTPUT"]
        assert outs == outputs
        ops = [op for label, op, _ in MENU_ENTRIES if label == kind]
        assert ops and hasattr(bpy.ops.material_structures, ops[0].split(".")[1])
    eta = {k: next(s for s in bpy.data.node_groups[k].interface.items_tree if s.name == "Eta").default_value
           for k in ("Enamel", "Gingiva")}
    assert eta["Enamel"] == pytest.approx(1.631) and eta["Gingiva"] == pytest.approx(1.33)


def _check(spp_cycles, spp_core, width, height, max_depth):
    from material_structures.addon.teeth.verify import cross_check

    out, _, _, _ = cross_check(spp_cycles=spp_cycles, spp_core=spp_core, width=width, height=height,
                               max_depth=max_depth)
    return out


REF = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "references",
                   "teeth-core-check-small.exr")


def test_cycles_matches_core_small(addon_module, update_refs):
    """32 x 20 px, Cycles 128 spp vs core 32 spp, depth 32 (MC error of this size: a few %).
    Tolerances: per-tooth mean colour 5 %, median 8 x 8-blurred pixel 8 %.

    The core image is a stored reference (deterministic: fixed seeds), rendered with the core forward
    path tracer by this test under ``--update-refs`` or when missing: the 4.5 environment has no embree,
    where the core's numpy ray caster takes minutes."""
    from material_structures.addon.teeth.verify import (
        check_scene,
        compare,
        render_core,
        render_cycles,
        tooth_regions,
    )
    from material_structures.core.exr_io import read_exr, write_exr

    ts, cam, light = check_scene(2, 20, 32, 20)
    if update_refs or not os.path.exists(REF):
        core = 0.5 * (render_core(ts, cam, light, 16, seed=1, max_depth=32)
                      + render_core(ts, cam, light, 16, seed=2, max_depth=32))
        write_exr(REF, core.astype(np.float32))
    core = read_exr(REF, channels=["R", "G", "B"]).astype(np.float64)
    cyc = render_cycles(ts, cam, light, 128, bounces=32)
    out = compare(cyc, core, tooth_regions(ts, cam))
    assert out["tooth_pixels"] > 150
    assert out["mean_colour_rel_err"] < 0.05, out
    assert out["median_px_rel_err"] < 0.08, out


@pytest.mark.slow
def test_cycles_matches_core_acceptance(addon_module):
    """The issue's acceptance: 64 x 40 px, Cycles 256 spp vs core 64 spp, depth 64:
    mean colour per tooth within 3 %, median per-pixel relative error after an 8 x 8 box filter <= 5 %.
    (Core per-tooth mean MC std at 64 spp is ~0.7-1 % per channel, measured over independent seeds.)"""
    pytest.importorskip("embreex")  # the core's numpy ray caster (4.5 env) takes many minutes here
    out = _check(256, 64, 64, 40, 64)
    assert out["mean_colour_rel_err"] < 0.03, out
    assert out["median_px_rel_err"] <= 0.05, out
