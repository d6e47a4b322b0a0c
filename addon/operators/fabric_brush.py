"""The fabric brushing tool: a modal viewport operator with an EXEC path that replays recorded strokes.

Drag with the left mouse button over a fabric-mapped mesh to paint; Ctrl+Z inside the tool (or the
"Undo Stroke" button) takes back the last stroke; Esc / right click leaves the tool. Every finished
stroke and every undo packs the changed maps into the .blend, so saving is safe at any time (a save
in the middle of a stroke packs through the save handler). Headless: pass the stroke as properties
and call EXEC.
"""

from __future__ import annotations

import bpy

from ..fabric.brushing import BrushSession, BrushSettings, load_brush_states
from ..fabric.material import MARKER
from ..fabric.mesh_uv import MeshUVLookup
from ..fabric.properties import MS_StrokePoint
from .fabric import material_map_images

_SESSIONS: dict[str, BrushSession] = {}


def fabric_material(obj):
    mat = obj.active_material if obj is not None and obj.type == "MESH" else None
    return mat if mat is not None and mat.get(MARKER) else None


def session_for(mat) -> BrushSession:
    """The brush session of ``mat`` (rebuilt when its images changed)."""
    images = material_map_images(mat)
    session = _SESSIONS.get(mat.name)
    if session is not None:
        same = all(session.images.get(k) == images.get(k) for k in session.images) and all(
            tuple(images[k].size) == (session.width, session.height) for k in images
        )
        if same:
            return session
    session = BrushSession(images)
    _SESSIONS[mat.name] = session
    return session


def drop_sessions() -> None:
    _SESSIONS.clear()


def pack_sessions() -> None:
    """Upload and pack whatever the brush sessions changed and have not packed yet."""
    for session in _SESSIONS.values():
        session.flush()
        session.pack()


def brush_settings(scene) -> BrushSettings:
    s = scene.material_structures.fabric_brush
    states = None
    if s.mode == "DATA_DRIVEN":
        if not s.states_dir:
            raise ValueError("choose the folder of the 8 brushing states for the data-driven mode")
        states = load_brush_states(bpy.path.abspath(s.states_dir))
    return BrushSettings(
        mode=s.mode,
        radius=s.radius,
        strength=s.strength,
        fibre_length=s.fibre_length,
        kd=tuple(s.kd) if s.recolor_diffuse else None,
        ks=tuple(s.ks) if s.recolor_specular else None,
        smooth_factor=s.smooth_factor,
        anisotropy_factor=s.anisotropy_factor,
        states=states,
    )


class MS_OT_fabric_brush(bpy.types.Operator):
    """Paint fibre direction, colour, smoothness or anisotropy on the active fabric's maps"""

    bl_idname = "material_structures.fabric_brush"
    bl_label = "Brush Fabric"
    bl_options = {"REGISTER"}

    stroke: bpy.props.CollectionProperty(type=MS_StrokePoint, options={"SKIP_SAVE"})
    stroke_space: bpy.props.EnumProperty(
        name="Stroke Space",
        items=[("UV", "UV", "Stroke points are UV coordinates"), ("WORLD", "World", "3D points on the surface")],
        default="UV",
        options={"SKIP_SAVE"},
    )

    @classmethod
    def poll(cls, context):
        mat = fabric_material(context.active_object)
        return mat is not None and len(material_map_images(mat)) == 4

    def _prepare(self, context):
        mat = fabric_material(context.active_object)
        self.session = session_for(mat)
        self.settings = brush_settings(context.scene)
        self.use_pressure = context.scene.material_structures.fabric_brush.use_pressure

    def execute(self, context):
        """Replay ``stroke`` (headless-friendly; one undoable stroke)."""
        try:
            self._prepare(context)
            points = self._stroke_uvs(context)
        except (ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        session = self.session
        session.begin_stroke()
        changed = False
        for (uv0, _), (uv1, p1) in zip(points[:-1], points[1:], strict=True):
            changed |= session.segment(uv0, uv1, self.settings, p1 if self.use_pressure else 1.0)
        session.end_stroke()
        if not changed:
            self.report({"ERROR"}, "The stroke changed no texel (it misses the map, or strength is 0)")
            return {"CANCELLED"}
        return {"FINISHED"}

    def _stroke_uvs(self, context):
        if len(self.stroke) < 2:
            raise ValueError("a stroke needs at least 2 points")
        if self.stroke_space == "UV":
            return [((p.uv[0], p.uv[1]), p.pressure) for p in self.stroke]
        lookup = MeshUVLookup(context.active_object, context.evaluated_depsgraph_get())
        out = []
        for p in self.stroke:
            uv = lookup.nearest(p.location)
            if uv is not None:
                out.append((uv, p.pressure))
        if len(out) < 2:
            raise ValueError("the stroke does not touch the mesh")
        return out

    # -- interactive ------------------------------------------------------------------------
    def invoke(self, context, event):
        if len(self.stroke) >= 2:
            return self.execute(context)
        if context.area is None or context.area.type != "VIEW_3D":
            self.report({"ERROR"}, "The fabric brush works in the 3D viewport")
            return {"CANCELLED"}
        try:
            self._prepare(context)
            self.lookup = MeshUVLookup(context.active_object, context.evaluated_depsgraph_get())
        except (ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.painting = False
        self.last_uv = None
        context.window_manager.modal_handler_add(self)
        self._header(context)
        return {"RUNNING_MODAL"}

    def _header(self, context):
        s = self.settings
        context.area.header_text_set(
            f"Fabric brush: {s.mode.title()}  radius {s.radius:.3f}  strength {s.strength:.2f}  |  "
            "LMB paint, Ctrl+Z undo stroke, Esc/RMB done"
        )

    def _uv_under_mouse(self, context, event):
        return self.lookup.under_mouse(context, event)

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._finish(context)
        if event.type == "Z" and event.ctrl and event.value == "PRESS":
            if self.session.undo_stroke():
                self.report({"INFO"}, "Stroke undone")
            return {"RUNNING_MODAL"}
        if event.type == "LEFTMOUSE":
            if event.value == "PRESS":
                self.painting = True
                self.session.begin_stroke()
                self.last_uv = self._uv_under_mouse(context, event)
            elif event.value == "RELEASE":
                self.painting = False
                self.session.end_stroke()
            return {"RUNNING_MODAL"}
        if event.type in {"MOUSEMOVE", "INBETWEEN_MOUSEMOVE"} and self.painting:
            uv = self._uv_under_mouse(context, event)
            if uv is not None and self.last_uv is not None:
                pressure = event.pressure if self.use_pressure and event.pressure > 0 else 1.0
                if self.session.segment(self.last_uv, uv, self.settings, pressure):
                    self.session.flush()
                    context.area.tag_redraw()
            self.last_uv = uv
            return {"RUNNING_MODAL"}
        return {"PASS_THROUGH"}

    def _finish(self, context):
        self.session.end_stroke()
        context.area.header_text_set(None)
        return {"FINISHED"}


class MS_OT_fabric_brush_undo(bpy.types.Operator):
    """Take back the last brush stroke on the active fabric's maps"""

    bl_idname = "material_structures.fabric_brush_undo"
    bl_label = "Undo Stroke"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        mat = fabric_material(context.active_object)
        return mat is not None and mat.name in _SESSIONS and bool(_SESSIONS[mat.name].undo_stack)

    def execute(self, context):
        _SESSIONS[fabric_material(context.active_object).name].undo_stroke()
        return {"FINISHED"}


CLASSES: list[type] = [MS_OT_fabric_brush, MS_OT_fabric_brush_undo]
