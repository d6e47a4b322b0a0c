"""Named scenes that ``render`` and ``demo`` know how to build (the sample library's showcase).

A feature adds its scenes with :func:`register_scene` in its own ``render/scenes_<feature>.py``; each
builder receives an empty scene that :func:`render_library_scene` has already configured (Cycles CPU,
OSL, fixed seed, dark world).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LibraryScene:
    name: str
    label: str
    build: Callable  # build(scene, workdir) -> None
    resolution: tuple[int, int] = (160, 120)
    samples: int = 32
    tags: tuple[str, ...] = field(default_factory=tuple)


SCENES: dict[str, LibraryScene] = {}


@dataclass(frozen=True)
class LibraryMaterial:
    """A material of the artist library (Asset Browser) and of the demo's contact sheet."""

    name: str  # material / asset name
    label: str
    catalog: str  # asset catalog path, e.g. "Fabric/Velvet"
    build: Callable  # build(scene, workdir) -> bpy.types.Material (lamps synced by the caller)
    description: str = ""
    preview: Callable | None = None  # preview(scene, material): own preview stage (default: shader ball)


MATERIALS: dict[str, LibraryMaterial] = {}


def register_scene(entry: LibraryScene) -> LibraryScene:
    if entry.name in SCENES:
        raise ValueError(f"library scene {entry.name!r} registered twice")
    SCENES[entry.name] = entry
    return entry


def register_material(entry: LibraryMaterial) -> LibraryMaterial:
    if entry.name in MATERIALS:
        raise ValueError(f"library material {entry.name!r} registered twice")
    MATERIALS[entry.name] = entry
    return entry


def available_materials() -> list[str]:
    _load_builtin_scenes()
    return sorted(MATERIALS)


def build_preview_scene(scene, material) -> None:
    """The standard preview stage with a shader ball wearing ``material``."""
    import bpy

    from .stage import add_studio_stage

    add_studio_stage(scene, target=(0.0, 0.0, 0.75))
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.75, location=(0.0, 0.0, 0.75), segments=64, ring_count=32)
    ball = bpy.context.active_object
    ball.name = "MS Shader Ball"
    for poly in ball.data.polygons:
        poly.use_smooth = True
    ball.data.materials.append(material)
    _sync_exact_lamps(scene)


def _sync_exact_lamps(scene) -> None:
    """Copy lamps into every shader that evaluates lamps itself (no-op without such materials)."""
    try:
        from ..addon.fabric.material import sync_fabric_lamps
    except ImportError:  # pragma: no cover - bpy missing
        return
    sync_fabric_lamps(scene)
    for hook in SYNC_HOOKS:
        hook(scene)


# Other features' lamp-sync functions (scene) -> None, called before library renders.
SYNC_HOOKS: list[Callable] = []


def render_material_preview(
    name: str,
    workdir: str,
    resolution: tuple[int, int] = (160, 120),
    samples: int = 16,
    exr_path: str | None = None,
) -> np.ndarray:
    """Render library material ``name`` on the preview stage; returns linear RGBA."""
    from . import configure_cycles, dark_world, render_to_array, reset_scene

    _load_builtin_scenes()
    if name not in MATERIALS:
        raise ValueError(f"unknown library material {name!r}; available: {', '.join(sorted(MATERIALS))}")
    os.makedirs(workdir, exist_ok=True)
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution, samples=samples)
    dark_world(scene)
    entry = MATERIALS[name]
    material = entry.build(scene, workdir)
    (entry.preview or build_preview_scene)(scene, material)
    return render_to_array(scene, exr_path)


def render_library_scene(
    name: str,
    workdir: str,
    resolution: tuple[int, int] | None = None,
    samples: int | None = None,
    exr_path: str | None = None,
) -> np.ndarray:
    """Build scene ``name`` from scratch and render it; returns linear RGBA (H, W, 4)."""
    from . import configure_cycles, dark_world, render_to_array, reset_scene

    _load_builtin_scenes()
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; available: {', '.join(sorted(SCENES))}")
    entry = SCENES[name]
    os.makedirs(workdir, exist_ok=True)
    scene = reset_scene()
    configure_cycles(scene, resolution=resolution or entry.resolution, samples=samples or entry.samples)
    dark_world(scene)
    entry.build(scene, workdir)
    return render_to_array(scene, exr_path)


def available_scenes() -> list[str]:
    _load_builtin_scenes()
    return sorted(SCENES)


def _load_builtin_scenes() -> None:
    """Import ``render/scenes.py`` and every ``render/scenes_<feature>.py`` (they register on import)."""
    import importlib
    import pkgutil

    from . import __path__ as package_path

    for info in pkgutil.iter_modules(package_path):
        if info.name == "scenes" or info.name.startswith("scenes_"):
            importlib.import_module(f"{__package__}.{info.name}")
