"""Fabric operators: new material, import fitted maps, save maps, sync lamps, add the node group."""

from __future__ import annotations

import os

import bpy

from ..fabric.material import (
    GROUP_NAME,
    MARKER,
    create_fabric_material,
    ensure_fabric_group,
    sync_fabric_lamps,
)
from ..fabric.presets import PRESET_ITEMS, preset_maps


def require_uv_mesh(op, obj) -> bool:
    if obj is None or obj.type != "MESH":
        op.report({"ERROR"}, "Select a mesh object")
        return False
    if not obj.data.uv_layers:
        op.report({"ERROR"}, f"'{obj.name}' has no UV map: the fabric frame and maps need one (UV > Unwrap)")
        return False
    return True


def assign_material(obj, mat) -> None:
    if obj.material_slots:
        obj.material_slots[obj.active_material_index].material = mat
    else:
        obj.data.materials.append(mat)


class MS_OT_fabric_new_material(bpy.types.Operator):
    """Give the active mesh a new pile-fabric material from a preset, with its own parameter maps to brush"""

    bl_idname = "material_structures.fabric_new_material"
    bl_label = "New Fabric Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default="VELVET")

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        from ..fabric.maps import maps_to_images

        name = f"Fabric {self.preset.title()}"
        images = maps_to_images(preset_maps(self.preset), name, btf_frame=False)  # preset bases: mesh frame
        mat = create_fabric_material(name, maps=images, scene=context.scene)
        assign_material(obj, mat)
        sync_fabric_lamps(context.scene)
        return {"FINISHED"}


class MS_OT_fabric_import_maps(bpy.types.Operator):
    """Create a fabric material from a fit's output folder (kd/ks/sigma/basis EXR maps + params.json)"""

    bl_idname = "material_structures.fabric_import_maps"
    bl_label = "Import Fitted Fabric Maps"
    bl_options = {"REGISTER", "UNDO"}

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        try:
            mat = import_fit_material(bpy.path.abspath(self.directory), context.scene)
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot import fabric maps: {exc}")
            return {"CANCELLED"}
        assign_material(obj, mat)
        sync_fabric_lamps(context.scene)
        self.report({"INFO"}, f"Fabric maps imported ({mat.name})")
        return {"FINISHED"}


def import_fit_material(params_dir: str, scene=None):
    """Material from a fit folder; images are packed into the .blend."""
    from ..fabric.maps import load_fit_folder, maps_to_images

    maps = load_fit_folder(params_dir)
    name = os.path.basename(os.path.normpath(params_dir)) or "fit"
    images = maps_to_images(maps, f"SGGX {name}")
    mat = create_fabric_material(f"Fabric {name}", maps=images, scene=scene)
    mat["material_structures_source"] = params_dir
    return mat


def material_map_images(mat) -> dict:
    """The map images (kd/ks/sigma/basis) a fabric material reads, by key."""
    out = {}
    for node in mat.node_tree.nodes:
        if node.type == "TEX_IMAGE" and node.name.startswith("map_") and node.image is not None:
            out[node.name[4:]] = node.image
    return out


class MS_OT_fabric_save_maps(bpy.types.Operator):
    """Write the active fabric material's (painted) maps to a folder as EXR + params.json"""

    bl_idname = "material_structures.fabric_save_maps"
    bl_label = "Save Fabric Maps"
    bl_options = {"REGISTER"}

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH")

    @classmethod
    def poll(cls, context):
        mat = getattr(context, "material", None) or getattr(context.active_object, "active_material", None)
        return mat is not None and mat.get(MARKER) and len(material_map_images(mat)) == 4

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        from ...core.fabric.parameter_maps import save_params
        from ..fabric.maps import images_to_maps

        mat = getattr(context, "material", None) or context.active_object.active_material
        try:
            maps = images_to_maps(material_map_images(mat))
            save_params(bpy.path.abspath(self.directory), maps, {"source": "Blender: " + mat.name})
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot save maps: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Saved {mat.name} maps to {self.directory}")
        return {"FINISHED"}


class MS_OT_fabric_sync_lamps(bpy.types.Operator):
    """Copy the scene's lamps into the fabric shaders now (normally automatic)"""

    bl_idname = "material_structures.fabric_sync_lamps"
    bl_label = "Sync Lamps"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        n = sync_fabric_lamps(context.scene)
        self.report({"INFO"}, f"{n} lamp(s) evaluated exactly by the fabric shader")
        return {"FINISHED"}


class MS_OT_fabric_add_group_node(bpy.types.Operator):
    """Add the SGGX Fabric node group to the edited material"""

    bl_idname = "material_structures.fabric_add_group_node"
    bl_label = "SGGX Fabric"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        space = context.space_data
        return space is not None and space.type == "NODE_EDITOR" and space.edit_tree is not None

    def execute(self, context):
        tree = context.space_data.edit_tree
        group = ensure_fabric_group(context.scene)
        for node in tree.nodes:
            node.select = False
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        node.label = GROUP_NAME
        node.select = True
        tree.nodes.active = node
        if context.space_data.id is not None and hasattr(context.space_data.id, "keys"):
            context.space_data.id[MARKER] = 1
        return {"FINISHED"}


CLASSES: list[type] = [
    MS_OT_fabric_new_material,
    MS_OT_fabric_import_maps,
    MS_OT_fabric_save_maps,
    MS_OT_fabric_sync_lamps,
    MS_OT_fabric_add_group_node,
]
