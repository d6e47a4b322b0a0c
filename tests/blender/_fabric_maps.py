"""Fabric parameter maps for the Blender-side fabric tests (not a test module): a random fit on disk, the maps a
material holds, the keywords of a replayed brush stroke."""

from __future__ import annotations

import numpy as np

from material_structures.core.fabric.parameter_maps import make_maps, save_params


def write_random_fabric_fit(folder, h: int, w: int, seed: int = 3):
    """Random ``h`` x ``w`` fabric parameter maps (a distinct fibre direction per texel, near +x) saved as a fit
    into ``folder``; returns the maps."""
    rng = np.random.default_rng(seed)
    maps = make_maps(
        kd=rng.uniform(0, 0.3, (h, w, 3)),
        ks=rng.uniform(0.1, 1, (h, w, 3)),
        sigma=rng.uniform(0.3, 2, (h, w, 2)),
        basis=np.tile([1.0, 0.0, 0.0, 0.0], (h, w, 1)) + rng.normal(scale=0.1, size=(h, w, 4)),
    )
    save_params(folder, maps)
    return maps


def material_maps(obj):
    """The fabric parameter maps that ``obj``'s active material holds now (its map images)."""
    from material_structures.addon.fabric.maps import images_to_maps
    from material_structures.addon.fabric.material import material_map_images

    return images_to_maps(material_map_images(obj.active_material))


def stroke_kwargs(uvs, pressure: float = 1.0) -> dict:
    """The keywords of the Fabric Brush operator that replay a stroke through the UV points ``uvs``."""
    return {"stroke": [{"name": "", "uv": uv, "location": (0, 0, 0), "pressure": pressure} for uv in uvs],
            "stroke_space": "UV"}
