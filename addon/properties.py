"""Per-feature PropertyGroups, attached to Blender datablocks (saved, undone and linked with them)."""

from __future__ import annotations

import bpy

from .fabric.properties import CLASSES as FABRIC_CLASSES
from .fabric.properties import MS_FabricBrushSettings
from .scratch import world as scratch_world
from .teeth import properties as teeth_properties


class MS_SceneSettings(bpy.types.PropertyGroup):
    """Scene-wide Material Structures settings (one pointer per feature)."""

    # Cycles' own viewport samples, shown in the tab (stored by Cycles, not here: one setting, not two).
    preview_samples: bpy.props.IntProperty(
        name="Viewport Samples", min=1, max=4096, description="Cycles samples of the rendered viewport",
        get=lambda self: self.id_data.cycles.preview_samples,
        set=lambda self, value: setattr(self.id_data.cycles, "preview_samples", value),
    )
    fabric_brush: bpy.props.PointerProperty(type=MS_FabricBrushSettings)
    # Scratched metal: the K brightest regions of the world as lamps of the scratch term (addon/scratch/world.py).
    # Stored in the scene's ID property "ms_scratch_world_lamps", where files and scripts from before set it.
    scratch_world_lamps: bpy.props.IntProperty(
        name="World Lights", min=0, max=scratch_world.MAX_WORLD_LAMPS, default=0,
        description="Brightest regions of the world's environment image given to the scratch term as distant "
        "sphere lamps, in free lamp slots (0: the scratches see no world light; an approximation)",
        get=scratch_world.get_world_lamps, set=scratch_world.set_world_lamps, update=scratch_world.update_world_lamps,
    )


# Feature property groups first: MS_SceneSettings points at them.
CLASSES: list[type] = [*FABRIC_CLASSES, *teeth_properties.CLASSES, MS_SceneSettings]


def register_pointers() -> None:
    bpy.types.Scene.material_structures = bpy.props.PointerProperty(type=MS_SceneSettings)
    teeth_properties.register_pointers()


def unregister_pointers() -> None:
    teeth_properties.unregister_pointers()
    del bpy.types.Scene.material_structures
