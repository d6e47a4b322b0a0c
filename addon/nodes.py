"""Node groups and their Add-menu entries. Features append to ``CLASSES`` and ``MENU_ENTRIES``."""

from __future__ import annotations

import bpy

# (label, operator bl_idname, operator kwargs) shown under Add > Material Structures in the shader editor.
MENU_ENTRIES: list[tuple[str, str, dict]] = [
    ("SGGX Fabric", "material_structures.fabric_add_group_node", {}),
    ("Enamel", "material_structures.teeth_add_enamel_node", {}),
    ("Dentin", "material_structures.teeth_add_dentin_node", {}),
    ("Gingiva", "material_structures.teeth_add_gingiva_node", {}),
]


class NODE_MT_material_structures_add(bpy.types.Menu):
    bl_idname = "NODE_MT_material_structures_add"
    bl_label = "Material Structures"

    def draw(self, context):
        layout = self.layout
        if not MENU_ENTRIES:
            layout.label(text="No node groups yet")
        for label, op, kwargs in MENU_ENTRIES:
            props = layout.operator(op, text=label)
            for key, value in kwargs.items():
                setattr(props, key, value)


def _draw_add_menu(self, context):
    if context.space_data.tree_type == "ShaderNodeTree":
        self.layout.menu(NODE_MT_material_structures_add.bl_idname)


CLASSES: list[type] = [NODE_MT_material_structures_add]


def register_menus() -> None:
    bpy.types.NODE_MT_add.append(_draw_add_menu)


def unregister_menus() -> None:
    bpy.types.NODE_MT_add.remove(_draw_add_menu)
