"""The registries of library scenes and materials that ``render`` and ``demo`` know how to build.

A feature adds its entries with :func:`register_scene` / :func:`register_material` in its own
``showcase/scenes_<feature>.py``; ``showcase/library.py`` imports those modules and renders the entries.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(frozen=True)
class LibraryScene:
    name: str
    label: str
    build: Callable  # build(scene, workdir) -> None
    resolution: tuple[int, int] = (160, 120)
    samples: int = 32
    tags: tuple[str, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class LibraryMaterial:
    """A material of the artist library (Asset Browser) and of the demo's contact sheet."""

    name: str  # material / asset name
    label: str
    catalog: str  # asset catalog path, e.g. "Fabric/Velvet"
    build: Callable  # build(scene, workdir) -> bpy.types.Material (lamps synced by the caller)
    description: str = ""
    preview: Callable | None = None  # preview(scene, material): own preview stage (default: shader ball)


SCENES: dict[str, LibraryScene] = {}
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
