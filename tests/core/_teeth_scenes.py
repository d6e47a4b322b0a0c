"""Small scenes shared by the teeth tests (not a test module)."""

from __future__ import annotations

import numpy as np

from material_structures.core.teeth.capture import Camera, PointLight
from material_structures.core.teeth.dentin_blend_shapes import DentinBlendShape
from material_structures.core.teeth.mesh import TriMesh
from material_structures.core.teeth.scene import OralCavity, TeethScene, Tooth, VolumeMaterial
from material_structures.core.teeth.synthetic import box_mesh


def slab_scene(sigma_t, albedo, thickness=2.0, a_t=0.9, g1=0.5, g2=-0.3, beta=0.7, floor_albedo=None):
    """A 100 x 100 mm slab z in [0, thickness] with a tiny far-away dentin core; optional floor at z=-5."""
    slab = box_mesh((-50, -50, 0), (50, 50, thickness))
    core = box_mesh((40, 40, 0.4 * thickness), (40.2, 40.2, 0.6 * thickness))
    dentin = DentinBlendShape(core, np.zeros((3, len(core.vertices), 3)))
    mat = VolumeMaterial(sigma_t, albedo, g1, g2, beta)
    tooth = Tooth("slab", slab, dentin, mat, VolumeMaterial(3.0, 0.5), np.full((1, 1, 3), a_t))
    cavity = None
    if floor_albedo is not None:
        floor = TriMesh([[-400, -400, -5], [400, -400, -5], [400, 400, -5], [-400, 400, -5]], [[0, 1, 2], [0, 2, 3]])
        cavity = OralCavity(floor, floor_albedo)
    return TeethScene([tooth], None, cavity)


def down_camera(width=16, height=16, fov=4.0, eye=(0.0, 0.0, 300.0), target=(0.0, 0.0, 0.0)):
    return Camera.look_at(eye, target, (0, 1, 0), fov, width, height)


def light(pos, intensity=1.0e5):
    return PointLight(pos, np.full(3, intensity))


def slab_fit_problem(size: int, capture_spp: int, start_enamel: VolumeMaterial, max_depth: int = 6):
    """A slab over a floor seen by one size x size camera under 3 lights: (start scene, capture of the
    truth at ``capture_spp``, no mask) with the start's enamel ``start_enamel``."""
    from material_structures.core.teeth.capture import Capture
    from material_structures.core.teeth.path_tracer import RenderSettings, render

    truth = slab_scene([1.0, 1.3, 1.7], [0.95, 0.9, 0.8], floor_albedo=[0.4, 0.3, 0.2])
    cams = [down_camera(size, size, fov=6.0)]
    lights = [light((60.0 * np.cos(a), 60.0 * np.sin(a), 200.0)) for a in (0.0, 2.1, 4.2)]
    img = render(truth, cams, lights, RenderSettings(capture_spp, max_depth, 999)).images
    cap = Capture(cams, lights, img.astype(np.float32), np.ones((1, size, size), dtype=bool))
    start = truth.copy()
    start.teeth[0].enamel = start_enamel
    return start, cap


def brute_force_hits(tris, origin, direction):
    """Every triangle's ray parameter t along ``origin + t direction`` (Moller-Trumbore, no tree) and the mask of
    the triangles the ray hits at t > 0: the reference the BVH traversal tests compare with."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    p = np.cross(direction, e2)
    det = np.einsum("tk,tk->t", e1, p)
    s = origin - tris[:, 0]
    u = np.einsum("tk,tk->t", s, p) / det
    q = np.cross(s, e1)
    v = q @ direction / det
    t = np.einsum("tk,tk->t", e2, q) / det
    return t, (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
