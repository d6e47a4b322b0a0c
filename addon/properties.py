"""The scene's Material Structures settings (``Scene.material_structures``): one pointer or setting per
feature, each defined in its feature folder. Saved, undone and linked with the scene."""

from __future__ import annotations

import bpy

from .fabric.properties import MS_FabricBrushSettings
from .scratch.properties import world_lamps_property


class MS_SceneSettings(bpy.types.PropertyGroup):
    """Scene-wide Material Structures settings (one pointer per feature)."""

    # Cycles' own viewport samples, shown in the tab (stored by Cycles, not here: one setting, not two).
    preview_samples: bpy.props.IntProperty(
        name="Viewport Samples", min=1, max=4096, description="Cycles samples of the rendered viewport",
        get=lambda self: self.id_data.cycles.preview_samples,
        set=lambda self, value: setattr(self.id_data.cycles, "preview_samples", value),
    )
    fabric_brush: bpy.props.PointerProperty(type=MS_FabricBrushSettings, name="Fabric Brush",
                                            description="Settings of the pile-fabric brush (mode, radius, strength)")
    # Scratched metal: the K brightest regions of the world as lamps of the scratch term (addon/scratch/world.py).
    scratch_world_lamps: world_lamps_property()


# The feature property groups it points at are registered before it (addon/__init__.py).
CLASSES: list[type] = [MS_SceneSettings]


def register_pointers() -> None:
    bpy.types.Scene.material_structures = bpy.props.PointerProperty(type=MS_SceneSettings)


def unregister_pointers() -> None:
    del bpy.types.Scene.material_structures
