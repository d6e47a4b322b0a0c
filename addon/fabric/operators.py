"""Fabric operators: new material, import fitted maps, save maps, sync lamps, add the node group, and the
brushing tool.

The brushing tool is a modal viewport operator with an EXEC path that replays recorded strokes: drag with
the left mouse button over a fabric-mapped mesh to paint; Esc / right click leaves the tool. Every finished
stroke packs the changed maps into the .blend and is one step of Blender's undo, so Ctrl+Z (inside the tool it
leaves the tool and undoes the last stroke), Ctrl+Shift+Z and Edit > Undo History work on strokes like on any
other edit, and saving is safe at any time (a save in the middle of a stroke packs through the save handler).
Headless: pass the stroke as properties and call EXEC.
"""

from __future__ import annotations

import os

import bpy

from ...core.fabric.closure_fit import save_closure_maps
from ...core.fabric.parameter_maps import save_params
from ..background_job import usable_cores, watch
from ..common import (
    BLEND_RELATIVE,
    AddGroupNode,
    CancelBackgroundJob,
    FolderPicker,
    MeshUVLookup,
    SyncLamps,
    assign_material,
    linked_slot_reason,
    push_undo,
    require_uv_mesh,
    stroke_property,
    stroke_space_property,
    stroke_uvs,
)
from . import fit_job
from .brushing import BrushSettings, load_brush_states, session_for
from .maps import CLOSURE_KEYS, images_to_closure_maps, images_to_maps, maps_to_images
from .material import (
    GROUP_NAME,
    MARKER,
    complete_closure_images,
    create_fabric_material,
    ensure_fabric_group,
    fabric_material,
    fit_closure_images,
    import_fit_material,
    material_map_images,
    sync_fabric_lamps,
)
from .presets import PRESET_ITEMS, preset_maps


class MS_OT_fabric_new_material(bpy.types.Operator):
    """Give the active mesh a new pile-fabric material from a preset, with its own parameter maps to brush"""

    bl_idname = "material_structures.fabric_new_material"
    bl_label = "New Fabric Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default="VELVET",
                                   description="Which pile fabric the new material starts as")

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        name = f"Fabric {self.preset.title()}"
        maps = preset_maps(self.preset)
        images = maps_to_images(maps, name, btf_frame=False)  # preset bases: mesh frame
        closures = fit_closure_images(maps, name)  # 256 x 256 presets: under half a second
        mat = create_fabric_material(name, maps=images, scene=context.scene, closures=closures)
        assign_material(obj, mat)
        sync_fabric_lamps(context.scene)
        return {"FINISHED"}


class MS_OT_fabric_import_maps(FolderPicker, bpy.types.Operator):
    """Create a fabric material from a fit's output folder (kd/ks/sigma/basis EXR maps + params.json)"""

    bl_idname = "material_structures.fabric_import_maps"
    bl_label = "Import Fitted Fabric Maps"
    bl_options = {"REGISTER", "UNDO"}

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH", options=BLEND_RELATIVE,
                                        description="A fit's output folder (kd, ks, sigma, basis maps, params.json)")

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 100)

        def progress(done, total):  # fitting the closures of the distinct fibre geometries
            wm.progress_update(int(100 * done / max(total, 1)))
            if context.workspace is not None:
                context.workspace.status_text_set(f"Fabric: fitting world-light closures {done}/{total}")

        try:
            mat = import_fit_material(bpy.path.abspath(self.directory), context.scene, progress=progress)
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot import fabric maps: {exc}")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
            if context.workspace is not None:
                context.workspace.status_text_set(None)
        assign_material(obj, mat)
        sync_fabric_lamps(context.scene)
        self.report({"INFO"}, f"Fabric maps imported ({mat.name})")
        return {"FINISHED"}


class MS_OT_fabric_save_maps(FolderPicker, bpy.types.Operator):
    """Write the active fabric material's (painted) maps to a folder as EXR + params.json"""

    bl_idname = "material_structures.fabric_save_maps"
    bl_label = "Save Fabric Maps"
    bl_options = {"REGISTER"}

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH", options=BLEND_RELATIVE,
                                        description="Folder the maps are written to (EXR maps and params.json)")

    @classmethod
    def poll(cls, context):
        mat = getattr(context, "material", None) or getattr(context.active_object, "active_material", None)
        return mat is not None and mat.get(MARKER) and len(material_map_images(mat)) == 4

    def execute(self, context):
        mat = getattr(context, "material", None) or context.active_object.active_material
        try:
            maps = images_to_maps(material_map_images(mat))
            folder = bpy.path.abspath(self.directory)
            save_params(folder, maps, {"source": "Blender: " + mat.name})
            closures = complete_closure_images(mat)
            if set(closures) == set(CLOSURE_KEYS):
                save_closure_maps(folder, images_to_closure_maps(closures))
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot save maps: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Saved {mat.name} maps to {self.directory}")
        return {"FINISHED"}


