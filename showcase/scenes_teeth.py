"""Teeth showcase scenes (thesis chapter 5): a smile (the upper and lower front teeth of
``core.teeth.anatomy`` on arches with scalloped gums, before an oral-cavity dome; docs/teeth-showcase.md)
and a fitting demo (a synthetic capture fitted by the core; start, fit and ground truth side by side).

Both are built as core ``TeethScene`` models and brought into Blender by ``addon.teeth.scene_build``
(one Blender unit = one millimetre here), rendered by Cycles with the Enamel/Dentin/Gingiva materials.
"""

from __future__ import annotations

import math
import os

import bpy
import numpy as np

from .. import addon
from ..addon.teeth.blend_volume import follow_materials
from ..addon.teeth.materials import group_node, new_teeth_material
from ..addon.teeth.scene_build import add_camera, add_point_light, build_teeth_scene, configure_teeth_cycles
from ..core.teeth.anatomy import make_anatomical_tooth
from ..core.teeth.capture import Camera, PointLight, default_rig
from ..core.teeth.optimise import FitSettings, fit, plot_loss
from ..core.teeth.scene import TeethScene, Tooth, VolumeMaterial
from ..core.teeth.smile import SMILE_LOWER_EDGE, SMILE_UPPER_EDGE, smile_scene
from ..core.teeth.synthetic import (
    GROUND_TRUTH,
    make_scene,
    perturbed_start,
    render_capture,
    scene_target,
)
from ..render import add_lamp
from .registry import LibraryMaterial, LibraryScene, register_material, register_scene


def _light_and_camera(scene, target, width, height, span, lights):
    dist = 160.0
    fov = 2.0 * math.degrees(math.atan(0.5 * span / dist))
    cam = Camera.look_at(target + np.array([0.0, dist, 0.15 * dist]), target, (0, 0, 1), fov, width, height)
    add_camera(scene, cam, mm_per_unit=1.0)
    for k, (pos, inten) in enumerate(lights):
        add_point_light(scene, PointLight(target + np.asarray(pos), np.full(3, inten)), 1.0, f"Teeth Light {k}")
    return cam


def _smile_camera_and_lights(scene, width: int, height: int) -> None:
    """A frontal dental-photography set-up: camera 250 mm in front of the incisors, slightly above the
    occlusal plane; two soft boxes left and right of the lens (their reflections are the enamel's
    highlights: the thin boundary is a mirror, eq. 5.1) and a dim one above."""
    target = np.array([0.0, 0.0, 0.5 * (SMILE_UPPER_EDGE + SMILE_LOWER_EDGE) + 1.5])
    dist, span = 250.0, 58.0
    fov = 2.0 * math.degrees(math.atan(0.5 * span / dist))
    cam = Camera.look_at(target + np.array([0.0, dist, 0.08 * dist]), target, (0, 0, 1), fov, width, height)
    add_camera(scene, cam, mm_per_unit=1.0)
    for k, (pos, power, size) in enumerate((((-110.0, 200.0, 40.0), SMILE_KEY_W, 140.0),
                                            ((110.0, 200.0, 40.0), 0.7 * SMILE_KEY_W, 140.0),
                                            ((0.0, 120.0, 160.0), 0.25 * SMILE_KEY_W, 140.0))):
        add_lamp(scene, "AREA", tuple(target + np.array(pos)), power, f"Teeth Soft Box {k}", size=size,
                 target=tuple(target))


SMILE_KEY_W = 3.0e5  # W (1 Blender unit = 1 mm): key soft box


def build_smile(scene, workdir: str) -> None:
    _ensure_registered()
    ts = smile_scene()
    build_teeth_scene(ts, scene.collection, mm_per_unit=1.0, smooth=True)
    _smile_camera_and_lights(scene, scene.render.resolution_x, scene.render.resolution_y)
    configure_teeth_cycles(scene, scene.cycles.samples, scene.cycles.seed, bounces=24)


DEMO_FREE = ("*.enamel.sigma_t", "*.enamel.albedo", "*.dentin.sigma_t", "*.dentin.albedo")


def fit_demo(workdir: str, iterations: int = 30, seed: int = 0):
    """Synthetic capture of one incisor, a start with perturbed enamel and dentin materials, a core fit of
    those materials (sigma_t, albedo). The dentin shape starts at the truth's and stays: a 24 x 16 pixel
    capture barely constrains the blend-shape coefficients, and freed they wander. Returns (truth, start,
    fit, log)."""
    truth = make_scene(n_teeth=1, resolution=20)
    cams, lights = default_rig(target=scene_target(truth), width=24, height=16, n_lights=9, n_cameras=2,
                               fov_x_deg=2.8)
    cap = render_capture(truth, cams, lights, spp=4, spp_background=1)
    start = perturbed_start(truth, seed=seed, sigma_factor=0.5, kappa_shift=0.4, reset_c=False)
    # a 30-iteration illustration on a 24 x 16 capture, not the product fit: plain Adam (the thesis), 1-spp
    # passes, per-pixel loss, the best-loss result, every light fitted (the settings its reference render has)
    settings = FitSettings(iterations=iterations, lr=0.06, lr_decay=0.0, lights_per_iteration=4, spp=1, image_spp=0,
                           loss_block=1, optimiser="adam", average_tail=0.0, held_out_lights=0, seed=seed,
                           free=DEMO_FREE)
    out = os.path.join(workdir, "teeth-fit") if workdir else None
    best, log = fit(start, cap, settings, out_dir=out)
    if out:
        plot_loss(log, os.path.join(out, "loss.png"))
    return truth, start, best, log


