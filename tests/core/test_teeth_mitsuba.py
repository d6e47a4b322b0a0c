"""Cross-check of the forward renderer against Mitsuba 3 (scalar_rgb, volpath) on a full tooth scene.

The two renderers agree exactly in model when the boundaries are index-matched (eta = 1, a_t = 1:
Mitsuba ``null`` BSDF interfaces) and the enamel/dentin blend is sharp (spread -> 0): enamel and
dentin media with two-lobe HG phase functions (Mitsuba ``blendphase``), gums, a Lambertian oral-cavity
proxy (``twosided diffuse``) and point lights. Compared per channel: the whole-image mean (2 %) and
the mean over the tooth pixels (within the Monte Carlo error of both renderers + 1 %), for a fixed
depth of 60 and for the all-bounce Russian-roulette estimator.
"""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Camera, PointLight
from material_structures.core.teeth.mesh import save_mesh
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import VolumeMaterial
from material_structures.core.teeth.synthetic import make_scene, scene_target, tooth_masks

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`

mi = pytest.importorskip("mitsuba")


def _scene():
    sc = make_scene(n_teeth=1, resolution=16)
    t = sc.teeth[0]
    t.eta, sc.gums.eta = 1.0, 1.0
    t.a_t[:] = 1.0
    sc.gums.a_t[:] = 1.0
    t.enamel = VolumeMaterial([0.7, 0.9, 1.2], [0.85, 0.8, 0.75], 0.6, -0.2, 0.8)
    t.dentin = VolumeMaterial([2.0, 2.4, 3.0], [0.8, 0.7, 0.55], 0.4, -0.1, 0.7)
    sc.gums.material = VolumeMaterial([1.5, 2.5, 2.5], [0.7, 0.45, 0.4], 0.7, -0.1, 0.9)
    sc.blend_spread = 1e-5  # sharp enamel/dentin interface, as in Mitsuba
    tgt = scene_target(sc)
    cam = Camera.look_at(tgt + [40.0, 290.0, 35.0], tgt, (0, 0, 1), 3.6, 24, 18)
    lights = [PointLight(tgt + [300.0, 900.0, 400.0], [1.0e6, 1.0e6, 1.0e6]),
              PointLight(tgt + [-700.0, 600.0, -100.0], [0.8e6, 1.1e6, 1.3e6])]
    return sc, cam, lights


def _medium(m: VolumeMaterial) -> dict:
    smax = float(m.sigma_t.max())  # Mitsuba's RGB values must be <= 1: scale them
    return {"type": "homogeneous", "sigma_t": {"type": "rgb", "value": (m.sigma_t / smax).tolist()}, "scale": smax,
            "albedo": {"type": "rgb", "value": m.albedo.tolist()},
            "phase": {"type": "blendphase", "weight": m.beta,
                      "phase1": {"type": "hg", "g": m.g2}, "phase2": {"type": "hg", "g": m.g1}}}


def _mitsuba_render(sc, cam: Camera, light: PointLight, spp: int, tmp, seed: int = 0) -> np.ndarray:
    mi.set_variant("scalar_rgb")
    t = sc.teeth[0]
    paths = {}
    for name, mesh in (("enamel", t.enamel_mesh), ("dentin", t.dentin_shape.mesh(t.c)), ("gums", sc.gums.mesh),
                       ("cavity", sc.cavity.mesh)):
        paths[name] = str(tmp / f"{name}.ply")
        save_mesh(type(mesh)(mesh.vertices, mesh.faces), paths[name])
    enamel, dentin, gums = _medium(t.enamel), _medium(t.dentin), _medium(sc.gums.material)
    eye = cam.center
    fwd = cam.R[2]
    up = -cam.R[1]
    fov = float(np.degrees(2 * np.arctan(0.5 * cam.width / cam.K[0, 0])))
    scene = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": -1, "rr_depth": 1000},
        "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x",
                   "to_world": mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=(eye + fwd).tolist(),
                                                              up=up.tolist()),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"}},
        "enamel": {"type": "ply", "filename": paths["enamel"], "face_normals": True, "bsdf": {"type": "null"},
                   "interior": enamel},
        "dentin": {"type": "ply", "filename": paths["dentin"], "face_normals": True, "bsdf": {"type": "null"},
                   "interior": dentin, "exterior": enamel},
        "gums": {"type": "ply", "filename": paths["gums"], "face_normals": True, "bsdf": {"type": "null"},
                 "interior": gums},
        "cavity": {"type": "ply", "filename": paths["cavity"], "face_normals": True,
                   "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance":
                                                         {"type": "rgb", "value": sc.cavity.albedo.tolist()}}}},
        "light": {"type": "point", "position": light.position.tolist(),
                  "intensity": {"type": "rgb", "value": light.intensity.tolist()}},
    }
    img = np.array(mi.render(mi.load_dict(scene), spp=spp, seed=seed))
    return img[:, :, :3]


@pytest.fixture(scope="module")
def mitsuba_refs(tmp_path_factory):
    """The scene, its tooth mask and per light three Mitsuba ``volpath`` renders with all bounces
    (``max_depth: -1``) at 256 spp, seeds 0-2."""
    sc, cam, lights = _scene()
    mask = tooth_masks(sc, [cam])[0]
    tmp = tmp_path_factory.mktemp("mitsuba")
    refs = [[_mitsuba_render(sc, cam, light, 256, tmp, seed=s) for s in range(3)] for light in lights]
    return sc, cam, lights, mask, refs


def _tooth_mean(imgs: list[np.ndarray], mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the mean over the tooth pixels of the seeds' mean image, and its standard error
    from the per-pixel variance over the seeds (pixels are independent estimates: this pools
    n_pixels x (n_seeds - 1) degrees of freedom instead of the n_seeds - 1 of the seeds' means)."""
    v = np.array([m[mask] for m in imgs])  # (seeds, pixels, 3)
    return v.mean(axis=(0, 1)), np.sqrt(v.var(axis=0, ddof=1).sum(axis=0) / len(v)) / v.shape[1]


def _compare(mine: list[np.ndarray], ref: list[np.ndarray], mask: np.ndarray, what) -> None:
    # whole image (lit oral-cavity walls, gums, tooth) per channel
    np.testing.assert_allclose(np.mean(mine, axis=0).mean((0, 1)), np.mean(ref, axis=0).mean((0, 1)), rtol=0.02)
    # the tooth pixels: agreement within the Monte Carlo error of both renderers + 1 %
    a, sa = _tooth_mean(mine, mask)
    b, sb = _tooth_mean(ref, mask)
    se = np.hypot(sa, sb)
    assert np.all(np.abs(a - b) < 4 * se + 0.01 * b), (what, a, b, se)


def test_full_tooth_matches_mitsuba(mitsuba_refs):
    """Fixed depth 60 (practically all bounces for these albedos) against Mitsuba with all bounces."""
    sc, cam, lights, mask, refs = mitsuba_refs
    assert mask.sum() > 40
    for k, light in enumerate(lights):
        mine = [render(sc, [cam], [light], RenderSettings(spp=32, max_depth=60, seed=10 * k + s)).images[0, 0]
                for s in range(3)]
        _compare(mine, refs[k], mask, ("depth 60", k))


def test_defaults_render_all_bounces_like_mitsuba(mitsuba_refs, tracer):
    """``render`` at its defaults (Russian roulette, all bounces) against Mitsuba ``volpath``
    ``max_depth: -1``, the compiled tracer and the numpy reference. (The same comparison at max_depth 6
    fails by 6-17 % per channel, see docs/teeth-tracer.md.)"""
    sc, cam, lights, mask, refs = mitsuba_refs
    for k, light in enumerate(lights):
        res = [render(sc, [cam], [light], RenderSettings(spp=32, seed=100 + 10 * k + s), reference=tracer.reference)
               for s in range(3)]
        assert all(r.stats["capped_paths"] == 0 for r in res)
        _compare([r.images[0, 0] for r in res], refs[k], mask, ("roulette", k))


def _refractive_scene(eta: float):
    """The test scene with thin dielectric boundaries: the tooth at ``eta`` with a_t (0.9, 0.85, 0.8), the gums at
    eta 1.4 with a_t 0.95."""
    sc, cam, lights = _scene()
    t = sc.teeth[0]
    t.eta, sc.gums.eta = eta, 1.4
    t.a_t[:] = [0.9, 0.85, 0.8]
    sc.gums.a_t[:] = 0.95
    return sc, cam, lights


def test_thin_dielectric_boundaries_match_mitsuba(tracer):
    """The Fresnel boundaries of eq. 5.1-5.2 (reflect with F, else straight on with weight a_t) against Mitsuba
    ``volpath`` with all bounces through the ``teeth_thin_boundary`` plugin (``mitsuba_capture``), at
    ``render``'s defaults. Measured: tooth means within 0.2-1.4 % (|diff| / tolerance <= 0.22); a plugin whose
    shadow rays ignore the Fresnel factor fails it."""
    sc, cam, lights = _refractive_scene(1.5)
    _compare_with_mitsuba(sc, cam, lights, tracer, "thin boundaries")


def _compare_with_mitsuba(sc, cam, lights, tracer, what: str) -> None:
    """``_compare`` of this tracer (3 seeds at 64 spp, the numpy reference at 32) with Mitsuba (3 seeds at 256 spp)
    for each light; no pixel of this tracer above 50 times Mitsuba's brightest."""
    from material_structures.core.teeth.mitsuba_capture import render_capture_mitsuba

    mask = tooth_masks(sc, [cam])[0]
    assert mask.sum() > 40
    caps = [render_capture_mitsuba(sc, [cam], lights, spp=256, seed=s) for s in range(3)]
    for k, light in enumerate(lights):
        ref = [c.images[0, k].astype(np.float64) for c in caps]
        mine = [render(sc, [cam], [light], RenderSettings(spp=32 if tracer.reference else 64, seed=10 * k + s),
                       reference=tracer.reference).images[0, 0] for s in range(3)]
        assert np.max(mine) < 50 * np.max(ref), (what, k)  # no path weighted by exp(+sigma d)
        _compare(mine, ref, mask, (what, k))


def test_a_tooth_rooted_in_the_gums_matches_mitsuba(tracer):
    """Overlapping volumes, as in a smile (each root inside the gums): a path that crossed the gums' surface
    from inside a tooth is in the air by the last surface it crossed, and may then cross the dentin's
    index-matched surface into the dentin. Both renderers follow the last surface crossed (Mitsuba: a shape's
    interior medium when entered, its exterior when left), so they must agree. Before that flight was sampled
    as one in a medium, its pdf counted the dentin's attenuation while its value did not: tooth pixels of a
    smile reached 1e8."""
    from material_structures.core.teeth.synthetic import box_mesh

    sc, cam, lights = _refractive_scene(1.5)
    lo, hi = sc.gums.mesh.vertices.min(axis=0), sc.gums.mesh.vertices.max(axis=0)
    sc.gums.mesh = box_mesh((lo[0], lo[1], lo[2]), (hi[0], hi[1], 2.5))  # over the bottom 4.3 mm of the tooth
    dentin_z = sc.teeth[0].dentin_vertices()[:, 2]
    assert dentin_z.min() < 2.5 < dentin_z.max()  # the gums' surface cuts the dentin
    _compare_with_mitsuba(sc, cam, lights, tracer, "rooted in the gums")


def test_a_tooth_cut_out_of_the_gums_matches_mitsuba(tracer):
    """The smile's gums now (``arch.gums_around_teeth``): the same box of gums with the tooth cut out of it and a
    0.05 mm film of air between them, so no volumes overlap: a path leaves the gums through the hole's wall, crosses
    the film and enters the enamel. Both renderers see nested surfaces only and must agree."""
    from material_structures.core.teeth.arch import gums_around_teeth
    from material_structures.core.teeth.synthetic import box_mesh

    sc, cam, lights = _refractive_scene(1.5)
    lo, hi = sc.gums.mesh.vertices.min(axis=0), sc.gums.mesh.vertices.max(axis=0)
    box = box_mesh((lo[0], lo[1], lo[2]), (hi[0], hi[1], 2.5))
    sc.gums.mesh = gums_around_teeth(box, [sc.teeth[0].enamel_mesh])
    assert sc.gums.mesh.volume() < box.volume() - 1.0  # the root's volume is gone from the gums
    _compare_with_mitsuba(sc, cam, lights, tracer, "cut out of the gums")

