"""Scratched-metal showcase (thesis ch. 4): a steel plate with ~10 000 wear scratches under a
sphere lamp and an area lamp, seen close up so that the iridescent scratch glints around both
highlights resolve. ``plain=True`` builds the same scene with a plain metal (the benchmark's base)."""

from __future__ import annotations

import math

import bpy
from mathutils import Vector

from ..addon.scratch.material import create_scratched_metal, sync_scratch_lamps
from ..core.scratch.scratch_generators import circular_polish, uniform_wear
from ..render import add_lamp, add_textured_plane, material_output, new_material, point_along
from .registry import LibraryMaterial, LibraryScene, register_material, register_scene

N_SCRATCHES = 10000
PATCH_MM = 100.0  # the patch covers the plate once: the plate holds exactly N_SCRATCHES scratches
PLATE_M = 0.1


def showcase_scratch_set(n: int = N_SCRATCHES, seed: int = 11):
    return uniform_wear(n, (PATCH_MM * 1000.0, PATCH_MM * 1000.0), length_um=(300.0, 3000.0), seed=seed,
                        max_footprint_um=150.0)


def build_scratched_plate(scene, workdir: str = "", plain: bool = False, n_scratches: int = N_SCRATCHES) -> None:
    base_color, roughness = (0.91, 0.92, 0.92), 0.05
    if plain:
        mat = new_material("Plain Steel")
        bsdf = mat.node_tree.nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Base Color"].default_value = (*base_color, 1.0)
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Roughness"].default_value = roughness
        mat.node_tree.links.new(bsdf.outputs[0], material_output(mat).inputs["Surface"])
    else:
        mat = create_scratched_metal("Scratched Steel", showcase_scratch_set(n_scratches), "showcase",
                                     base_color=base_color, roughness=roughness,
                                     tiling=PLATE_M / (PATCH_MM / 1000.0), scene=scene)
    _plate_stage(scene, mat)
    if not plain:
        sync_scratch_lamps(scene)


def _plate_stage(scene, mat) -> None:
    """The close-up plate stage: a 10 cm plate wearing ``mat``, a sphere lamp near the mirror
    direction of the view and a rectangular area lamp to the side."""
    add_textured_plane(scene, PLATE_M, mat, name="MS Scratched Plate")
    cam_data = bpy.data.cameras.new("MS Scratch Camera")
    cam_data.lens = 50.0
    cam = bpy.data.objects.new("MS Scratch Camera", cam_data)
    view = Vector((0.0, -math.sin(math.radians(40)), math.cos(math.radians(40))))
    cam.location = 0.16 * view
    point_along(cam, -view)
    scene.collection.objects.link(cam)
    scene.camera = cam
    # sphere lamp near the mirror direction of the view, area lamp to the side
    add_lamp(scene, "POINT", (0.01, 0.25 * math.sin(math.radians(40)), 0.25 * math.cos(math.radians(40))), 2.0,
             "MS Scratch Sphere", radius=0.01)
    add_lamp(scene, "AREA", (-0.12, 0.12, 0.18), 3.0, "MS Scratch Area", size=(0.06, 0.02), shape="RECTANGLE",
             target=(0.0, 0.0, 0.0))
    if scene.world is not None and scene.world.node_tree is not None:
        bg = next((n for n in scene.world.node_tree.nodes if n.type == "BACKGROUND"), None)
        if bg is not None:
            bg.inputs["Strength"].default_value = 0.02


register_scene(LibraryScene("scratch-plate", "Scratched steel plate (10 000 scratches)", build_scratched_plate,
                            resolution=(320, 240), samples=16, tags=("scratch",)))


# -- library materials: worn metals (RGB and spectral) ---------------------------------------------
_WORN_TILING = PLATE_M / 0.02  # the 20 mm scratch patch tiles the 10 cm preview plate


def _worn_metal(name, scratch_set, scene, spectral, base_color=(0.91, 0.92, 0.92), roughness=0.06):
    return create_scratched_metal(name, scratch_set, name, base_color=base_color, roughness=roughness,
                                  spectral=spectral, tiling=_WORN_TILING, scene=scene)


def light_wear_material(scene, workdir: str = ""):
    return _worn_metal("Light Wear Steel", uniform_wear(600, (20000.0, 20000.0), seed=3), scene, spectral=False)


def polished_circles_material(scene, workdir: str = ""):
    # 8 polishing centres with arcs wrapped across the patch border: the patch tiles without a seam or one
    # bow-tie highlight per tile (one centre per 20 mm patch, tiled 5 x 5, showed a grid of wedges)
    marks = circular_polish(1500, (20000.0, 20000.0), seed=4, centres=8, boundary="wrap")
    return _worn_metal("Polished Circles Aluminium", marks, scene,
                       spectral=True, base_color=(0.92, 0.93, 0.94), roughness=0.04)


def heavy_wear_material(scene, workdir: str = ""):
    return _worn_metal("Heavy Wear Brass", uniform_wear(4000, (20000.0, 20000.0), seed=5), scene, spectral=True,
                       base_color=(0.91, 0.78, 0.42), roughness=0.08)


def metal_preview(scene, material) -> None:
    """Library preview of a worn metal: the close-up plate stage (scratch glints need it)."""
    _plate_stage(scene, material)
    sync_scratch_lamps(scene)


def _register_worn_metals() -> None:
    register_material(LibraryMaterial("Light Wear Steel", "Light wear (RGB)", "Metal/Light Wear",
                                      light_wear_material, "Steel with sparse wear scratches, 3-wavelength mode",
                                      preview=metal_preview))
    register_material(LibraryMaterial("Polished Circles Aluminium", "Polished circles (16 bands)",
                                      "Metal/Polished", polished_circles_material,
                                      "Circular polishing marks, 16-band spectral mode",
                                      preview=metal_preview))
    register_material(LibraryMaterial("Heavy Wear Brass", "Heavy wear (16 bands)", "Metal/Heavy Wear",
                                      heavy_wear_material, "Brass with dense wear, 16-band spectral mode",
                                      preview=metal_preview))


_register_worn_metals()
