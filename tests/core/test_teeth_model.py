"""Scene model pieces: procedural meshes, blend shapes (eq. 5.5), phase function (eq. 5.4), Fresnel
weights, a_t texture lookup, serialisation and the capture dataset format."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.integrate import quad

from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.enamel_transmission import lookup_a_t
from material_structures.core.teeth.mesh import load_mesh, save_mesh
from material_structures.core.teeth.phase_function import hg, sample_two_lobe, two_lobe
from material_structures.core.teeth.scene import TeethScene
from material_structures.core.teeth.synthetic import make_scene
from material_structures.core.teeth.tooth_mesh import TOOTH_TYPES, make_tooth


@pytest.mark.parametrize("kind", TOOTH_TYPES)
def test_tooth_mesh_watertight_dentin_inside(kind):
    geo = make_tooth(kind, resolution=20)
    assert geo.enamel.is_watertight() and geo.dentin.base.is_watertight()
    assert geo.enamel.corner_uv is not None and np.all((geo.enamel.corner_uv >= 0) & (geo.enamel.corner_uv <= 1))
    # the volume agrees with trimesh's (independent) computation, and is a plausible crown size
    tm = trimesh.Trimesh(geo.enamel.vertices, geo.enamel.faces, process=False)
    assert geo.enamel.volume() == pytest.approx(tm.volume, rel=1e-9)
    assert 150 < geo.enamel.volume() < 900  # mm^3
    te = trimesh.Trimesh(geo.enamel.vertices, geo.enamel.faces)
    for c in (np.zeros(3), np.full(3, 0.5), np.full(3, -0.5)):
        assert te.contains(geo.dentin.vertices(c)).all()


def test_blend_shape_linear_model():
    geo = make_tooth("incisor", resolution=16)
    c = np.array([0.3, -0.2, 0.5])
    v = geo.dentin.vertices(c)
    expect = geo.dentin.base.vertices + sum(c[k] * (geo.dentin.mode_mesh(k).vertices - geo.dentin.base.vertices)
                                            for k in range(3))
    np.testing.assert_allclose(v, expect, atol=1e-12)
    # modes move the crown along their axes: buccal widens y, proximal x, occlusal raises the top
    b0 = geo.dentin.base.vertices
    ext = [np.ptp(geo.dentin.mode_mesh(k).vertices[:, k2]) - np.ptp(b0[:, k2]) for k, k2 in ((0, 1), (1, 0))]
    assert ext[0] > 1.0 and ext[1] > 1.0
    assert geo.dentin.mode_mesh(2).vertices[:, 2].max() == pytest.approx(b0[:, 2].max() + 1.0, abs=1e-9)


def test_two_lobe_phase_normalised_and_sampled():
    g1, g2, beta = 0.7, -0.3, 0.6
    total, _ = quad(lambda mu: 2 * np.pi * two_lobe(mu, g1, g2, beta), -1, 1)
    assert total == pytest.approx(1.0, abs=1e-9)
    mean_mu, _ = quad(lambda mu: 2 * np.pi * mu * two_lobe(mu, g1, g2, beta), -1, 1)
    assert mean_mu == pytest.approx(beta * g1 + (1 - beta) * g2, abs=1e-9)
    rng = np.random.default_rng(0)
    d = np.tile([0.0, 0.0, 1.0], (200000, 1))
    out, mu = sample_two_lobe(d, g1, g2, beta, rng.random((200000, 3)))
    np.testing.assert_allclose(out[:, 2], mu, atol=1e-12)
    assert mu.mean() == pytest.approx(beta * g1 + (1 - beta) * g2, abs=5 * mu.std() / np.sqrt(len(mu)))
    hist, edges = np.histogram(mu, bins=20, range=(-1, 1), density=True)
    centers = 0.5 * (edges[1:] + edges[:-1])
    ref = np.array([quad(lambda m: 2 * np.pi * two_lobe(m, g1, g2, beta), a, b)[0] / (b - a)
                    for a, b in zip(edges[:-1], edges[1:], strict=True)])
    assert np.max(np.abs(hist - ref) / ref) < 0.05, centers
    assert hg(np.array([1.0]), 0.0)[0] == pytest.approx(1 / (4 * np.pi))


def test_a_t_bilinear_lookup():
    tex = np.zeros((2, 4, 3))
    tex[..., 0] = np.arange(8).reshape(2, 4)
    tex[..., 1] = 1.0
    uv = np.array([[0.125, 0.25], [0.25, 0.25], [0.125, 0.5], [0.0, 0.25]])
    vals, _, w = lookup_a_t(tex, uv)
    np.testing.assert_allclose(vals[:, 0], [0.0, 0.5, 2.0, 1.5])  # last: wraps between col 3 and col 0
    np.testing.assert_allclose(vals[:, 1], 1.0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)


def test_scene_json_roundtrip_and_mesh_io(tmp_path):
    sc = make_scene(n_teeth=2, resolution=12)
    sc2 = TeethScene.from_dict(sc.to_dict())
    for t, t2 in zip(sc.teeth, sc2.teeth, strict=True):
        np.testing.assert_allclose(t.dentin_vertices(), t2.dentin_vertices(), atol=1e-8)
        np.testing.assert_allclose(t.enamel.sigma_t, t2.enamel.sigma_t)
    geo = make_tooth("molar", resolution=12)
    for ext in ("ply", "obj"):
        p = tmp_path / f"m.{ext}"
        save_mesh(geo.enamel, p)
        m = load_mesh(p)
        assert m.volume() == pytest.approx(geo.enamel.volume(), rel=1e-6)
    with pytest.raises(FileNotFoundError):
        load_mesh(tmp_path / "missing.ply")


def test_capture_folder_roundtrip(tmp_path):
    cams, lights = default_rig(width=8, height=6)
    assert len(cams) == 3 and len(lights) == 54
    # every light is about 1 m away and in front of the mouth (+y)
    pos = np.array([li.position for li in lights])
    assert np.all(pos[:, 1] > 0) and np.allclose(np.linalg.norm(pos - [0, 0, 5], axis=1), 1000.0)
    # the rig's cameras project the target to the image centre
    for c in cams:
        np.testing.assert_allclose(c.project(np.array([[0.0, 0.0, 5.0]]))[0], [4.0, 3.0], atol=1e-9)
    rng = np.random.default_rng(1)
    images = rng.random((3, 54, 6, 8, 3)).astype(np.float32)
    masks = rng.random((3, 6, 8)) > 0.5
    Capture(cams, lights, images, masks).save(tmp_path)
    cap = Capture.load(tmp_path)
    np.testing.assert_array_equal(cap.images, images)
    np.testing.assert_array_equal(cap.masks, masks)
    np.testing.assert_allclose(cap.cameras[2].K, cams[2].K)
    with pytest.raises(FileNotFoundError):
        Capture.load(tmp_path / "nope")


def test_optimiser_bounds_are_the_valid_ranges():
    """Clipping the optimiser variables to ``optimiser_bounds`` is the projection onto the valid ranges: the
    bounds map to the ranges' ends, a clipped variable maps to the same (clamped) parameters as the
    unclipped one, and inside the bounds the map is exactly invertible (no clamp acts)."""
    from material_structures.core.teeth.param_vector import (
        RANGES,
        ParamLayout,
        from_optimiser,
        optimiser_bounds,
        to_optimiser,
    )

    scene = make_scene(n_teeth=1, resolution=8)
    lay = ParamLayout(scene)
    lo, hi = optimiser_bounds(lay)
    kinds = lay.kinds()
    ends = np.array([RANGES[k] for k in kinds])
    x_lo, x_hi = from_optimiser(lo, lay), from_optimiser(hi, lay)
    flip = kinds == "albedo"  # kappa = log10(1 - albedo) decreases with the albedo
    np.testing.assert_allclose(np.where(flip, x_hi, x_lo), ends[:, 0], rtol=1e-9)
    np.testing.assert_allclose(np.where(flip, x_lo, x_hi), ends[:, 1], rtol=1e-9)
    rng = np.random.default_rng(8)
    y = lo + (hi - lo) * rng.uniform(-0.5, 1.5, size=lay.size)  # a third of them outside
    yc = np.clip(y, lo, hi)
    assert np.any(yc != y)
    np.testing.assert_allclose(from_optimiser(yc, lay), from_optimiser(y, lay), rtol=1e-12)
    np.testing.assert_allclose(to_optimiser(from_optimiser(yc, lay), lay), yc, rtol=1e-9, atol=1e-9)


def test_tooth_forward_lobe_keeps_to_the_literature_range():
    """g1 of enamel and dentin is bounded by the literature's range (0.3-0.9, the span of the literature
    search's g values); the gums' g1 keeps the phase function's range. A step past the bound lands on it."""
    from material_structures.core.teeth.literature_init import G_VALUES
    from material_structures.core.teeth.param_vector import (
        RANGES,
        TOOTH_G1_RANGE,
        ParamLayout,
        from_optimiser,
        optimiser_bounds,
        scene_to_vector,
        to_optimiser,
    )

    scene = make_scene(n_teeth=2, resolution=8)
    lay = ParamLayout(scene)
    assert TOOTH_G1_RANGE == (0.3, 0.9)
    assert (min(G_VALUES), max(G_VALUES)) == TOOTH_G1_RANGE
    lo, hi = optimiser_bounds(lay)
    for t in scene.teeth:
        for part in ("enamel", "dentin"):
            e = lay[f"{t.name}.{part}.g1"]
            assert e.kind == "tooth_g1"
            assert (lo[e.start], hi[e.start]) == TOOTH_G1_RANGE
    if scene.gums is not None:
        e = lay["gums.g1"]
        assert (lo[e.start], hi[e.start]) == RANGES["g"] and RANGES["g"][0] < 0.0
    x = scene_to_vector(scene, lay)
    y = to_optimiser(x, lay)
    i = lay["tooth0.dentin.g1"].start
    y[i] = 0.1  # a step below the literature's range
    assert from_optimiser(y, lay)[i] == 0.3
