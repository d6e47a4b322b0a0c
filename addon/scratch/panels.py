"""Scratched-metal panels: the material properties of scratched-metal materials (set info, shader controls,
tools) and the sidebar's "Scratches"."""

from __future__ import annotations

import bpy

from ..common import MaterialPanel, SidebarPanel, draw_group_inputs, draw_shader_path
from .material import MARKER, group_node
from .tables import PROP

CONTROLS = (("BaseColor", "Base Color"), ("EdgeTint", "Edge Tint"), ("Roughness", "Roughness"),
            ("Intensity", "Scratch Intensity"), ("Coherence", "Coherence Length (um)"),
            ("Spectral", "Spectral (16 bands)"), ("Tiling", "Tiling"))


def draw_import_export(layout) -> None:
    row = layout.row()
    row.operator("material_structures.scratch_import", icon="IMPORT")
    row.operator("material_structures.scratch_export", icon="EXPORT")


class MATERIAL_PT_material_structures_scratch(MaterialPanel, bpy.types.Panel):
    bl_label = "Scratched Metal"
    bl_idname = "MATERIAL_PT_material_structures_scratch"
    marker = MARKER

    def draw(self, context):
        layout = self.layout
        node = group_node(context.material)
        if node is None:
            layout.label(text="No scratched-metal group in this material", icon="ERROR")
            return
        meta = node.node_tree.get(PROP)
        if meta is not None:
            box = layout.box()
            box.label(text=f"Set '{meta['name']}': {meta['n_segments']} segments")
            px, py = meta["patch_size_um"]
            box.label(text=f"Patch {px / 1000:.2f} x {py / 1000:.2f} mm, indexed for sigma {meta['sigma_um']:g} um")
        draw_shader_path(layout, context.scene)
        draw_group_inputs(layout, node, CONTROLS)
        layout.prop(context.scene.material_structures, "scratch_world_lamps", text="World Lights")
        row = layout.row()
        row.operator("material_structures.scratch_generate", icon="MOD_NOISE")
        row.operator("material_structures.scratch_draw", icon="GREASEPENCIL")
        draw_import_export(layout)
        layout.operator("material_structures.scratch_sync_lamps", icon="LIGHT")


class VIEW3D_PT_material_structures_scratch(SidebarPanel, bpy.types.Panel):
    bl_label = "Scratches"
    bl_idname = "VIEW3D_PT_material_structures_scratch"

    def draw(self, context):
        layout = self.layout
        layout.operator("material_structures.scratch_generate", icon="MOD_NOISE")
        layout.operator("material_structures.scratch_draw", icon="GREASEPENCIL")
        draw_import_export(layout)


CLASSES: list[type] = [MATERIAL_PT_material_structures_scratch, VIEW3D_PT_material_structures_scratch]