def finish_fabric_fit(job, scene, obj, state: str) -> tuple[str, str]:
    """What an ended fabric fit becomes: its maps as a new fabric material on ``obj`` (when it is a mesh with
    a UV map; else the material is kept with a fake user). Returns (report level, message); ``job.outcome``
    says the same in the panel."""
    job.settled = True
    if state != "FINISHED":
        job.outcome = f"{state.lower()}: see {job.log_path}"
        return ("WARNING" if state == "CANCELLED" else "ERROR"), f"Fabric fit {state.lower()}: {job.last_line}"
    try:
        mat = import_fit_material(job.out_dir, scene)
    except (OSError, ValueError) as exc:
        job.outcome = f"finished, not imported: {exc}"
        return "ERROR", f"Fabric fit finished but its maps cannot be imported: {exc}"
    linked = linked_slot_reason(obj) if obj is not None and obj.type == "MESH" else ""
    if obj is not None and obj.type == "MESH" and obj.data.uv_layers and not linked:
        assign_material(obj, mat)
        sync_fabric_lamps(scene)
        where = f" on {obj.name}"
    else:
        mat.use_fake_user = True  # kept for the next mesh, although nothing uses it yet
        why = f"{linked}; then pick it" if linked else "select a mesh with a UV map and pick it"
        where = f" ({why} in its material slot)"
    job.outcome = f"done: {mat.name}{where}"
    return "INFO", f"Fabric fit finished: {mat.name}{where}"


def _watch(job, scene_name: str, obj_name: str | None):
    """A timer that redraws the panels while ``job`` runs and makes its material when it ends (the operator
    has returned by then: Blender stays usable while the fit runs)."""

    def tick():
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                area.tag_redraw()
        if job.is_alive():
            return 0.5
        scene = bpy.data.scenes.get(scene_name)
        if scene is not None and not job.settled:
            state = job.poll()
            finish_fabric_fit(job, scene, bpy.data.objects.get(obj_name) if obj_name else None, state)
            if state == "FINISHED":  # the fitted material, one step of its own: Ctrl+Z takes back only it
                push_undo("Fabric Fit")
        return None

    return tick


class MS_OT_fabric_fit_btf(FolderPicker, bpy.types.Operator):
    """Fit the pile-fabric model to a measured BTF folder in the background, then give the active mesh a new
    fabric material with the fitted maps"""

    bl_idname = "material_structures.fabric_fit_btf"
    bl_label = "Fit BTF"
    bl_options = {"REGISTER"}

    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH", options=BLEND_RELATIVE,
                                        description="The measured BTF folder (btf.json and its images)")
    out_dir: bpy.props.StringProperty(name="Output Folder", subtype="DIR_PATH", options=BLEND_RELATIVE,
                                      description="Where the fitted maps are written (default: beside the BTF "
                                                  "folder, its name + _fit)")

    @classmethod
    def poll(cls, context):
        if fit_job.job_running():
            cls.poll_message_set("A fabric fit is already running")
            return False
        return True

    def execute(self, context):
        btf = os.path.normpath(bpy.path.abspath(self.directory))
        out = bpy.path.abspath(self.out_dir) if self.out_dir else fit_job.default_out_dir(btf)
        if fit_job.job_running():
            self.report({"ERROR"}, "A fabric fit is already running")
            return {"CANCELLED"}
        try:
            # what the fit command checks first, checked here before its folder and log are made: a bad BTF or an
            # output over the input leaves nothing behind
            from ...core.fabric.btf_io import read_btf_header
            from ...core.output_paths import input_written_over

            if os.path.isfile(os.path.join(btf, "btf.json")):  # without one the job says "no btf.json in ..."
                read_btf_header(btf)
            if input_written_over(out, [btf]) is not None:
                raise ValueError(f"the Output Folder {out!r} would write over the BTF folder; choose another")
            job = fit_job.FabricFitJob(btf, out, workers=usable_cores()).start()
        except (FileNotFoundError, OSError, ValueError) as exc:  # UserError is a ValueError
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        fit_job.set_current_job(job)
        obj = context.active_object
        if bpy.app.background:  # scripts, tests, headless: wait for the fit
            level, message = finish_fabric_fit(job, context.scene, obj, job.wait())
            self.report({level}, message)
            return {"FINISHED"} if level == "INFO" else {"CANCELLED"}
        # from the file browser: the fit runs beside Blender; the panel shows its progress and Cancel
        watch(_watch(job, context.scene.name, obj.name if obj else None))
        self.report({"INFO"}, f"Fabric fit started: {job.log_path}")
        return {"FINISHED"}


