"""A smile: the upper and lower front teeth on dental arches, with gums and the oral cavity (thesis Figs.
5.11-5.13), and a ground truth for it whose teeth differ from one another.

* ``smile_scene``: the 8 upper and 8 lower front teeth (central and lateral incisors, canines, first premolars,
  both sides) of ``core.teeth.anatomy`` on the parabolic arches of ``core.teeth.arch``, the mouth slightly open
  (the thesis' volunteers bite on a rigid object), scalloped gums with papillae and a dark-red oral-cavity dome
  behind. Scene: millimetres, mouth facing +y, z up. Every tooth has the given materials.
* ``smile_truth``: that scene with each tooth's own enamel, dentin and dentin shape, drawn from ``seed``:
  translucency (sigma_t a factor 0.6-1.6 of the base, per tissue), shade (log10(1 - albedo) shifted by
  -0.2..0.2 in every channel, brighter or darker, plus -0.1..0.3 times (0, 0.5, 1) in red, green, blue: whiter
  or more yellow), phase functions (g1 0.4-0.8, inside the literature's range the fit keeps to; g2 -0.35..0.05;
  beta 0.6-0.9) and dentin shape (each coefficient -0.3..0.3). The gums and the cavity keep the base's.
* ``smile_framing``: the capture rig's target and horizontal field of view for the arches' width, and
  ``SMILE_CAPTURE_SIZE``, the image size at which an upper central incisor spans at least
  ``INCISOR_MIN_PIXELS`` pixels across in the centre camera.

The thesis masks the molars where the cavity shadows them; the smile has no molars (its back teeth are the first
premolars, lit from the front), so its masks are every pixel that sees a tooth's enamel first.
"""

from __future__ import annotations

import numpy as np

from .arch import build_arch, cavity_dome, gum_mesh, merge_meshes
from .parameterisation import albedo_from_kappa, kappa_from_albedo
from .scene import Gums, OralCavity, TeethScene, Tooth, VolumeMaterial
from .synthetic import GROUND_TRUTH

SMILE_UPPER_EDGE, SMILE_LOWER_EDGE = 0.0, -3.2  # incisal edges (mm): the mouth slightly open, as in the
SMILE_OVERJET = 2.6  # thesis' captures (the volunteer bites on a rigid object); lower arch behind the upper
SMILE_TRUTH_SEED = 69
SMILE_CAPTURE_SIZE = (208, 128)  # width, height: an upper central incisor about 31 pixels across
INCISOR_MIN_PIXELS = 30
FRAMING_MARGIN_MM = 4.0  # beyond the teeth on either side
CAMERA_DISTANCE_MM = 300.0  # the rig's (``capture.default_rig``)


def smile_scene(resolution: int = 40, lower: bool = True, materials: dict | None = None) -> TeethScene:
    """The smile of the module docstring; ``materials``: ``GROUND_TRUTH``'s keys (enamel, dentin, gums,
    cavity_albedo), by default ``GROUND_TRUTH``."""
    mats = GROUND_TRUTH if materials is None else materials
    jaws = [build_arch("upper", resolution=resolution, edge_z=SMILE_UPPER_EDGE)]
    if lower:
        jaws.append(build_arch("lower", resolution=resolution, edge_z=SMILE_LOWER_EDGE, y0=-SMILE_OVERJET))
    teeth, gum_meshes = [], []
    for placed, arch in jaws:
        for t in placed:
            teeth.append(Tooth(t.name, t.geometry.enamel, t.geometry.dentin, mats["enamel"], mats["dentin"],
                               np.full((1, 1, 3), 0.95), np.zeros(3), kind=t.spec.kind))
        gum_meshes.append(gum_mesh(placed, arch))
    gums = Gums(merge_meshes(gum_meshes), mats["gums"], np.full((1, 1, 3), 0.9))
    cavity = OralCavity(cavity_dome(), np.asarray(mats["cavity_albedo"], dtype=np.float64))
    return TeethScene(teeth, gums, cavity)


YELLOW = np.array([0.0, 0.5, 1.0])  # a yellower shade absorbs more blue than green, and no more red


def _varied(base: VolumeMaterial, rng: np.random.Generator) -> VolumeMaterial:
    sigma_t = base.sigma_t * rng.uniform(0.6, 1.6)
    kappa = kappa_from_albedo(base.albedo) + rng.uniform(-0.2, 0.2) + rng.uniform(-0.1, 0.3) * YELLOW
    albedo = np.clip(albedo_from_kappa(kappa), 0.5, 0.995)
    return VolumeMaterial(sigma_t, albedo, rng.uniform(0.4, 0.8), rng.uniform(-0.35, 0.05), rng.uniform(0.6, 0.9))


def smile_truth(scene: TeethScene | None = None, seed: int = SMILE_TRUTH_SEED) -> TeethScene:
    """A copy of ``scene`` (default: ``smile_scene()``) whose teeth each have their own materials and dentin
    shape (module docstring); the same ``seed`` gives the same truth."""
    out = (smile_scene() if scene is None else scene).copy()
    rng = np.random.default_rng(seed)
    for t in out.teeth:
        t.enamel = _varied(t.enamel, rng)
        t.dentin = _varied(t.dentin, rng)
        t.c = rng.uniform(-0.3, 0.3, 3)
    return out


def smile_framing(scene: TeethScene) -> tuple[np.ndarray, float]:
    """(target, horizontal field of view in degrees) of a rig ``CAMERA_DISTANCE_MM`` away that sees the teeth's
    full width plus ``FRAMING_MARGIN_MM`` on either side."""
    v = np.concatenate([t.enamel_mesh.vertices for t in scene.teeth])
    lo, hi = v.min(axis=0), v.max(axis=0)
    span = float(hi[0] - lo[0]) + 2.0 * FRAMING_MARGIN_MM
    fov = 2.0 * float(np.degrees(np.arctan(0.5 * span / CAMERA_DISTANCE_MM)))
    return 0.5 * (lo + hi), fov
