"""Synthetic ground truth: a small jaw section (teeth on a gum ridge in front of an oral-cavity
proxy), tooth masks, and perturbed starting points. Used by tests, ``teeth synth`` and benchmarks.
"""

from __future__ import annotations

import numpy as np

from .capture import Camera
from .compiled_scene import KIND_DIELECTRIC, CompiledScene
from .mesh import TriMesh
from .scene import Gums, OralCavity, TeethScene, Tooth, VolumeMaterial
from .tooth_mesh import make_tooth

GROUND_TRUTH = {
    "enamel": VolumeMaterial([0.9, 1.1, 1.4], [0.97, 0.96, 0.94], 0.6, -0.2, 0.85),
    "dentin": VolumeMaterial([2.2, 2.6, 3.2], [0.93, 0.85, 0.72], 0.5, -0.1, 0.8),
    "gums": VolumeMaterial([1.5, 2.5, 2.5], [0.9, 0.55, 0.5], 0.7, -0.1, 0.9),
    "cavity_albedo": np.array([0.35, 0.12, 0.1]),
}


def _rot_z(deg: float, tx: float, ty: float = 0.0, tz: float = 0.0) -> np.ndarray:
    r = np.radians(deg)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]]
    m[:3, 3] = (tx, ty, tz)
    return m


def box_mesh(lo, hi, inward: bool = False) -> TriMesh:
    """Axis-aligned closed box with per-face planar UVs (outward normals unless ``inward``)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces, uv = [], []
    for q in quads:
        faces += [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
        uv += [((0, 0), (1, 0), (1, 1)), ((0, 0), (1, 1), (0, 1))]
    f = np.array(faces)
    m = TriMesh(v, f, np.array(uv, dtype=np.float64))
    if (m.volume() < 0) != inward:
        m = TriMesh(v, f[:, [0, 2, 1]], m.corner_uv[:, [0, 2, 1]])
    return m


def cavity_proxy(x_half: float = 22.0, y_back: float = -14.0, y_front: float = 4.0, z_lo: float = -10.0,
                 z_hi: float = 18.0) -> TriMesh:
    """Open box (back, floor, ceiling and side walls) behind the teeth, normals facing inwards."""
    box = box_mesh((-x_half, y_back, z_lo), (x_half, y_front, z_hi), inward=True)
    c = box.triangles().mean(axis=1)
    keep = c[:, 1] < y_front - 1e-9  # drop the front face (the mouth opening)
    return TriMesh(box.vertices, box.faces[keep], None)


def make_scene(n_teeth: int = 2, resolution: int = 32, with_gums: bool = True, with_cavity: bool = True,
               a_t: float = 0.95) -> TeethScene:
    """Ground-truth scene: ``n_teeth`` teeth (incisor, canine, premolar, molar, ...) in a row."""
    kinds = ["incisor", "canine", "premolar", "molar"]
    c_true = [np.array([0.2, -0.15, 0.1]), np.array([-0.1, 0.2, -0.2]), np.array([0.1, 0.1, 0.1]),
              np.array([0.0, -0.1, 0.15])]
    teeth = []
    x = -4.3 * (n_teeth - 1)
    for i in range(n_teeth):
        kind = kinds[i % 4]
        geo = make_tooth(kind, resolution=resolution)
        width = float(np.max(geo.enamel.vertices[:, 0]) - np.min(geo.enamel.vertices[:, 0]))
        if i > 0:
            x += 0.5 * width + 0.15
        geo = geo.transformed(_rot_z(12.0 * i, x, -0.6 * i))
        x += 0.5 * width + 0.15
        teeth.append(Tooth(f"tooth{i}", geo.enamel, geo.dentin, GROUND_TRUTH["enamel"], GROUND_TRUTH["dentin"],
                           np.full((1, 1, 3), a_t), c_true[i % 4], kind=kind))
    lo = np.min([t.enamel_mesh.vertices.min(axis=0) for t in teeth], axis=0)
    hi = np.max([t.enamel_mesh.vertices.max(axis=0) for t in teeth], axis=0)
    gums = None
    if with_gums:
        gums = Gums(box_mesh((lo[0] - 3.0, lo[1] - 1.0, lo[2] - 6.0), (hi[0] + 3.0, hi[1] + 1.0, lo[2] - 0.1)),
                    GROUND_TRUTH["gums"], np.full((1, 1, 3), 0.9))
    cavity = OralCavity(cavity_proxy(), GROUND_TRUTH["cavity_albedo"]) if with_cavity else None
    return TeethScene(teeth, gums, cavity)


def scene_target(scene: TeethScene) -> np.ndarray:
    v = np.concatenate([t.enamel_mesh.vertices for t in scene.teeth])
    return 0.5 * (v.min(axis=0) + v.max(axis=0))


_PROBES = ((0.5, 0.5), (0.02, 0.02), (0.98, 0.02), (0.02, 0.98), (0.98, 0.98))  # a pixel's centre and corners


def _probe_teeth(cs: CompiledScene, n_teeth: int, cam: Camera):
    """Per sub-pixel probe (``_PROBES``): the index of the tooth whose enamel the probe sees first, -1 where it
    sees no tooth first, (H * W,) each."""
    jj, ii = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    for dx, dy in _PROBES:
        o, d = cam.rays(jj.ravel() + dx, ii.ravel() + dy)
        tri, _ = cs.caster.first_hit(o, d)
        t = np.maximum(tri, 0)
        yield np.where((tri >= 0) & (cs.kind[t] == KIND_DIELECTRIC) & (cs.tex_id[t] < n_teeth), cs.tex_id[t], -1)


def tooth_masks(scene: TeethScene, cameras: list[Camera], compiled: CompiledScene | None = None) -> np.ndarray:
    """(n_cam, H, W) bool: pixels whose centre and four corners all see a tooth's enamel first."""
    cs = compiled or CompiledScene(scene)
    out = []
    for cam in cameras:
        ok = np.ones(cam.height * cam.width, dtype=bool)
        for tid in _probe_teeth(cs, len(scene.teeth), cam):
            ok &= tid >= 0
        out.append(ok.reshape(cam.height, cam.width))
    return np.array(out)


