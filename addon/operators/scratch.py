"""Scratched-metal operators: generate, draw (modal + EXEC stroke replay), import/export, sync lamps."""

from __future__ import annotations

import os

import bpy

from ...core.scratch.scratch_io import load_scratch_set, save_scratch_set
from ..fabric.mesh_uv import MeshUVLookup
from ..fabric.properties import MS_StrokePoint
from ..scratch.editing import (
    FINE_WEAR_SIGMA_UM,
    PATTERNS,
    curves_set,
    generate_set,
    material_set,
    merge_sets,
    object_scratch_material,
)
from ..scratch.material import create_scratched_metal, ensure_scratch_group, sync_scratch_lamps
from .fabric import assign_material, require_uv_mesh

PATTERN_ITEMS = [(k, k.title(), v) for k, v in PATTERNS.items()]


def apply_set(context, obj, scratch_set, set_name: str):
    """Put ``scratch_set`` on ``obj``: update its scratched-metal material, or give it a new one."""
    mat = object_scratch_material(obj)
    if mat is not None:
        current = material_set(mat)
        name = current[0] if current else set_name
        ensure_scratch_group(scratch_set, name, context.scene)
    else:
        mat = create_scratched_metal(f"Scratched Metal {set_name}", scratch_set, set_name, scene=context.scene)
        assign_material(obj, mat)
    sync_scratch_lamps(context.scene)
    return mat


class MS_OT_scratch_generate(bpy.types.Operator):
    """Generate a scratch set (wear, polishing circles or hairline) on the active object's scratched metal"""

    bl_idname = "material_structures.scratch_generate"
    bl_label = "Generate Scratches"
    bl_options = {"REGISTER", "UNDO"}

    pattern: bpy.props.EnumProperty(name="Pattern", items=PATTERN_ITEMS, default="WEAR")
    count: bpy.props.IntProperty(name="Scratches", description="Number of scratches on one patch", default=500,
                                 min=1, max=200000)
    patch_mm: bpy.props.FloatProperty(name="Patch Size (mm)", description="Side of the square patch that tiles "
                                      "the UV map", default=20.0, min=0.5, max=1000.0)
    length_um: bpy.props.FloatVectorProperty(name="Length (um)", size=2, default=(300.0, 4000.0), min=1.0)
    width_um: bpy.props.FloatVectorProperty(name="Width (um)", size=2, default=(0.8, 6.0), min=0.05, max=100.0)
    depth_um: bpy.props.FloatVectorProperty(name="Depth (um)", size=2, default=(0.8, 6.0), min=0.0, max=100.0)
    angle_deg: bpy.props.FloatProperty(name="Hairline Angle", default=0.0, min=-180.0, max=180.0)
    fine_wear: bpy.props.BoolProperty(name="Fine Wear", description=f"Coherence length {FINE_WEAR_SIGMA_UM:g} um "
                                      "instead of 60 um", default=False)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    replace: bpy.props.BoolProperty(name="Replace", description="Replace the current set (else add to it)",
                                    default=True)
    set_name: bpy.props.StringProperty(name="Set Name", default="Scratches")

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        for label, (lo, hi) in (("length", self.length_um), ("width", self.width_um), ("depth", self.depth_um)):
            if lo > hi:
                self.report({"ERROR"}, f"{label} range is empty ({lo} > {hi})")
                return {"CANCELLED"}
        sigma = FINE_WEAR_SIGMA_UM if self.fine_wear else 60.0
        try:
            new = generate_set(self.pattern, self.count, self.patch_mm, tuple(self.length_um), tuple(self.width_um),
                               tuple(self.depth_um), self.seed, sigma, self.angle_deg)
            current = None if self.replace else material_set(object_scratch_material(obj))
            s = merge_sets(current[1] if current else None, new)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        mat = apply_set(context, obj, s, self.set_name)
        self.report({"INFO"}, f"{s.n_scratches} scratches ({s.n_segments} segments) on '{mat.name}'")
        return {"FINISHED"}


