"""Sidebar panel "Teeth": add teeth, edit the dentin shape (live shape keys), fit to a capture (choosing which
tooth of the scene each capture tooth's fit is applied to)."""

from __future__ import annotations

import bpy

from ...core.teeth.fit_checkpoint import stopped_fit
from ..common import SidebarPanel
from ..operators import osl_ready
from .properties import CHECK_IMAGE_NAME, fit_out_dir, owner
from .scene_build import short_light_paths


def scene_has_teeth(scene) -> bool:
    """Whether ``scene`` renders a tooth: one of its objects, or one in a collection it instances, at any depth
    (File > Link of a collection makes an instance; its objects are not the scene's objects). Each collection is
    looked into once: the panel redraws often, and a scene may instance one collection a thousand times."""
    seen: set = set()

    def has_teeth(objects) -> bool:
        for obj in objects:
            if obj.ms_tooth.role == "ENAMEL":
                return True
            coll = obj.instance_collection if obj.instance_type == "COLLECTION" else None
            if coll is not None and coll.as_pointer() not in seen:
                seen.add(coll.as_pointer())
                if has_teeth(coll.all_objects):
                    return True
        return False

    return has_teeth(scene.objects)


class VIEW3D_PT_material_structures_teeth(SidebarPanel, bpy.types.Panel):
    bl_label = "Teeth"
    bl_idname = "VIEW3D_PT_material_structures_teeth"

    def draw(self, context):
        layout = self.layout
        row = layout.row(align=True)
        row.operator("material_structures.teeth_add_tooth", text="Add Tooth", icon="ADD").source = "TEMPLATE"
        row.operator("material_structures.teeth_add_tooth", text="From Mesh", icon="MESH_DATA").source = "MESH"
        layout.operator("material_structures.teeth_import_scene", icon="IMPORT")
        if (context.scene.render.engine == "CYCLES" and short_light_paths(context.scene)
                and scene_has_teeth(context.scene)):
            row = layout.row()
            row.label(text="Light Paths too short: teeth render too dark", icon="ERROR")
            row.operator("material_structures.teeth_light_paths", text="Set Light Paths")
        if not osl_ready(context.scene):  # nothing switches the engine unasked: the artist may, here
            row = layout.row()
            row.label(text="Exact enamel surface:", icon="INFO")
            row.operator("material_structures.setup_cycles_osl", text="Use Cycles + OSL")
        obj = owner(context.active_object)
        if obj is None:
            layout.label(text="Select a tooth to edit its dentin", icon="INFO")
        else:
            st = obj.ms_tooth
            box = layout.box()
            box.label(text=f"{st.tooth_name} ({st.kind or 'tooth'}): dentin shape", icon="SHAPEKEY_DATA")
            col = box.column(align=True)
            col.prop(st, "buccal", slider=True)
            col.prop(st, "proximal", slider=True)
            col.prop(st, "occlusal", slider=True)
            if st.has_fit:
                f = st.fitted
                box.label(text=f"Fitted c: {f[0]:+.3f} {f[1]:+.3f} {f[2]:+.3f}")
            row = box.row()
            row.enabled = st.has_fit
            row.operator("material_structures.teeth_apply_fitted", icon="CHECKMARK")
        fs = context.scene.ms_teeth_fit
        box = layout.box()
        box.label(text="Fit to capture", icon="MOD_LENGTH")
        box.prop(fs, "capture_dir")
        if len(fs.tooth_map):  # capture tooth -> the tooth of this scene its fit is applied to
            col = box.column(align=True)
            for m in fs.tooth_map:
                split = col.split(factor=0.4, align=True)
                split.label(text=m.capture_tooth, icon="FORWARD")
                split.prop(m, "enamel", text="")
            if all(m.enamel is None for m in fs.tooth_map):
                col.label(text="No capture tooth is mapped to a tooth of this scene", icon="ERROR")
        row = box.row(align=True)
        row.operator("material_structures.teeth_read_capture_teeth", icon="FILE_REFRESH")
        row.operator("material_structures.teeth_map_by_position", icon="ORIENTATION_GLOBAL")
        row.operator("material_structures.use_sample", text="Open Sample", icon="FILE_FOLDER").sample = "CAPTURE"
        box.prop(fs, "out_dir")
        box.prop(fs, "iterations")
        box.prop(fs, "init")
        if fs.running:
            box.prop(fs, "progress", slider=True)
            box.operator("material_structures.teeth_fit_cancel", icon="CANCEL")
        else:
            row = box.row(align=True)
            row.operator("material_structures.teeth_fit", icon="PLAY")
            if fs.capture_dir and stopped_fit(fit_out_dir(fs)):
                row.operator("material_structures.teeth_fit", text="Resume", icon="FF").resume = True
            box.operator("material_structures.teeth_apply_fit_file", icon="FILE_TICK")
        if fs.status:
            box.label(text=fs.status)
        if fs.check_error:
            box.label(text=fs.check_error, icon="CHECKMARK")
        if fs.check_intervals:
            box.label(text=fs.check_intervals, icon="INFO")
        if fs.check_parameters:
            draw_parameters(context, box, fs)
        img = bpy.data.images.get(CHECK_IMAGE_NAME) if fs.check_image else None
        if img is not None and img.preview is None:  # packed in the .blend; its preview is made again on reopen
            try:
                img.preview_ensure()
            except (RuntimeError, AttributeError):
                pass
        if img is not None and img.preview is not None:
            box.label(text="Capture | Fit | Difference x4")
            box.template_icon(icon_value=img.preview.icon_id, scale=10.0)


def draw_parameters(context, box, fs) -> None:
    """The fit's parameters and intervals, and what the capture leaves open: a fold-out list, each line wrapped
    to the panel's width."""
    import textwrap

    row = box.row()
    row.prop(fs, "show_check_parameters", emboss=False,
             icon="TRIA_DOWN" if fs.show_check_parameters else "TRIA_RIGHT")
    if not fs.show_check_parameters:
        return
    region = getattr(context, "region", None)
    width = max(30, int(region.width / 7)) if region is not None else 60
    col = box.column(align=True)
    for line in fs.check_parameters.splitlines():
        for i, part in enumerate(textwrap.wrap(line, width)):
            col.label(text=part if i == 0 else "    " + part)
    if fs.check_open:
        col.separator()
        col.label(text="Left open by the capture:")
        for line in fs.check_open.splitlines():
            for i, part in enumerate(textwrap.wrap(line, width)):
                col.label(text=part, icon="DOT" if i == 0 else "BLANK1")


CLASSES: list[type] = [VIEW3D_PT_material_structures_teeth]
