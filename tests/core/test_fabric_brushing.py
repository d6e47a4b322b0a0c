"""Brushing / editing of fabric parameter maps (thesis section 3.5) against closed forms and a
brute-force second implementation of the capsule weights."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.fabric.brushing import (
    BrushStates,
    anisotropy,
    brush_data_driven,
    brush_edit,
    brush_fibres,
    brush_stroke,
    brushed_basis,
    capsule_window,
    max_tilt,
    recolor,
    smoothness,
    stroke_weight_map,
)
from material_structures.core.fabric.parameter_maps import make_maps
from material_structures.core.fabric.quaternion import quat_angle, quat_from_axis_angle, quat_to_matrix
from material_structures.core.fabric.sggx_brdf import sggx_brdf


def flat_maps(h=40, w=50, q=(1.0, 0, 0, 0)):
    return make_maps(np.full((h, w, 3), 0.2), np.full((h, w, 3), 0.5),
                     np.tile([0.3, 0.6], (h, w, 1)), np.tile(q, (h, w, 1)))


def test_capsule_weights_match_brute_force():
    shape = (30, 40)
    p0, p1, r = np.array([5.3, 7.1]), np.array([31.0, 20.4]), 6.5
    win = capsule_window(shape, p0, p1, r, strength=0.8)
    full = np.zeros(shape)
    full[win.slices] = win.weight
    ref = np.zeros(shape)
    for y in range(shape[0]):
        for x in range(shape[1]):
            p = np.array([x + 0.5, y + 0.5])
            t = min(1.0, max(0.0, float((p - p0) @ (p1 - p0) / ((p1 - p0) @ (p1 - p0)))))
            dist = np.linalg.norm(p - (p0 + t * (p1 - p0)))
            ref[y, x] = 0.8 * max(0.0, 1 - dist / r)
    assert np.allclose(full, ref, atol=1e-5)
    assert capsule_window(shape, (-50, -50), (-40, -45), 3.0) is None
    sw = stroke_weight_map(shape, [p0, p1, (35.0, 5.0)], r)
    assert sw.max() == pytest.approx(1.0, abs=0.05) and sw[0, 0] == 0


def test_max_tilt_and_brushed_basis():
    assert max_tilt(1.0) == 0.0 and max_tilt(0.5) == 0.0
    assert max_tilt(2.0) == pytest.approx(np.pi / 3)
    for ang in (0.0, 0.7, 2.5, -1.9):
        d = np.array([np.cos(ang), np.sin(ang)])
        r = quat_to_matrix(brushed_basis(d, fibre_length=1.5))
        assert np.degrees(np.arccos(r[2, 2])) == pytest.approx(np.degrees(np.arccos(1 / 1.5)), abs=1e-9)
        # the z axis leans toward the stroke, the tangent follows it
        assert r[:2, 2] @ d > 0 and r[:2, 0] @ d > 0
        assert abs(r[:2, 2] @ np.array([-d[1], d[0]])) < 1e-12


def test_brush_fibres_slerp_weights_and_purity():
    maps = flat_maps()
    before = maps.copy()
    p0, p1 = np.array([5.0, 20.0]), np.array([45.0, 20.0])
    out = brush_fibres(maps, p0, p1, radius=8.0, fibre_length=1.3)
    for name in ("kd", "ks", "sigma", "basis"):  # input untouched (undo = keep the old maps)
        assert np.array_equal(getattr(maps, name), getattr(before, name))
    assert out.kd is maps.kd and out.basis is not maps.basis
    target = brushed_basis(p1 - p0, 1.3)
    full = quat_angle(maps.basis[20, 20], target)
    # pixel centre (20.5, 20.5): distance 0.5 -> weight 1 - 0.5/8
    w = 1 - 0.5 / 8
    assert quat_angle(out.basis[20, 20], maps.basis[20, 20]) == pytest.approx(w * full, abs=1e-5)
    assert quat_angle(out.basis[20, 20], target) == pytest.approx((1 - w) * full, abs=1e-5)
    assert np.array_equal(out.basis[5], maps.basis[5])  # outside the radius
    stroke = brush_stroke(maps, [p0, (25.0, 20.0), p1], radius=8.0, fibre_length=1.3)
    assert quat_angle(stroke.basis[20, 30], target) < quat_angle(maps.basis[20, 30], target)


def test_brush_fibres_uses_symmetric_target():
    """A basis already equal to the target up to the x/y flip symmetry does not spin around."""
    d = np.array([1.0, 0.0])
    t = brushed_basis(d, 1.2)
    flipped = np.array([-t[3], t[2], -t[1], t[0]])
    maps = flat_maps(q=flipped)
    out = brush_fibres(maps, (5, 20), (45, 20), radius=8.0, fibre_length=1.2)
    assert quat_angle(out.basis[20, 20], flipped) < 1e-5


def test_recolor_smoothness_anisotropy_closed_forms():
    maps = flat_maps(8, 9)
    w = np.linspace(0, 1, 72).reshape(8, 9)
    rc = recolor(maps, kd=(0.0, 0.6, 0.1), weight=w)
    assert np.allclose(rc.kd[..., 1], 0.2 * (1 - w) + 0.6 * w, atol=1e-6) and rc.ks is maps.ks
    sm = smoothness(maps, 0.5, weight=w)
    assert np.allclose(sm.sigma, maps.sigma * 0.5 ** w[..., None], rtol=1e-6)
    an = anisotropy(maps, 0.25)
    assert np.allclose(an.sigma[..., 0], 0.3 * 0.25) and np.allclose(an.sigma[..., 1], 0.6)
    # smaller deviations give a sharper, higher specular peak (eq. 3.9 at the mirror direction)
    wdir = np.array([0.0, 0.0, 1.0])
    f0 = sggx_brdf(wdir, wdir, maps.kd[0, 0], maps.ks[0, 0], maps.sigma[0, 0], maps.basis[0, 0])
    f1 = sggx_brdf(wdir, wdir, maps.kd[0, 0], maps.ks[0, 0], sm.sigma[0, -1], sm.basis[0, -1])
    assert f1[0] > f0[0]
    be = brush_edit(maps, (0.0, 4.0), (9.0, 4.0), 3.0, kd=(1.0, 0.0, 0.0), anisotropy_factor=0.5)
    assert be.kd[4, 4, 0] == pytest.approx(0.2 * (1 / 6) + 1.0 * (5 / 6), abs=1e-5)
    assert be.sigma[4, 4, 0] == pytest.approx(0.3 * 0.5 ** (5 / 6), rel=1e-5)
    assert np.array_equal(be.kd[0], maps.kd[0]) and be.basis is maps.basis


def test_repeated_smoothness_and_anisotropy_keep_sigma_in_the_fitters_range():
    """Each stroke segment multiplies sigma again: one back-and-forth stroke (60 segments) at factor 0.1 took it to 0
    (maps the add-on's own import then refused), at 2.0 to 5.7e17. It stays within 0.01-10, the fitter's range."""
    from material_structures.core.fabric.levenberg_marquardt import LOG_SIGMA_MAX, LOG_SIGMA_MIN
    from material_structures.core.fabric.parameter_maps import SIGMA_RANGE

    assert SIGMA_RANGE == pytest.approx((0.01, 10.0)) == (np.exp(LOG_SIGMA_MIN), np.exp(LOG_SIGMA_MAX))
    for factor, bound in ((0.1, 0.01), (2.0, 10.0)):
        maps = flat_maps(8, 9)
        for _ in range(60):
            maps = smoothness(maps, factor)
        np.testing.assert_allclose(maps.sigma, bound, rtol=1e-6)
    maps = flat_maps(8, 9)
    for _ in range(60):
        maps = anisotropy(maps, 0.1)
    assert maps.sigma[..., 0].min() == pytest.approx(0.01, rel=1e-6) and np.allclose(maps.sigma[..., 1], 0.6)
    # maps from elsewhere, sigma 20 (outside the range): texels the brush does not touch (weight 0) keep their
    # values; touched ones move with the stroke toward the range, not away from it, and do not jump into it (a
    # smoothing stroke at 0.9 clamped 20 to 10)
    wide = flat_maps(8, 9).replace(sigma=np.full((8, 9, 2), 20.0, np.float32))
    w = np.zeros((8, 9))
    w[2:4, 2:4] = 1.0
    for edit in (lambda m: smoothness(m, 0.9, weight=w), lambda m: anisotropy(m, 0.9, weight=w)):
        out = edit(wide)
        assert np.all(out.sigma[w == 0] == 20.0)
        np.testing.assert_allclose(out.sigma[w > 0].min(axis=-1), 18.0, rtol=1e-6)
    for edit in (lambda m: smoothness(m, 1.5, weight=w), lambda m: anisotropy(m, 1.5, weight=w)):
        assert np.all(edit(wide).sigma == 20.0)  # away from the range: held where it was
    low = wide.replace(sigma=np.full((8, 9, 2), 0.005, np.float32))
    np.testing.assert_allclose(smoothness(low, 1.5, weight=w).sigma[w > 0], 0.0075, rtol=1e-6)
    assert np.all(smoothness(low, 0.5, weight=w).sigma == np.float32(0.005))


def test_data_driven_states_blend_by_direction():
    states = []
    for k in range(8):
        q = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(np.radians(45 * k) * 0.5))
        states.append(make_maps(np.full((4, 4, 3), 0.1 * k), np.full((4, 4, 3), 0.5),
                                np.full((4, 4, 2), 0.2 + 0.05 * k), np.tile(q, (4, 4, 1))))
    bs = BrushStates(tuple(states))
    maps = flat_maps(20, 20)
    # stroke toward 90 degrees (+y): state 2 exactly, full weight on the centre line
    out = brush_data_driven(maps, (10.5, 2.0), (10.5, 18.0), 5.0, bs)
    assert out.kd[10, 10] == pytest.approx([0.2, 0.2, 0.2], abs=1e-6)
    assert out.sigma[10, 10] == pytest.approx([0.3, 0.3], abs=1e-6)
    assert quat_angle(out.basis[10, 10], states[2].basis[0, 0]) < 1e-4
    # 22.5 degrees: halfway between states 0 and 1
    d = np.array([np.cos(np.radians(22.5)), np.sin(np.radians(22.5))])
    blend = bs.blend(d, np.arange(2), np.arange(3))
    assert np.allclose(blend.kd, 0.05) and np.allclose(blend.sigma, 0.225)
    assert quat_angle(blend.basis[0, 0], states[1].basis[0, 0]) == pytest.approx(np.radians(22.5 / 2), abs=1e-5)
    with pytest.raises(ValueError, match="8 states"):
        BrushStates(tuple(states[:7]))


def test_model_and_brushing_import_without_scipy():
    """The Blender side (model, parameter maps, brushing) must not need scipy."""
    import subprocess
    import sys

    code = ("import sys, material_structures.core.fabric as f; f.brush_fibres; f.sggx_brdf; f.load_params; "
            "sys.exit(1 if 'scipy' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
