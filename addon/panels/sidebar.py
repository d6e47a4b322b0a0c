"""The 3D viewport sidebar tab."""

from __future__ import annotations

import bpy

from ..operators.scene_setup import osl_ready


class VIEW3D_PT_material_structures(bpy.types.Panel):
    bl_label = "Material Structures"
    bl_idname = "VIEW3D_PT_material_structures"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Material Structures"

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