class MS_OT_fabric_fit_cancel(CancelBackgroundJob, bpy.types.Operator):
    """Stop the running fabric fit (the tiles it has fitted are kept: fitting the same folder again goes on
    from there)"""

    bl_idname = "material_structures.fabric_fit_cancel"
    bl_label = "Cancel Fabric Fit"
    job_kind = fit_job.KIND
    nothing_running = "No fabric fit is running"


class MS_OT_fabric_sync_lamps(SyncLamps, bpy.types.Operator):
    """Copy the scene's lights into the fabric shaders now (normally automatic)"""

    bl_idname = "material_structures.fabric_sync_lamps"
    bl_label = "Sync Lights"
    sync = staticmethod(sync_fabric_lamps)
    evaluated_by = "exactly by the fabric shader"


class MS_OT_fabric_add_group_node(AddGroupNode, bpy.types.Operator):
    """Add the SGGX Fabric node group to the edited material"""

    bl_idname = "material_structures.fabric_add_group_node"
    bl_label = GROUP_NAME
    marker = MARKER

    def group(self, context):
        return ensure_fabric_group(context.scene)


def brush_settings(scene) -> BrushSettings:
    """The scene's brush settings (``Scene.material_structures.fabric_brush``) as the session takes them."""
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

    stroke: stroke_property()
    stroke_space: stroke_space_property()

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
            obj = context.active_object
            points = stroke_uvs(self.stroke, self.stroke_space, obj, context.evaluated_depsgraph_get())
        except (ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        session = self.session
        session.begin_stroke()
        for (uv0, _), (uv1, p1) in zip(points[:-1], points[1:], strict=True):
            session.segment(uv0, uv1, self.settings, p1 if self.use_pressure else 1.0)
        if not session.end_stroke():
            self.report({"ERROR"}, "The stroke changed no texel (it misses the map, or strength is 0)")
            return {"CANCELLED"}
        return {"FINISHED"}

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
        self.material_uid = fabric_material(context.active_object).session_uid
        self.painting = False
        self.last_uv = None
        context.window_manager.modal_handler_add(self)
        self._header(context)
        return {"RUNNING_MODAL"}

    def _header(self, context):
        s = self.settings
        context.area.header_text_set(
            f"Fabric brush: {s.mode.title()}  radius {s.radius:.3f}  strength {s.strength:.2f}  |  "
            "LMB paint, Ctrl+Z leave and undo the last stroke, Esc/RMB done"
        )

    def _uv_under_mouse(self, context, event):
        return self.lookup.under_mouse(context, event)

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._finish(context)
        if event.type == "Z" and (event.ctrl or event.oskey) and event.value == "PRESS":
            # Blender's undo takes the stroke back: leave the tool and let the key reach Edit > Undo
            self._finish(context)
            return {"FINISHED", "PASS_THROUGH"}
        if event.type == "LEFTMOUSE":
            if event.value == "PRESS":
                self.painting = True
                mat = fabric_material(context.active_object)
                if mat is None or mat.session_uid != self.material_uid:  # the material changed meanwhile
                    self._finish(context)
                    return {"CANCELLED"}
                self.session = session_for(mat)  # a session dropped by an undo starts again
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
        if self.painting:
            self.painting = False
            self.session.end_stroke()
        context.area.header_text_set(None)
        return {"FINISHED"}


CLASSES: list[type] = [
    MS_OT_fabric_new_material,
    MS_OT_fabric_import_maps,
    MS_OT_fabric_save_maps,
    MS_OT_fabric_fit_btf,
    MS_OT_fabric_fit_cancel,
    MS_OT_fabric_sync_lamps,
    MS_OT_fabric_add_group_node,
    MS_OT_fabric_brush,
]