def build_fit_demo(scene, workdir: str) -> None:
    """Left: start (perturbed), middle: fitted, right: ground truth; same lamps and camera."""
    _ensure_registered()
    truth, start, best, _ = fit_demo(workdir)
    for k, (label, ts) in enumerate((("start", start), ("fit", best), ("truth", truth))):
        ts = ts.copy()
        ts.gums, ts.cavity = None, None
        objs = build_teeth_scene(ts, scene.collection, mm_per_unit=1.0, prefix=f"{label} ", smooth=True)
        for enamel, _ in objs["teeth"]:
            enamel.location.x = (k - 1) * 11.0
    target = np.array([0.0, 0.0, 5.0])
    _light_and_camera(scene, target, scene.render.resolution_x, scene.render.resolution_y, 36.0,
                      [((50.0, 150.0, 60.0), 5.0e4)])
    configure_teeth_cycles(scene, scene.cycles.samples, scene.cycles.seed, bounces=24)


def _ensure_registered() -> None:
    """The builders use ``Object.ms_tooth``: register the add-on's classes when running headless."""
    if not hasattr(bpy.types.Object, "ms_tooth"):
        addon.register()


register_scene(LibraryScene("teeth-smile", "Smile: enamel, dentin, gums", build_smile, (160, 96), 32,
                            ("teeth",)))
register_scene(LibraryScene("teeth-fit-demo", "Teeth fit: start | fit | truth", build_fit_demo, (192, 64), 32,
                            ("teeth",)))


# -- library materials: three dentin shades (the shade of a tooth is mostly its dentin) ------------
SHADES = {
    "Dentin Shade A1 (light)": ([2.2, 2.6, 3.2], [0.95, 0.90, 0.80]),
    "Dentin Shade A3 (yellowish)": ([2.4, 2.9, 3.8], [0.93, 0.82, 0.62]),
    "Dentin Shade C2 (greyish)": ([2.6, 2.8, 3.1], [0.86, 0.83, 0.76]),
}


def _shade_material(name: str):
    def build(scene, workdir: str = ""):
        _ensure_registered()
        sigma_t, albedo = SHADES[name]
        # 1 Blender unit = 1 m for artists' scenes (mm per Unit = 1000)
        return new_teeth_material("Dentin", name, scene=scene, volume=VolumeMaterial(np.array(sigma_t),
                                  np.array(albedo), 0.5, -0.1, 0.8), mm_per_unit=1000.0)

    return build


def shade_preview(scene, material) -> None:
    """An upper central incisor (``core.teeth.anatomy``, generic enamel) whose dentin wears ``material``, crown
    up on a dark stage (mm units): the shade shows in the dentin-backed body, the enamel-only incisal third
    stays translucent."""
    geo = make_anatomical_tooth("upper_central", resolution=48)
    tooth = Tooth("shade", geo.enamel, geo.dentin, GROUND_TRUTH["enamel"], GROUND_TRUTH["dentin"],
                  np.full((1, 1, 3), 0.95), np.zeros(3), kind="incisor")
    ts = TeethScene([tooth], None, None)
    objs = build_teeth_scene(ts, scene.collection, mm_per_unit=1.0, smooth=True)
    group_node(material).inputs["mm per Unit"].default_value = 1.0  # the preview stage is in mm
    objs["teeth"][0][1].data.materials[0] = material
    follow_materials([objs["teeth"][0][0]])  # the tooth's Blend Volume takes the shade (as for an artist)
    w, h = scene.render.resolution_x, scene.render.resolution_y
    _light_and_camera(scene, np.array([0.0, 0.0, 3.5]), w, h, 24.0, [((60.0, 150.0, 60.0), 5.0e4)])
    configure_teeth_cycles(scene, scene.cycles.samples, scene.cycles.seed, bounces=24)


def _register_shades() -> None:
    for name in SHADES:
        register_material(LibraryMaterial(name, name.replace("Dentin Shade ", "Shade "), "Teeth/Dentin Shades",
                                          _shade_material(name), "Dentin volume (two-lobe HG) of a tooth shade; "
                                          "pair with the Enamel group", preview=shade_preview))


_register_shades()