class MS_OT_scratch_draw(bpy.types.Operator):
    """Draw scratches on the active object with the mouse (LMB drag; Esc/RMB done). EXEC replays ``stroke``"""

    bl_idname = "material_structures.scratch_draw"
    bl_label = "Draw Scratches"
    bl_options = {"REGISTER", "UNDO"}

    stroke: bpy.props.CollectionProperty(type=MS_StrokePoint, options={"SKIP_SAVE"})
    stroke_space: bpy.props.EnumProperty(
        name="Stroke Space",
        items=[("UV", "UV", "Stroke points are UV coordinates"), ("WORLD", "World", "3D points on the surface")],
        default="UV",
        options={"SKIP_SAVE"},
    )
    width_um: bpy.props.FloatVectorProperty(name="Width (um)", size=2, default=(2.0, 4.0), min=0.05, max=100.0)
    depth_um: bpy.props.FloatVectorProperty(name="Depth (um)", size=2, default=(1.0, 3.0), min=0.0, max=100.0)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)

    @classmethod
    def poll(cls, context):
        return material_set(object_scratch_material(context.active_object)) is not None

    def execute(self, context):
        obj = context.active_object
        try:
            curve = self._stroke_uvs(context, obj)
            self._add_curves(context, obj, [curve])
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}

    def _stroke_uvs(self, context, obj):
        if len(self.stroke) < 2:
            raise ValueError("a scratch stroke needs at least 2 points")
        if self.stroke_space == "UV":
            return [tuple(p.uv) for p in self.stroke]
        lookup = MeshUVLookup(obj, context.evaluated_depsgraph_get())
        out = [uv for uv in (lookup.nearest(p.location) for p in self.stroke) if uv is not None]
        if len(out) < 2:
            raise ValueError("the stroke does not touch the mesh")
        return out

    def _add_curves(self, context, obj, curves):
        mat = object_scratch_material(obj)
        name, current = material_set(mat)
        new = curves_set(curves, current.patch_size_um, tuple(self.width_um), tuple(self.depth_um),
                         current.sigma_um, self.seed, current.query_radius_um - 3.5 * current.sigma_um)
        ensure_scratch_group(merge_sets(current, new), name, context.scene)

    # -- interactive ----------------------------------------------------------------------------
    def invoke(self, context, event):
        if len(self.stroke) >= 2:
            return self.execute(context)
        if context.area is None or context.area.type != "VIEW_3D":
            self.report({"ERROR"}, "Drawing scratches works in the 3D viewport")
            return {"CANCELLED"}
        try:
            self.lookup = MeshUVLookup(context.active_object, context.evaluated_depsgraph_get())
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.drawing = False
        self.points = []
        self.curves = []
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set("Draw scratches: LMB drag draws one scratch, Esc/RMB done")
        return {"RUNNING_MODAL"}

    def _uv_under_mouse(self, context, event):
        return self.lookup.under_mouse(context, event)

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._finish(context)
        if event.type == "LEFTMOUSE":
            if event.value == "PRESS":
                self.drawing = True
                uv = self._uv_under_mouse(context, event)
                self.points = [uv] if uv is not None else []
            elif event.value == "RELEASE":
                self.drawing = False
                if len(self.points) >= 2:
                    self.curves.append(list(self.points))
                self.points = []
            return {"RUNNING_MODAL"}
        if event.type in {"MOUSEMOVE", "INBETWEEN_MOUSEMOVE"} and self.drawing:
            uv = self._uv_under_mouse(context, event)
            if uv is not None:
                self.points.append(uv)
            return {"RUNNING_MODAL"}
        return {"PASS_THROUGH"}

    def _finish(self, context):
        if context.area is not None:
            context.area.header_text_set(None)
        if not self.curves:
            return {"CANCELLED"}
        try:
            self._add_curves(context, context.active_object, self.curves)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"{len(self.curves)} scratch(es) drawn")
        return {"FINISHED"}


class MS_OT_scratch_import(bpy.types.Operator):
    """Import a scratch set (.npz file or EXR-table folder) onto the active object"""

    bl_idname = "material_structures.scratch_import"
    bl_label = "Import Scratch Set"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="File or Folder", subtype="FILE_PATH")
    set_name: bpy.props.StringProperty(name="Set Name", default="")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        path = bpy.path.abspath(self.filepath)
        if os.path.isfile(path) is False and os.path.isdir(os.path.dirname(path)) and not path.endswith(".npz"):
            path = os.path.dirname(path)  # a file picked inside an EXR-table folder
        try:
            s = load_scratch_set(path)
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot import scratch set: {exc}")
            return {"CANCELLED"}
        name = self.set_name or os.path.splitext(os.path.basename(path.rstrip(os.sep)))[0] or "Imported"
        apply_set(context, obj, s, name)
        self.report({"INFO"}, f"Imported {s.n_scratches} scratches from {path}")
        return {"FINISHED"}


class MS_OT_scratch_export(bpy.types.Operator):
    """Export the active object's scratch set (.npz file, or an EXR-table folder for any other path)"""

    bl_idname = "material_structures.scratch_export"
    bl_label = "Export Scratch Set"
    bl_options = {"REGISTER"}

    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        return object_scratch_material(context.active_object) is not None

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = "scratches.npz"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        found = material_set(object_scratch_material(context.active_object))
        if found is None:
            self.report({"ERROR"}, "The active object has no scratch set")
            return {"CANCELLED"}
        path = bpy.path.abspath(self.filepath)
        try:
            save_scratch_set(path, found[1])
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot export scratch set: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Exported {found[1].n_scratches} scratches to {path}")
        return {"FINISHED"}


class MS_OT_scratch_sync_lamps(bpy.types.Operator):
    """Copy the scene's lamps into the scratched-metal shaders now (normally automatic)"""

    bl_idname = "material_structures.scratch_sync_lamps"
    bl_label = "Sync Scratch Lamps"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        n = sync_scratch_lamps(context.scene)
        self.report({"INFO"}, f"{n} lamp(s) evaluated by the scratch term")
        return {"FINISHED"}


CLASSES: list[type] = [
    MS_OT_scratch_generate,
    MS_OT_scratch_draw,
    MS_OT_scratch_import,
    MS_OT_scratch_export,
    MS_OT_scratch_sync_lamps,
]
