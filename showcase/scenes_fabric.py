"""Pile-fabric showcase scenes: brushed velvet cushion, corduroy bolster with wales, plush ball."""

from __future__ import annotations

import math
import os

import bpy
import numpy as np

from ..addon.fabric.brushing import BrushSession, BrushSettings
from ..addon.fabric.maps import load_fit_folder, maps_to_images
from ..addon.fabric.material import create_fabric_material, fit_closure_images, sync_fabric_lamps
from ..core.fabric.btf_io import save_btf
from ..core.fabric.parameter_maps import make_maps
from ..core.fabric.preset_maps import preset_maps, tilted_quat
from ..core.fabric.synthetic_btf import light_view_pairs, render_btf, synthetic_maps
from ..render import add_lamp
from .registry import LibraryMaterial, LibraryScene, register_material, register_scene
from .stage import add_studio_stage

MAP_SIZE = 256


def _preset_maps(preset: str, size: int = MAP_SIZE, seed: int = 0):
    return preset_maps(preset, size, seed)


def _mapped_material(maps, name, scene, strokes=(), btf_frame=False):
    """A mapped fabric material with its fitted closures; ``strokes``: list of (uv points, BrushSettings)
    brushed into it."""
    images = maps_to_images(maps, name, btf_frame=btf_frame)
    if strokes:
        session = BrushSession(images)
        for points, settings in strokes:
            session.begin_stroke()
            for a, b in zip(points[:-1], points[1:], strict=True):
                session.segment(a, b, settings)
            session.end_stroke()  # uploads and packs
        maps = session.maps()
    closures = fit_closure_images(maps, name)
    return create_fabric_material(name, maps=images, scene=scene, closures=closures)


def _wear(obj, mat):
    obj.data.materials.append(mat)
    for poly in obj.data.polygons:
        poly.use_smooth = True


def velvet_material(scene, workdir: str = ""):
    """Velvet with three combed strokes (the pile turned by the brushing tool)."""
    t = np.linspace(0.0, 1.0, 40)
    comb = BrushSettings(mode="COMB", radius=0.06, strength=1.0, fibre_length=2.0)
    strokes = [
        (np.stack([0.05 + 0.9 * t, 0.62 + 0.05 * np.sin(9 * t)], -1), comb),
        (np.stack([0.95 - 0.9 * t, 0.72 + 0.04 * np.sin(7 * t)], -1), comb),
        (np.stack([0.3 + 0.02 * np.sin(5 * t), 0.52 + 0.4 * t], -1), comb),
    ]
    return _mapped_material(_preset_maps("VELVET"), "Velvet (brushed)", scene, strokes)


def corduroy_material(scene, workdir: str = ""):
    """Corduroy: ridges (wales) across u, the pile leaning to either flank of each ridge."""
    maps = _preset_maps("CORDUROY", seed=1)
    return _mapped_material(maps, "Corduroy", scene)


def plush_material(scene, workdir: str = ""):
    """Plush: 30 degree pile whose lean direction varies smoothly (clumps)."""
    from scipy.ndimage import zoom  # scipy: optional where the add-on runs (desktop Blender has none)

    maps = _preset_maps("PLUSH", seed=2)
    rng = np.random.default_rng(7)
    coarse = np.radians(rng.uniform(0.0, 360.0, size=(8, 8)))
    c, s = (zoom(f(coarse), MAP_SIZE / 8, order=1, mode="grid-wrap", grid_mode=True) for f in (np.cos, np.sin))
    az = np.degrees(np.arctan2(s, c))
    quats = tilted_quat(30.0, az)
    maps = make_maps(kd=maps.kd, ks=maps.ks, sigma=maps.sigma, basis=quats)
    return _mapped_material(maps, "Plush", scene)


def fitted_material(scene, workdir: str):
    """Fitted from a synthetic BTF (16 x 16 texels, 12 x 12 light-view pairs) with the core fitter,
    then imported like any fit folder (basis converted from the BTF frame)."""
    from ..core.fabric.btf_fitter import fit_btf  # needs scipy, like the fitter

    fit_dir = os.path.join(workdir, "synthetic-fabric-fit")
    if not os.path.isfile(os.path.join(fit_dir, "params.json")):
        truth = synthetic_maps(16, 16, seed=11)
        wi, wo = light_view_pairs(12, 12)
        btf_path = save_btf(os.path.join(workdir, "synthetic-fabric.npz"), render_btf(truth, wi, wo), wi, wo)
        fit_btf(btf_path, fit_dir, tile=16, workers=1, progress=False, keep_cache=False)
    return _mapped_material(load_fit_folder(fit_dir), "Fitted Satin (synthetic BTF)", scene, btf_frame=True)


def _key_lamp(scene, location=(2.5, -2.0, 3.0), power=900.0):
    """A point key lamp: evaluated exactly (eq. 3.9) by the fabric shader."""
    return add_lamp(scene, "POINT", location, power, "MS Fabric Key")


def build_velvet_cushion(scene, workdir: str) -> None:
    add_studio_stage(scene, target=(0.0, 0.0, 0.35))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0.0, 0.0, 0.38), segments=64, ring_count=32)
    cushion = bpy.context.active_object
    cushion.scale = (1.15, 1.15, 0.38)
    _wear(cushion, velvet_material(scene))
    _key_lamp(scene)
    sync_fabric_lamps(scene)


def build_corduroy_bolster(scene, workdir: str) -> None:
    add_studio_stage(scene, target=(0.0, 0.0, 0.5))
    bpy.ops.mesh.primitive_cylinder_add(radius=0.5, depth=2.2, location=(0.0, 0.0, 0.5), vertices=96)
    bolster = bpy.context.active_object
    bolster.rotation_euler = (0.0, math.radians(90.0), math.radians(25.0))
    _wear(bolster, corduroy_material(scene))
    _key_lamp(scene, location=(1.5, -2.5, 2.8))
    sync_fabric_lamps(scene)


def build_plush_ball(scene, workdir: str) -> None:
    add_studio_stage(scene, target=(0.0, 0.0, 0.7))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.75, location=(0.0, 0.0, 0.75), segments=64, ring_count=32)
    _wear(bpy.context.active_object, plush_material(scene))
    _key_lamp(scene, location=(2.0, -2.5, 3.2))
    sync_fabric_lamps(scene)


register_scene(LibraryScene("fabric-velvet", "Velvet cushion (brushed)", build_velvet_cushion, samples=16))
register_scene(LibraryScene("fabric-corduroy", "Corduroy bolster (wales)", build_corduroy_bolster, samples=16))
register_scene(LibraryScene("fabric-plush", "Plush ball (clumped pile)", build_plush_ball, samples=16))

register_material(
    LibraryMaterial(
        "Velvet (brushed)",
        "Velvet",
        "Fabric/Velvet",
        velvet_material,
        "SGGX pile fabric (thesis eq. 3.9), combed with the brushing tool",
    )
)
register_material(
    LibraryMaterial("Corduroy", "Corduroy", "Fabric/Corduroy", corduroy_material, "Anisotropic pile along wales")
)
register_material(LibraryMaterial("Plush", "Plush", "Fabric/Plush", plush_material, "Long pile leaning 30 degrees"))
register_material(
    LibraryMaterial(
        "Fitted Satin (synthetic BTF)",
        "Fitted from BTF",
        "Fabric/Fitted",
        fitted_material,
        "Parameter maps fitted by the BTF fitter from a synthetic measurement",
    )
)
