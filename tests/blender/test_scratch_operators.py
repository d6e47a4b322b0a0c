"""Scratch-set operators: generation statistics, file round trips, packed .blend, drawing (EXEC path)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from material_structures.core.scratch.scratch_io import load_scratch_set, save_scratch_set


@pytest.fixture
def plate(addon_module):
    import bpy

    from material_structures.render import add_textured_plane, configure_cycles, reset_scene

    scene = reset_scene()
    configure_cycles(scene, resolution=(8, 8), samples=1)
    obj = add_textured_plane(scene, 1.0)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)
    return obj


def _set_of(obj):
    from material_structures.addon.scratch.editing import material_set, object_scratch_material

    return material_set(object_scratch_material(obj))[1]


def _point(uv):
    return {"name": "", "location": (0.0, 0.0, 0.0), "uv": uv, "pressure": 1.0}


def _polyline_lengths(s):
    seg = s.segments
    lens = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    return np.bincount(s.scratch_id, weights=lens)


def test_generated_statistics_match_requested_ranges(plate):
    import bpy

    res = bpy.ops.material_structures.scratch_generate(
        pattern="WEAR", count=400, patch_mm=20.0, length_um=(500.0, 3000.0), width_um=(1.0, 4.0),
        depth_um=(0.5, 2.0), seed=7,
    )
    assert res == {"FINISHED"}
    s = _set_of(plate)
    widths = np.array([s.width_um[s.scratch_id == i][0] for i in np.unique(s.scratch_id)])
    depths = np.array([s.depth_um[s.scratch_id == i][0] for i in np.unique(s.scratch_id)])
    assert 380 <= s.n_scratches <= 400  # a few may be clipped away entirely at the patch edge
    assert widths.min() >= 1.0 and widths.max() <= 4.0
    assert depths.min() >= 0.5 and depths.max() <= 2.0
    # uniform draws: mean within 4 standard errors of the range's midpoint
    for a, lo, hi in ((widths, 1.0, 4.0), (depths, 0.5, 2.0)):
        se = (hi - lo) / np.sqrt(12 * a.size)
        assert abs(a.mean() - 0.5 * (lo + hi)) <= 4 * se
    lengths = _polyline_lengths(s)
    assert lengths.max() <= 3000.0 * 1.001  # clipping can only shorten
    assert np.median(lengths) >= 500.0
    assert np.allclose(s.patch_size_um, 20000.0)
    assert s.sigma_um == 60.0


def test_fine_wear_and_other_patterns(plate):
    import bpy

    assert bpy.ops.material_structures.scratch_generate(pattern="HAIRLINE", count=50, fine_wear=True) == {"FINISHED"}
    s = _set_of(plate)
    assert s.sigma_um == 10.0
    seg = s.segments
    ang = np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0])
    assert np.percentile(np.abs(np.sin(ang)), 95) < 0.1  # hairlines run along the 0 degree direction
    assert bpy.ops.material_structures.scratch_generate(pattern="POLISH", count=30, replace=False) == {"FINISHED"}
    s2 = _set_of(plate)
    assert s2.n_scratches == s.n_scratches + 30 or s2.n_scratches >= s.n_scratches + 25


def test_file_round_trip_npz_and_exr(plate, tmp_path):
    import bpy

    bpy.ops.material_structures.scratch_generate(pattern="WEAR", count=60, seed=1)
    s = _set_of(plate)
    for target in (str(tmp_path / "set.npz"), str(tmp_path / "set_exr")):
        assert bpy.ops.material_structures.scratch_export(filepath=target) == {"FINISHED"}
        back = load_scratch_set(target)
        np.testing.assert_array_equal(back.segments, s.segments)  # s is float32-exact already
        np.testing.assert_array_equal(back.width_um, s.width_um)
        np.testing.assert_array_equal(back.cell_segments, s.cell_segments)
        np.testing.assert_array_equal(back.grid_count, s.grid_count)
    other = load_scratch_set(str(tmp_path / "set.npz"))
    save_scratch_set(str(tmp_path / "again.npz"), other)
    assert bpy.ops.material_structures.scratch_import(filepath=str(tmp_path / "again.npz")) == {"FINISHED"}
    np.testing.assert_array_equal(_set_of(plate).segments, s.segments)


def test_packed_blend_reopens_intact(plate, tmp_path):
    """The set lives in packed images: save, delete the EXR cache, reopen -> same set, cache re-extracted."""
    import shutil

    import bpy

    from material_structures.addon.scratch.material import scratch_script_nodes

    bpy.ops.material_structures.scratch_generate(pattern="WEAR", count=80, seed=5)
    s = _set_of(plate)
    name = plate.name
    folder = next(scratch_script_nodes()).inputs["TableDir"].default_value
    path = str(tmp_path / "scratched.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    shutil.rmtree(folder)
    bpy.ops.wm.open_mainfile(filepath=path)
    obj = bpy.data.objects[name]
    back = _set_of(obj)
    for key in ("segments", "width_um", "depth_um", "scratch_id", "grid_offset", "grid_count", "cell_segments"):
        np.testing.assert_array_equal(getattr(back, key), getattr(s, key))
    node = next(scratch_script_nodes())
    assert node.inputs["TableDir"].default_value == folder
    assert os.path.isfile(os.path.join(folder, "segments.exr")), "load_post did not re-extract the tables"
    np.testing.assert_array_equal(load_scratch_set(folder).segments, s.segments)


def test_draw_exec_replays_a_recorded_curve(plate):
    import bpy

    bpy.ops.material_structures.scratch_generate(pattern="WEAR", count=5, seed=2)
    before = _set_of(plate)
    op = bpy.ops.material_structures.scratch_draw
    stroke = [_point((0.1 + 0.08 * i, 0.5 + 0.02 * i)) for i in range(8)]
    assert op(stroke=stroke, width_um=(3.0, 3.0), depth_um=(1.5, 1.5)) == {"FINISHED"}
    after = _set_of(plate)
    assert after.n_scratches == before.n_scratches + 1
    new = after.scratch_id == after.scratch_id.max()
    np.testing.assert_allclose(after.width_um[new], 3.0)
    # the drawn scratch follows the curve: its endpoints are the first and last UV points in um
    seg = after.segments[new]
    np.testing.assert_allclose(seg[0, :2], np.array([0.1, 0.5]) * 20000.0, atol=0.01)
    np.testing.assert_allclose(seg[-1, 2:], np.array([0.1 + 0.56, 0.5 + 0.14]) * 20000.0, atol=0.01)


def test_draw_rejects_short_stroke(plate):
    import bpy

    bpy.ops.material_structures.scratch_generate(pattern="WEAR", count=5, seed=2)
    with pytest.raises(RuntimeError, match="at least 2 points"):
        bpy.ops.material_structures.scratch_draw(stroke=[_point((0.5, 0.5))])


def test_draw_modal_with_stand_in_events(plate):
    """modal() directly, with stand-in events and a stubbed ray cast (no window in background mode)."""
    import bpy

    from material_structures.addon.scratch.operators import MS_OT_scratch_draw

    bpy.ops.material_structures.scratch_generate(pattern="WEAR", count=5, seed=2)
    before = _set_of(plate).n_scratches

    class Ev:
        def __init__(self, type_, value="NOTHING", x=0):
            self.type, self.value, self.mouse_region_x, self.mouse_region_y = type_, value, x, 0

    class Stub:
        stroke = []
        width_um, depth_um, seed = (2.0, 2.0), (1.0, 1.0), 0

        def report(self, *_a):
            pass

        def _uv_under_mouse(self, _context, event):
            return (0.2 + 0.05 * event.mouse_region_x, 0.3)

    op = Stub()
    for name in ("modal", "_finish", "_add_curves"):
        setattr(op, name, getattr(MS_OT_scratch_draw, name).__get__(op))
    op.drawing, op.points, op.curves = False, [], []
    ctx = bpy.context
    assert op.modal(ctx, Ev("LEFTMOUSE", "PRESS", 0)) == {"RUNNING_MODAL"}
    for x in range(1, 6):
        op.modal(ctx, Ev("MOUSEMOVE", x=x))
    op.modal(ctx, Ev("LEFTMOUSE", "RELEASE", 5))
    assert op.modal(ctx, Ev("ESC", "PRESS")) == {"FINISHED"}
    assert _set_of(plate).n_scratches == before + 1