def tooth_regions(scene: TeethScene, cam: Camera, compiled: CompiledScene | None = None) -> np.ndarray:
    """(H, W) int: the index of the tooth whose enamel the pixel's centre and four corners all see first, -1
    elsewhere (per-tooth means of a render)."""
    cs = compiled or CompiledScene(scene)
    region = None
    for tid in _probe_teeth(cs, len(scene.teeth), cam):
        region = tid if region is None else np.where(region == tid, region, -1)
    return region.reshape(cam.height, cam.width)


def render_capture(scene: TeethScene, cameras: list[Camera], lights: list, spp: int = 16,
                   spp_background: int = 2, seed: int = 12345, max_depth: int | None = None, progress=None,
                   workers: int = 1):
    """Synthetic capture of ``scene``: masked tooth pixels at ``spp``, the rest at ``spp_background``;
    ``workers`` processes trace each batch of lights (same images up to floating-point summation order)."""
    from .capture import Capture
    from .path_tracer import RenderSettings, render

    cs = CompiledScene(scene)
    masks = tooth_masks(scene, cameras, cs)
    h, w = cameras[0].height, cameras[0].width
    images = np.zeros((len(cameras), len(lights), h, w, 3))
    for part, (sel, n) in enumerate(((True, spp), (False, spp_background))):
        if n <= 0:
            continue
        pixels = [np.flatnonzero(m.ravel() == sel) for m in masks]
        for k, l0 in enumerate(range(0, len(lights), 9)):
            ids = np.arange(l0, min(l0 + 9, len(lights)))
            res = render(scene, cameras, lights, RenderSettings(n, max_depth, seed + 1000 * part + k, workers=workers),
                         pixels=pixels, light_ids=ids, compiled=cs)
            images[:, ids] += res.images
            if progress is not None:
                progress(len(ids))
    return Capture(cameras, lights, images.astype(np.float32), masks)


def perturbed_start(scene: TeethScene, seed: int = 0, sigma_factor: float = 0.3, kappa_shift: float = 0.25,
                    reset_c: bool = True) -> TeethScene:
    """Start point for recovery tests: sigma_t scaled by exp(+-sigma_factor), kappa shifted by
    +-kappa_shift (random signs per channel), dentin coefficients reset to 0."""
    from .parameterisation import albedo_from_kappa, kappa_from_albedo
    from .scene import VolumeMaterial

    rng = np.random.default_rng(seed)
    out = scene.copy()

    def perturb(m: VolumeMaterial) -> VolumeMaterial:
        s = m.sigma_t * np.exp(sigma_factor * rng.choice([-1.0, 1.0], 3))
        a = albedo_from_kappa(kappa_from_albedo(m.albedo) + kappa_shift * rng.choice([-1.0, 1.0], 3))
        return VolumeMaterial(s, a, m.g1, m.g2, m.beta)

    for t in out.teeth:
        t.enamel = perturb(t.enamel)
        t.dentin = perturb(t.dentin)
        if reset_c:
            t.c = np.zeros(3)
    return out
