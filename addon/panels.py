"""The 3D viewport sidebar tab "Material Structures" (the features' panels: ``<feature>/panels.py``)."""

from __future__ import annotations

import bpy

from .common import SidebarPanel
from .operators import osl_ready


class VIEW3D_PT_material_structures(SidebarPanel, bpy.types.Panel):
    bl_label = "Material Structures"
    bl_idname = "VIEW3D_PT_material_structures"

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        if osl_ready(scene):
            layout.label(text="Cycles + OSL: ready", icon="CHECKMARK")
        else:
            layout.label(text="Exact shaders need Cycles + OSL", icon="INFO")
            layout.operator("material_structures.setup_cycles_osl")
        layout.prop(scene.material_structures, "preview_samples")


CLASSES: list[type] = [VIEW3D_PT_material_structures]
