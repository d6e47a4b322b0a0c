"""Add-on preferences."""

from __future__ import annotations

import bpy

# The add-on's module name: "bl_ext.<repo>.material_structures" when installed as an extension.
ADDON_ID = __package__.rpartition(".")[0]


class MS_Preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    def draw(self, context):
        layout = self.layout
        layout.label(text="Material Structures: pile fabric, scratched metal, teeth (Cycles + OSL)")
        layout.operator("material_structures.setup_cycles_osl", icon="SHADING_RENDERED")
        layout.operator("material_structures.register_asset_library", icon="ASSET_MANAGER")


CLASSES: list[type] = [MS_Preferences]
