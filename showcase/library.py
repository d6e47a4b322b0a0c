"""Rendering the library: every scene and material registered by ``showcase/scenes*.py``.

Each scene builder receives an empty scene that :func:`render_library_scene` has already configured
(Cycles CPU, OSL, fixed seed, dark world); each material is shown on its own preview stage or on the
standard one (:func:`build_preview_scene`).
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from ..addon.fabric.material import sync_fabric_lamps
from ..core.errors import UserError
from ..render import configure_cycles, dark_world, denoise_for_display, render_to_array, reset_scene
from . import scenes, scenes_fabric, scenes_scratch, scenes_teeth  # noqa: F401  (they register on import)
from .registry import MATERIALS, SCENES, LibraryMaterial, LibraryScene  # noqa: F401  (the registries, re-exported)
from .stage import add_studio_stage


def available_materials() -> list[str]:
    return sorted(MATERIALS)


def available_scenes() -> list[str]:
    return sorted(SCENES)


def build_preview_scene(scene, material) -> None:
    """The standard preview stage with a shader ball wearing ``material``."""
    add_studio_stage(scene, target=(0.0, 0.0, 0.75))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.75, location=(0.0, 0.0, 0.75), segments=64, ring_count=32)
    ball = bpy.context.active_object
    ball.name = "MS Shader Ball"
    for poly in ball.data.polygons:
        poly.use_smooth = True
    ball.data.materials.append(material)
    sync_fabric_lamps(scene)  # the exact fabric path evaluates the stage's lamps itself


def _fresh_scene(workdir: str, resolution: tuple[int, int], samples: int):
    os.makedirs(workdir, exist_ok=True)
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=samples)
    dark_world(scene)
    return scene


def render_material_preview(
    name: str,
    workdir: str,
    resolution: tuple[int, int] = (160, 120),
    samples: int = 16,
    exr_path: str | None = None,
    denoise: bool = False,
) -> np.ndarray:
    """Render library material ``name`` on its preview stage; returns linear RGBA. ``denoise``: for
    display (the showcase), not for references."""
    if name not in MATERIALS:
        raise UserError(f"unknown library material {name!r}; available: {', '.join(sorted(MATERIALS))}")
    scene = _fresh_scene(workdir, resolution, samples)
    entry = MATERIALS[name]
    material = entry.build(scene, workdir)
    (entry.preview or build_preview_scene)(scene, material)
    if denoise:
        denoise_for_display(scene)
    return render_to_array(scene, exr_path)


def render_library_scene(
    name: str,
    workdir: str,
    resolution: tuple[int, int] | None = None,
    samples: int | None = None,
    exr_path: str | None = None,
    denoise: bool = False,
) -> np.ndarray:
    """Build scene ``name`` from scratch and render it; returns linear RGBA (H, W, 4). ``denoise``: for
    display (the showcase), not for references."""
    if name not in SCENES:
        raise UserError(f"unknown scene {name!r}; available: {', '.join(sorted(SCENES))}")
    entry = SCENES[name]
    scene = _fresh_scene(workdir, resolution or entry.resolution, samples or entry.samples)
    entry.build(scene, workdir)
    if denoise:
        denoise_for_display(scene)
    return render_to_array(scene, exr_path)
