"""The scene setting of the scratched metal: World Lights (``Scene.material_structures.scratch_world_lamps``).

It is stored in the scene's ID property ``ms_scratch_world_lamps`` (``world.WORLD_LAMPS_PROP``), where files
and scripts from before it was a setting put it, so those keep working.
"""

from __future__ import annotations

import bpy

from .material import sync_scratch_lamps
from .world import MAX_WORLD_LAMPS, WORLD_LAMPS_PROP, world_lamp_count


def get_world_lamps(settings) -> int:
    """Getter of ``MS_SceneSettings.scratch_world_lamps`` (``settings.id_data`` is the scene)."""
    return world_lamp_count(settings.id_data)


def set_world_lamps(settings, value: int) -> None:
    settings.id_data[WORLD_LAMPS_PROP] = max(0, min(MAX_WORLD_LAMPS, int(value)))


def update_world_lamps(settings, context) -> None:
    """A changed World Lights reaches the shaders at once (render_pre syncs again anyway)."""
    sync_scratch_lamps(settings.id_data)


def world_lamps_property():
    """The World Lights setting: the K brightest regions of the world as lamps of the scratch term
    (``world.py``)."""
    return bpy.props.IntProperty(
        name="World Lights", min=0, max=MAX_WORLD_LAMPS, default=0,
        description="Brightest regions of the world's environment image given to the scratch term as distant "
        "sphere lights, in free light slots (0: the scratches see no world light; an approximation)",
        get=get_world_lamps, set=set_world_lamps, update=update_world_lamps,
    )
