"""Fabric panels: the material properties of SGGX fabric materials (multipliers, maps, lamps) and the
sidebar's "Pile Fabric" (new material, import, the brush)."""

from __future__ import annotations

import bpy

from ..common import MaterialPanel, SidebarPanel, draw_group_inputs, draw_shader_path
from . import fit_job
from .material import (
    GROUP_NAME,
    MARKER,
    exact_path_renders,
    fabric_group_node,
    lamps_leaving_fabric_unlit,
    material_map_images,
)
from .world_light import world_light_status

MULTIPLIERS = (("Tint", "Tint"), ("SigmaScale", "Roughness Scale"), ("Anisotropy", "Anisotropy"),
               ("FastPreview", "Fast Preview (closures only)"), ("ExactWorld", "Exact World Light"))


def draw_unlit_warnings(layout, scene, obj) -> None:
    """A lamp linked from another file that leaves this object unlit here: say which and what lights it."""
    for lamp, unlit in lamps_leaving_fabric_unlit(scene):
        if obj is None or any(o.name_full == obj.name_full for o in unlit):
            col = layout.column(align=True)
            col.alert = True
            col.label(text=f"Lamp '{lamp.name}' from {_library_name(lamp)} leaves this object unlit here", icon="ERROR")
            col.label(text="Its file's light links are for the exact path: turn on Open Shading Language"
                      if not exact_path_renders(scene) else
                      "Its file's light links are read-only here: make the lamp local (Object > Relations)")


def _library_name(lamp) -> str:
    lib = lamp.library or lamp.light_linking.receiver_collection.library
    return bpy.path.basename(lib.filepath) if lib is not None else "another file"


class MATERIAL_PT_material_structures_fabric(MaterialPanel, bpy.types.Panel):
    bl_label = "SGGX Fabric"
    bl_idname = "MATERIAL_PT_material_structures_fabric"
    marker = MARKER

    def draw(self, context):
        layout = self.layout
        mat = context.material
        node = fabric_group_node(mat)
        if node is None:
            layout.label(text=f"No '{GROUP_NAME}' node in this material", icon="ERROR")
            return
        draw_shader_path(layout, context.scene)
        draw_unlit_warnings(layout, context.scene, context.object)
        draw_group_inputs(layout, node, [m for m in MULTIPLIERS if m[0] in node.inputs], linked="from a map")
        if "ExactWorld" in node.inputs and node.inputs["ExactWorld"].default_value:
            layout.label(text=world_light_status(context.scene), icon="WORLD")
        images = material_map_images(mat)
        box = layout.box()
        box.label(text="Parameter maps" if images else "Constant parameters (no maps)")
        for key, image in sorted(images.items()):
            row = box.row()
            row.label(text=key)
            row.label(text=f"{image.name} ({image.size[0]} x {image.size[1]})")
        if not images:
            for name in ("Kd", "Ks", "SigmaX", "SigmaY"):
                box.prop(node.inputs[name], "default_value", text=name)
        row = layout.row()
        row.operator("material_structures.fabric_sync_lamps", icon="LIGHT")
        row.operator("material_structures.fabric_save_maps", icon="FILE_TICK")
        layout.operator("material_structures.fabric_import_maps", icon="IMPORT")


class VIEW3D_PT_material_structures_fabric(SidebarPanel, bpy.types.Panel):
    bl_label = "Pile Fabric"
    bl_idname = "VIEW3D_PT_material_structures_fabric"
    bl_parent_id = "VIEW3D_PT_material_structures"

    def draw(self, context):
        layout = self.layout
        layout.operator_menu_enum("material_structures.fabric_new_material", "preset", icon="MATERIAL")
        layout.operator("material_structures.fabric_import_maps", icon="IMPORT")
        layout.operator("material_structures.fabric_sync_lamps", icon="LIGHT")
        job = fit_job.current_job()
        box = layout.box()
        if job is not None and job.is_alive():
            box.progress(factor=job.progress, text=job.status_text().replace(" (Esc cancels)", ""))
            box.operator("material_structures.fabric_fit_cancel", icon="CANCEL")
        else:
            row = box.row(align=True)
            row.operator("material_structures.fabric_fit_btf", icon="PLAY")
            row.operator("material_structures.use_sample", text="Fit Sample", icon="FILE_FOLDER").sample = "BTF"
            if job is not None:
                box.label(text=f"Last fit: {job.ended_text()}")
        brush = context.scene.material_structures.fabric_brush
        box = layout.box()
        box.label(text="Brush", icon="BRUSH_DATA")
        box.prop(brush, "mode")
        col = box.column(align=True)
        col.prop(brush, "radius")
        col.prop(brush, "strength")
        col.prop(brush, "use_pressure")
        if brush.mode == "COMB":
            box.prop(brush, "fibre_length")
        elif brush.mode == "RECOLOR":
            row = box.row()
            row.prop(brush, "recolor_diffuse")
            row.prop(brush, "kd", text="")
            row = box.row()
            row.prop(brush, "recolor_specular")
            row.prop(brush, "ks", text="")
        elif brush.mode == "SMOOTH":
            box.prop(brush, "smooth_factor")
        elif brush.mode == "ANISOTROPY":
            box.prop(brush, "anisotropy_factor")
        else:
            box.prop(brush, "states_dir")
            box.operator("material_structures.use_sample", text="Open Sample States", icon="FILE_FOLDER").sample = \
                "STATES"
        box.operator("material_structures.fabric_brush", icon="BRUSH_DATA")
        box.label(text="Each stroke is one step of Edit > Undo (Ctrl+Z)", icon="INFO")


CLASSES: list[type] = [MATERIAL_PT_material_structures_fabric, VIEW3D_PT_material_structures_fabric]
