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


def register_scene(entry: LibraryScene) -> LibraryScene:
    if entry.name in SCENES:
        raise ValueError(f"library scene {entry.name!r} registered twice")
    SCENES[entry.name] = entry
    return entry


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
