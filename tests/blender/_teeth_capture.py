"""A tiny synthetic teeth capture, its import and the check of an applied fit, shared by the Blender-side teeth
tests (not a test module)."""

from __future__ import annotations

import os

import bpy
import numpy as np


def write_tiny_capture(folder: str, width: int, height: int, n_lights: int) -> str:
    """A synthetic capture of one tooth ("tooth0"), one camera and ``n_lights`` lights, ``width`` x ``height``
    px, written by the core into ``folder``; returns ``folder``."""
    from material_structures.core.teeth.capture import default_rig
    from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target

    scene = make_scene(n_teeth=1, resolution=12)
    cams, lights = default_rig(target=scene_target(scene), width=width, height=height, n_lights=n_lights,
                               n_cameras=1, fov_x_deg=2.6)
    render_capture(scene, cams, lights, spp=2, spp_background=1, max_depth=4).save(folder, scene.to_dict())
    return folder


def import_capture_scene(capture_dir: str):
    """An empty file with the capture's ``scene.json`` imported (Import Teeth Scene); returns tooth0's enamel."""
    bpy.ops.wm.read_homefile(use_empty=True)
    path = os.path.join(capture_dir, "scene.json")
    assert bpy.ops.material_structures.teeth_import_scene(filepath=path) == {"FINISHED"}
    return bpy.data.objects["tooth0 Enamel"]


def assert_fit_applied(enamel, fit_dir):
    """The first tooth of the fitted scene ``fit_dir/scene_fit.json`` is in ``enamel``'s tooth: its coefficients
    (clipped for the dentin shape keys) and its enamel's Sigma_t. Returns that fitted tooth."""
    from material_structures.core.teeth.scene import load_scene

    t = load_scene(os.path.join(fit_dir, "scene_fit.json")).teeth[0]
    st = enamel.ms_tooth
    assert st.has_fit
    np.testing.assert_allclose(tuple(st.fitted), t.c, atol=1e-6)
    np.testing.assert_allclose(st.coefficients(), np.clip(t.c, -0.8, 0.8), atol=1e-6)
    node = enamel.active_material.node_tree.nodes["Enamel"]
    np.testing.assert_allclose(tuple(node.inputs["Sigma_t"].default_value), t.enamel.sigma_t, rtol=1e-6)
    return t
