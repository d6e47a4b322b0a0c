"""Per-feature PropertyGroups, attached to Blender datablocks (saved, undone and linked with them)."""

from __future__ import annotations

import bpy

from .fabric.properties import CLASSES as FABRIC_CLASSES
from .fabric.properties import MS_FabricBrushSettings
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


# Feature property groups first: MS_SceneSettings points at them.
CLASSES: list[type] = [*FABRIC_CLASSES, *teeth_properties.CLASSES, MS_SceneSettings]


def register_pointers() -> None:
    bpy.types.Scene.material_structures = bpy.props.PointerProperty(type=MS_SceneSettings)
    teeth_properties.register_pointers()


def unregister_pointers() -> None:
    teeth_properties.unregister_pointers()
    del bpy.types.Scene.material_structures
