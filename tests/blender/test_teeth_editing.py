"""Tooth object pairs: geometry against the core model (eq. 5.5), live shape keys, undo, save/reload."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from material_structures.core.teeth.dentin_blend_shapes import MODE_NAMES
from material_structures.core.teeth.tooth_mesh import make_tooth

TOL = 2e-5  # float32 mesh coordinates of ~10 mm


def _geometry():
    from material_structures.addon.teeth import geometry as G

    return G


def _add(kind="CANINE", resolution=16):
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.material_structures.teeth_add_tooth(kind=kind, resolution=resolution, smooth=False) == {"FINISHED"}
    enamel = bpy.context.active_object
    return enamel, enamel.ms_tooth.partner


def _expected(kind, resolution, c):
    G = _geometry()
    geo = make_tooth(kind, resolution=resolution)
    b = geo.dentin.base
    n = G.vertex_normals(b.vertices, b.faces)
    dentin = b.vertices - G.GAP_MM * n + np.tensordot(np.asarray(c), geo.dentin.deltas, axes=1)
    inner = geo.dentin.vertices(np.asarray(c))
    return geo, dentin, inner


def test_pair_structure_matches_core(addon_module):
    G = _geometry()
    enamel, dentin = _add()
    geo, dv, inner = _expected("canine", 16, (0, 0, 0))
    assert enamel.ms_tooth.role == "ENAMEL" and dentin.ms_tooth.role == "DENTIN"
    assert dentin.parent == enamel and enamel.ms_tooth.partner == dentin
    assert [k.name for k in dentin.data.shape_keys.key_blocks] == ["Basis", *MODE_NAMES]
    assert [k.name for k in enamel.data.shape_keys.key_blocks] == ["Basis", *MODE_NAMES]
    ne = len(geo.enamel.vertices)
    ev = G.evaluated_vertices(enamel)
    np.testing.assert_allclose(ev[:ne], geo.enamel.vertices, atol=TOL)
    np.testing.assert_allclose(ev[ne:], inner, atol=TOL)
    np.testing.assert_allclose(G.evaluated_vertices(dentin), dv, atol=TOL)
    inner_attr = np.empty(len(enamel.data.polygons), dtype=np.float32)
    enamel.data.attributes["ms_inner"].data.foreach_get("value", inner_attr)
    assert inner_attr.sum() == len(geo.dentin.base.faces)
    uv = np.empty(len(enamel.data.loops) * 2, dtype=np.float32)
    enamel.data.uv_layers["UVMap"].data.foreach_get("uv", uv)
    nf = len(geo.enamel.faces)
    np.testing.assert_allclose(uv.reshape(-1, 2)[: 3 * nf], geo.enamel.corner_uv.reshape(-1, 2), atol=1e-6)
    assert enamel.scale[0] == pytest.approx(1e-3)  # mm mesh in a metre scene
    assert enamel.active_material.node_tree.nodes["Enamel"].node_tree.name == "Enamel"
    targets = sorted(n.target for n in enamel.active_material.node_tree.nodes if n.type == "OUTPUT_MATERIAL")
    assert targets == ["CYCLES", "EEVEE"]  # the OSL boundary is Cycles-only: EEVEE gets a stand-in


def test_sliders_drive_both_meshes_eq_5_5(addon_module):
    G = _geometry()
    enamel, dentin = _add("INCISOR", 16)
    c = (0.3, -0.25, 0.6)
    st = enamel.ms_tooth
    st.buccal, st.proximal, st.occlusal = c
    geo, dv, inner = _expected("incisor", 16, c)
    np.testing.assert_allclose(G.key_values(dentin), c, atol=1e-6)
    np.testing.assert_allclose(G.evaluated_vertices(dentin), dv, atol=TOL)
    ne = len(geo.enamel.vertices)
    ev = G.evaluated_vertices(enamel)
    np.testing.assert_allclose(ev[ne:], inner, atol=TOL)
    np.testing.assert_allclose(ev[:ne], geo.enamel.vertices, atol=TOL)  # the outer surface never moves
    # the operator path and the range clamp (core RANGES["c"] = +-0.8)
    bpy.context.view_layer.objects.active = dentin  # editing through the dentin core works too
    assert bpy.ops.material_structures.teeth_set_dentin(coefficients=(0.1, 0.0, -0.1)) == {"FINISHED"}
    np.testing.assert_allclose(G.key_values(enamel), (0.1, 0.0, -0.1), atol=1e-6)
    st.buccal = 5.0
    assert st.buccal == pytest.approx(0.8)


def test_undo_restores_mesh(addon_module):
    G = _geometry()
    enamel, dentin = _add("PREMOLAR", 12)
    before = G.evaluated_vertices(dentin)
    bpy.ops.ed.undo_push(message="before edit")
    enamel.ms_tooth.occlusal = 0.5
    moved = G.evaluated_vertices(dentin)
    assert np.abs(moved - before).max() > 0.2  # mm
    bpy.ops.ed.undo_push(message="edit")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    enamel = bpy.data.objects["Premolar Enamel"]
    assert enamel.ms_tooth.occlusal == 0.0
    np.testing.assert_allclose(G.evaluated_vertices(enamel.ms_tooth.partner), before, atol=1e-7)


def test_fit_values_roundtrip_through_blend_file(addon_module, tmp_path):
    from material_structures.addon.teeth.scene_build import apply_fit
    from material_structures.core.teeth.synthetic import make_scene

    G = _geometry()
    bpy.ops.wm.read_homefile(use_empty=True)
    ts = make_scene(n_teeth=1, resolution=12, with_gums=False, with_cavity=False)
    from material_structures.addon.teeth.scene_build import build_teeth_scene

    build_teeth_scene(ts, bpy.context.scene.collection, mm_per_unit=1000.0)
    fit = ts.copy()
    fit.teeth[0].c = np.array([0.41, -0.33, 0.27])
    fit.teeth[0].enamel.sigma_t = np.array([1.7, 2.3, 4.1])
    fit.teeth[0].dentin.g1 = 0.37
    fit.teeth[0].a_t = np.linspace(0.5, 0.9, 4 * 3 * 3).reshape(4, 3, 3)
    assert apply_fit(fit, bpy.context.scene, source="test", set_current=False) == ["tooth0"]
    enamel = bpy.data.objects["tooth0 Enamel"]
    assert bpy.ops.material_structures.teeth_apply_fitted.poll()
    bpy.context.view_layer.objects.active = enamel
    assert bpy.ops.material_structures.teeth_apply_fitted() == {"FINISHED"}
    verts = G.evaluated_vertices(enamel.ms_tooth.partner)
    path = str(tmp_path / "teeth.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    assert "tooth0 Enamel" not in bpy.data.objects
    bpy.ops.wm.open_mainfile(filepath=path)
    enamel = bpy.data.objects["tooth0 Enamel"]
    st = enamel.ms_tooth
    np.testing.assert_allclose(tuple(st.fitted), (0.41, -0.33, 0.27), atol=1e-6)
    np.testing.assert_allclose(st.coefficients(), (0.41, -0.33, 0.27), atol=1e-6)
    assert st.has_fit and st.fit_source == "test"
    np.testing.assert_allclose(G.key_values(st.partner), (0.41, -0.33, 0.27), atol=1e-6)
    np.testing.assert_allclose(G.evaluated_vertices(st.partner), verts, atol=1e-7)
    node = enamel.active_material.node_tree.nodes["Enamel"]
    np.testing.assert_allclose(tuple(node.inputs["Sigma_t"].default_value), (1.7, 2.3, 4.1), rtol=1e-6)
    assert st.partner.active_material.node_tree.nodes["Dentin"].inputs["G1"].default_value == pytest.approx(0.37)
    img = next(n for n in enamel.active_material.node_tree.nodes if n.type == "TEX_IMAGE").image
    px = np.empty(img.size[0] * img.size[1] * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    np.testing.assert_allclose(px.reshape(4, 3, 4)[:, :, :3], fit.teeth[0].a_t, atol=1e-6)


def test_tooth_from_mesh(addon_module):
    import bmesh

    G = _geometry()
    bpy.ops.wm.read_homefile(use_empty=True)
    me = bpy.data.meshes.new("Blob")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=8, radius=0.005)  # 5 mm
    bmesh.ops.triangulate(bm, faces=bm.faces[:])
    bm.to_mesh(me)
    bm.free()
    obj = bpy.data.objects.new("Blob", me)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.material_structures.teeth_add_tooth(source="MESH") == {"FINISHED"}
    enamel = bpy.context.active_object
    dv = G.evaluated_vertices(enamel.ms_tooth.partner)
    r = np.linalg.norm(dv, axis=1)
    assert r.max() < 5.0 - 1.0 and r.min() > 2.0  # inside by the enamel thickness (1.1 - 1.8 mm)


def test_errors_are_reported(addon_module):
    with pytest.raises(RuntimeError, match="closed mesh"):
        bpy.ops.material_structures.teeth_add_tooth(source="MESH")
    with pytest.raises(RuntimeError, match="not a tooth"):
        bpy.ops.material_structures.teeth_set_dentin(coefficients=(0.1, 0.1, 0.1))
    _add()
    with pytest.raises(RuntimeError, match="No fitted"):
        bpy.ops.material_structures.teeth_apply_fitted()
