"""Scratched-metal OSL shader vs core.scratch.scratch_radiance on a flat plate (per pixel).

Reference: ``scratch_radiance`` (numpy, float64) at the rendered pixels' positions (position pass),
with the same lamps converted independently from the Blender lamp settings (verify.core_light) and
the footprint the shader derived from Cycles' ray differentials (checked against the camera
geometry in ``test_footprint_is_the_pixel_width``). Relative errors are taken over pixels whose
reference exceeds 1 % of its 99th percentile. Acceptance (issue 14): median <= 2 %, p99 <= 10 %.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from material_structures.addon.scratch.verify import relative_errors, render_plate_vs_core

SPHERE = ("POINT", (0.5, 0.3, 1.2), 200.0, 0.08)
RECT = ("AREA", (0.45, 0.3, 1.0), 100.0, (0.3, 0.2))


def _check(lamps, debug=1, spectral=False, min_pixels=30):
    rgb, ref, mask = render_plate_vs_core(lamps=lamps, debug=debug, spectral=spectral)
    err = relative_errors(rgb, ref, mask)
    assert err.size >= min_pixels, f"only {err.size} lit pixels: the test scene does not exercise the shader"
    assert np.median(err) <= 0.02, f"median relative error {np.median(err):.4f}"
    assert np.percentile(err, 99) <= 0.10, f"p99 relative error {np.percentile(err, 99):.4f}"
    return err


def test_sphere_and_polygon_lamps_match_core(addon_module):
    err = _check((SPHERE, RECT))
    # measured: median ~2e-4, p99 ~1e-3 on both Blender versions; keep a margin well inside the issue's
    assert np.median(err) < 2e-3


def test_sun_point_and_disk_lamps_match_core(addon_module):
    disk = ("AREA", (-0.4, -0.3, 1.1), 80.0, (0.35, 0.35))
    _check((("SUN", (0.5, 0.3, 1.2), 3.0, 0), ("POINT", (0.6, -0.2, 1.0), 150.0, 0), disk), min_pixels=20)


def test_rho_matches_core(addon_module):
    err = _check((SPHERE,), debug=2, min_pixels=100)
    assert np.percentile(err, 99) < 1e-3


@pytest.mark.slow
def test_spectral_mode_matches_core(addon_module):
    _check((SPHERE, RECT), spectral=True)


def test_footprint_is_the_pixel_width(addon_module):
    """Cycles' compact ray differentials: Dx, Dy of the UV map are orthogonal and one pixel long
    (ortho_scale / resolution on the plate, times the patch size in um), whatever the view tilt."""
    import bpy

    from material_structures.addon.scratch.verify import footprint_pass

    render_plate_vs_core(lamps=(SPHERE,), resolution=(12, 12))
    scene = bpy.context.scene
    g = next(n for n in bpy.data.materials["Plate"].node_tree.nodes if n.type == "GROUP")
    plate = next(o for o in scene.objects if o.type == "MESH")
    plate.data.materials[0] = bpy.data.materials["Plate"]
    scene.render.film_transparent = False
    J = footprint_pass(scene, g)[6, 6]
    pixel_um = 0.9 / 12 * 2000.0
    scale = g.inputs["FootprintScale"].default_value
    assert np.linalg.norm(J[:, 0]) == pytest.approx(scale * pixel_um, rel=1e-3)
    assert np.linalg.norm(J[:, 1]) == pytest.approx(scale * pixel_um, rel=1e-3)
    assert abs(J[:, 0] @ J[:, 1]) <= 1e-3 * (scale * pixel_um) ** 2


def test_spectra_header_matches_core():
    from material_structures.addon.scratch.spectra_header import HEADER, header_text

    with open(HEADER) as f:
        assert f.read() == header_text(), "regenerate cycles_osl/ms_scratch_spectra.h (spectra_header.py)"


def test_lamp_sync_follows_lamp_moves(addon_module):
    """Moving a lamp updates the shader inputs through the depsgraph handler; radius and units follow."""
    import bpy

    from material_structures.addon.scratch.material import scratch_script_nodes

    render_plate_vs_core(lamps=(SPHERE,), resolution=(8, 8))
    lamp = next(o for o in bpy.context.scene.objects if o.type == "LIGHT")
    lamp.location = (-0.2, 0.4, 0.9)
    lamp.data.shadow_soft_size = 0.05
    bpy.context.view_layer.update()
    node = next(scratch_script_nodes())
    assert tuple(node.inputs["Lamp1Position"].default_value) == pytest.approx((-0.2, 0.4, 0.9), abs=1e-6)
    assert node.inputs["Lamp1Radius"].default_value == pytest.approx(0.05)
    assert node.inputs["Lamp1Color"].default_value[0] == pytest.approx(200.0 / (4 * math.pi), rel=1e-6)
    assert node.inputs["Lamp1Type"].default_value == 1
    assert node.inputs["Lamp2Type"].default_value == 0


def test_showcase_scene_builds_and_shows_scratches(addon_module, tmp_path):
    """The 10 000-scratch sample scene: the scratch term adds light (glints) to a measurable fraction
    of the plate's pixels compared with the same material at zero scratch intensity."""
    import bpy

    from material_structures.addon.scratch.material import group_node
    from material_structures.render import render_to_array
    from material_structures.showcase import library

    library.render_library_scene("scratch-plate", str(tmp_path), (48, 36), 1)
    scene = bpy.context.scene
    g = group_node(bpy.data.materials["Scratched Steel"])
    assert g.node_tree["ms_scratch_set"]["n_segments"] > 10000
    g.inputs["Debug"].default_value = 1
    scratch = render_to_array(scene)[..., :3]
    assert np.mean(scratch.sum(-1) > 1e-3) > 0.05
    assert np.all(np.isfinite(scratch))
