"""Fabric operators: clear errors, map import/save round trip, lamps kept in sync."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from material_structures.core.fabric.parameter_maps import load_params, make_maps, save_params


def _scene_with_plane(uv=True):
    from material_structures import render as R

    scene = R.reset_scene()
    R.configure_cycles(scene, resolution=(8, 8), samples=1)
    if uv:
        obj = R.add_textured_plane(scene, 1.0)
    else:
        mesh = bpy.data.meshes.new("NoUV")
        mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0)], [], [(0, 1, 2)])
        obj = bpy.data.objects.new("NoUV", mesh)
        scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    return scene, obj


def _write_fit(folder, h=3, w=4, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(h, w, 4))
    maps = make_maps(
        kd=rng.uniform(0, 0.3, (h, w, 3)),
        ks=rng.uniform(0.1, 1, (h, w, 3)),
        sigma=rng.uniform(0.2, 2, (h, w, 2)),
        basis=q,
    )
    save_params(folder, maps)
    return maps


def test_new_material_needs_uvs(addon_module):
    _, obj = _scene_with_plane(uv=False)
    with pytest.raises(RuntimeError, match="no UV map"):
        bpy.ops.material_structures.fabric_new_material(preset="VELVET")
    assert len(obj.data.materials) == 0


def test_new_material_from_preset(addon_module):
    _, obj = _scene_with_plane()
    assert bpy.ops.material_structures.fabric_new_material(preset="CORDUROY") == {"FINISHED"}
    mat = obj.active_material
    assert mat is not None and mat.get("material_structures_fabric")
    from material_structures.addon.fabric.maps import images_to_maps
    from material_structures.addon.fabric.material import material_map_images

    sigma = images_to_maps(material_map_images(mat)).sigma  # the preset's maps (brushable)
    np.testing.assert_allclose(sigma.reshape(-1, 2).mean(axis=0, dtype=np.float64), [2.2, 0.9], rtol=1e-6)
    targets = sorted(n.target for n in mat.node_tree.nodes if n.type == "OUTPUT_MATERIAL")
    assert targets == ["CYCLES", "EEVEE"]  # never pink in EEVEE


def test_preset_material_carries_its_fitted_closures(addon_module):
    from material_structures.addon.fabric.maps import CLOSURE_KEYS, images_to_closure_maps, images_to_maps
    from material_structures.addon.fabric.material import (
        fabric_group_node,
        material_closure_images,
        material_map_images,
    )
    from material_structures.core.fabric.closure_fit import fit_closure_maps

    _, obj = _scene_with_plane()
    assert bpy.ops.material_structures.fabric_new_material(preset="CORDUROY") == {"FINISHED"}
    mat = obj.active_material
    images = material_closure_images(mat)
    assert sorted(images) == sorted(CLOSURE_KEYS)
    assert all(img.packed_file is not None and img.colorspace_settings.name == "Non-Color" for img in images.values())
    assert fabric_group_node(mat).inputs["UseFittedClosures"].default_value == 1
    maps = images_to_maps(material_map_images(mat), btf_frame=False)
    expect = fit_closure_maps(maps.sigma, maps.basis)
    got = images_to_closure_maps(images)
    np.testing.assert_allclose(got.weights, expect.weights, atol=1e-6)
    np.testing.assert_allclose(got.shape, expect.shape, atol=1e-6)
    np.testing.assert_allclose(got.ggx_scale, expect.ggx_scale, atol=1e-6)


def test_import_reads_closures_the_fitter_saved_and_save_writes_them(addon_module, tmp_path):
    from material_structures.addon.fabric.maps import images_to_closure_maps
    from material_structures.addon.fabric.material import material_closure_images
    from material_structures.core.fabric.closure_fit import ClosureMaps, load_closure_maps, save_closure_maps

    _write_fit(tmp_path / "fit")
    marked = ClosureMaps(weights=np.full((3, 4, 5, 4), 0.25, np.float32), shape=np.full((3, 4, 6), 0.5, np.float32),
                         ggx_scale=np.full((3, 4, 1), 1.4, np.float32))
    save_closure_maps(tmp_path / "fit", marked)
    _, obj = _scene_with_plane()
    assert bpy.ops.material_structures.fabric_import_maps(directory=str(tmp_path / "fit")) == {"FINISHED"}
    got = images_to_closure_maps(material_closure_images(obj.active_material))
    np.testing.assert_array_equal(got.weights, marked.weights)
    assert bpy.ops.material_structures.fabric_save_maps(directory=str(tmp_path / "saved")) == {"FINISHED"}
    np.testing.assert_array_equal(load_closure_maps(tmp_path / "saved").ggx_scale, marked.ggx_scale)


def test_material_from_before_the_second_velvet_is_completed_at_weight_zero(addon_module, tmp_path):
    """A fabric material saved before the mix had a second velvet has six closure images. Saving its
    maps (and brushing it) first adds the two missing images with w_v2 = 0, which is the mix those
    closures were fitted as: the five weights and the first four shape values are kept bit for bit.
    Without the completion the save would skip the closures (it writes them only when all are there)."""
    from material_structures.addon.fabric.maps import CLOSURE_KEYS, images_to_closure_maps
    from material_structures.addon.fabric.material import complete_closure_images, material_closure_images
    from material_structures.core.fabric.closure_fit import load_closure_maps

    _, obj = _scene_with_plane()
    assert bpy.ops.material_structures.fabric_new_material(preset="VELVET") == {"FINISHED"}
    mat = obj.active_material
    full = images_to_closure_maps(material_closure_images(mat))
    for node in list(mat.node_tree.nodes):  # what a file from before holds
        if node.type == "TEX_IMAGE" and node.name in ("fit_velvet2", "fit_shape2"):
            mat.node_tree.nodes.remove(node)
    assert len(material_closure_images(mat)) == 6
    assert bpy.ops.material_structures.fabric_save_maps(directory=str(tmp_path / "saved")) == {"FINISHED"}
    assert sorted(material_closure_images(mat)) == sorted(CLOSURE_KEYS)
    back = load_closure_maps(tmp_path / "saved")
    np.testing.assert_array_equal(back.weights[..., :4, :], full.weights[..., :4, :])
    np.testing.assert_array_equal(back.shape[..., :4], full.shape[..., :4])
    assert np.all(back.weights[..., 4, :] == 0.0)
    new_nodes = ("fit_velvet2", "fit_shape2")
    links = {link.to_socket.name for link in mat.node_tree.links if link.from_node.name in new_nodes}
    assert links == {"FitVelvet2", "FitVelvet2A", "FitShape2"}
    assert complete_closure_images(mat).keys() == material_closure_images(mat).keys()  # nothing added twice


def test_import_and_save_roundtrip(addon_module, tmp_path):
    maps = _write_fit(tmp_path / "fit")
    _, obj = _scene_with_plane()
    assert bpy.ops.material_structures.fabric_import_maps(directory=str(tmp_path / "fit")) == {"FINISHED"}
    mat = obj.active_material
    from material_structures.addon.fabric.material import material_map_images

    images = material_map_images(mat)
    assert sorted(images) == ["basis", "kd", "ks", "sigma"]
    from material_structures.addon.fabric.material import material_closure_images

    assert len(material_closure_images(mat)) == 8  # fitted on import (no closure maps in the folder)
    assert all(img.packed_file is not None for img in images.values())  # saved inside the .blend
    assert bpy.ops.material_structures.fabric_save_maps(directory=str(tmp_path / "saved")) == {"FINISHED"}
    back = load_params(tmp_path / "saved")
    for key in ("kd", "ks", "sigma", "basis"):
        np.testing.assert_allclose(getattr(back, key), getattr(maps, key), atol=1e-7)


def test_import_reports_bad_folder(addon_module, tmp_path):
    _scene_with_plane()
    with pytest.raises(RuntimeError, match="params.json"):
        bpy.ops.material_structures.fabric_import_maps(directory=str(tmp_path))
    _write_fit(tmp_path / "fit")
    (tmp_path / "fit" / "sigma.exr").write_bytes(b"garbage")
    with pytest.raises(RuntimeError, match="sigma"):
        bpy.ops.material_structures.fabric_import_maps(directory=str(tmp_path / "fit"))


def test_moving_a_lamp_updates_the_shader(addon_module):
    scene, obj = _scene_with_plane()
    bpy.ops.material_structures.fabric_new_material(preset="VELVET")
    light = bpy.data.lights.new("Key", "POINT")
    light.energy = 10.0
    lamp = bpy.data.objects.new("Key", light)
    scene.collection.objects.link(lamp)
    lamp.location = (1.0, 2.0, 3.0)
    bpy.context.view_layer.update()  # fires depsgraph_update_post
    from material_structures.addon.fabric.material import fabric_script_nodes

    node = next(fabric_script_nodes())
    assert node.inputs["Lamp1Type"].default_value == 1
    assert tuple(node.inputs["Lamp1Position"].default_value) == pytest.approx((1.0, 2.0, 3.0))
    assert node.inputs["Lamp1Color"].default_value[0] == pytest.approx(10.0 / (4 * np.pi), rel=1e-6)
    lamp.location = (-1.0, 0.5, 2.0)
    bpy.context.view_layer.update()
    assert tuple(node.inputs["Lamp1Position"].default_value) == pytest.approx((-1.0, 0.5, 2.0))
    # the fabric object is light-linked off the lamp (its closures must not count it twice)
    coll = lamp.light_linking.receiver_collection
    assert coll is not None and obj.name in coll.objects
    assert coll.collection_objects[0].light_linking.link_state == "EXCLUDE"


def test_fabric_material_cli_writes_a_blend(tmp_path):
    import subprocess
    import sys

    _write_fit(tmp_path / "fit")
    out = tmp_path / "fabric.blend"
    proc = subprocess.run(
        [sys.executable, "-m", "material_structures", "fabric", "material", str(tmp_path / "fit"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    with bpy.data.libraries.load(str(out)) as (src, _dst):
        assert "Fabric fit" in src.materials
        assert {"SGGX fit kd", "SGGX fit basis"} <= set(src.images)
    bad = subprocess.run(
        [sys.executable, "-m", "material_structures", "fabric", "material", str(tmp_path / "nothing")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert bad.returncode == 1 and "params.json" in bad.stderr  # a runtime error: 1


def test_syncing_an_unchanged_scene_writes_nothing(addon_module, tmp_path):
    """The depsgraph handler copies lamps and the world into the shader; once they are in, another
    sync must not write the sockets again (a float64 value never equals its float32 socket: every
    sync would tag the material and restart the viewport render)."""
    from material_structures.addon.fabric.material import fabric_script_nodes
    from material_structures.addon.fabric.verify import hdri_world
    from material_structures.core.fabric import closure_accuracy as A

    scene, _obj = _scene_with_plane()
    bpy.ops.material_structures.fabric_new_material(preset="VELVET")
    light = bpy.data.lights.new("Key", "POINT")
    light.energy = 10.0  # its intensity 10 / 4 pi is not a float32
    lamp = bpy.data.objects.new("Key", light)
    scene.collection.objects.link(lamp)
    world = hdri_world(scene, A.sky_hdri(16, 32), str(tmp_path / "sky.exr"), rotation_z_deg=37.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.7
    bpy.context.view_layer.update()
    bpy.context.view_layer.update()
    node = next(fabric_script_nodes())
    assert node.inputs["WorldTable"].default_value and node.inputs["WorldWidth"].default_value == 32
    assert node.inputs["WorldStrength"].default_value == pytest.approx(0.7)
    assert node.inputs["WorldAxisX"].default_value[1] == pytest.approx(-np.sin(np.radians(37.0)), abs=1e-6)
    seen = []

    def spy(_scene, depsgraph):
        seen.extend(type(u.id).__name__ for u in depsgraph.updates)

    from material_structures.addon.fabric.material import sync_fabric_lamps

    bpy.app.handlers.depsgraph_update_post.append(spy)
    try:
        sync_fabric_lamps(scene)  # what the handler does on the next change anywhere in the scene
        bpy.context.view_layer.update()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(spy)
    assert not seen, seen


def test_cli_writes_that_blender_refuses_are_one_line(addon_module, tmp_path, capsys):
    """``render --blend`` of a file whose scene has no camera, ``fabric material --out`` where Blender cannot write
    (here a folder of that name): one line each, no traceback; no preview left without its .blend."""
    from material_structures.cli import main

    bpy.ops.wm.read_homefile(use_empty=True)
    empty = tmp_path / "empty.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(empty))
    assert main(["render", "--blend", str(empty), "--out", str(tmp_path / "r.png"), "--resolution", "8x8"]) == 1
    err = capsys.readouterr().err
    assert "has no camera" in err and err.count("\n") == 1 and "Traceback" not in err, err
    _write_fit(tmp_path / "fit")
    (tmp_path / "m.blend").mkdir()
    preview = tmp_path / "m.png"
    assert main(["fabric", "material", str(tmp_path / "fit"), "--out", str(tmp_path / "m.blend"),
                 "--render", str(preview), "--samples", "1"]) == 1
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert lines and "cannot write" in lines[-1] and "Traceback" not in err, err
    assert not preview.exists() and not (tmp_path / "r.png").exists()
