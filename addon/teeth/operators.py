"""Teeth operators: tooth pairs from templates or meshes, dentin coefficients, node groups, fitting."""

from __future__ import annotations

import os

import bpy

from ...core.teeth.anatomy import SPECS as ANATOMY_SPECS
from ...core.teeth.anatomy import make_anatomical_tooth
from ...core.teeth.fit_checkpoint import stopped_fit
from ..common import (
    BLEND_RELATIVE,
    AddGroupNode,
    CancelBackgroundJob,
    FilePicker,
    end_modal_progress,
    target_collection,
)
from . import fit_job
from .fit_job import FitJob, current_job, job_running, set_current_job, usable_cores
from .geometry import build_tooth_pair, placement_from_mesh_object, tooth_from_mesh_object
from .materials import GROUP_NAMES, MARKER, ensure_group, new_teeth_material
from .properties import CHECK_IMAGE_NAME, fit_out_dir, owner
from .scene_build import (
    apply_fit,
    build_teeth_scene,
    capture_tooth_names,
    fill_tooth_map,
    fit_targets,
    linked_tooth_reason,
    map_teeth_by_position,
    no_mapping_message,
    raise_light_paths,
)

LIGHT_PATHS_WORDS = ("Raise the scene's Cycles light-path limits (Total, Volume, Transmission and Transparent "
                     "bounces) to 256 where they are lower: light scatters hundreds of times inside teeth, which "
                     "render more than half too dark under Blender's default limits (54-65 % measured)")


def _report_light_paths(op, scene) -> None:
    changed = raise_light_paths(scene) if op.light_paths else ""
    if changed:
        op.report({"INFO"}, f"Light Paths raised for the teeth: {changed}")

# enum identifiers are the core's template names upper-cased (execute() lower-cases them back)
TOOTH_KINDS = [("INCISOR", "Incisor", ""), ("CANINE", "Canine", ""), ("PREMOLAR", "Premolar", ""),
               ("MOLAR", "Molar", "")] + [
    (key.upper(), spec.name.title(), "Dental-atlas anatomy: labial convexity, cervical constriction, incisal edge "
     "or cusps, root; the dentin stops short of the edge") for key, spec in ANATOMY_SPECS.items()]


def _mm_per_unit(scene) -> float:
    """Millimetres per Blender unit from the scene's unit scale (metres by default: 1000)."""
    return 1000.0 * float(scene.unit_settings.scale_length or 1.0)


def show_fit_check(fs, out_dir: str) -> None:
    """The fit's held-out check (fit_report.json, check.png) into the panel: its error as text, the image
    as the Image datablock ``CHECK_IMAGE_NAME``, packed into the .blend (a new fit's check replaces it)."""
    import json

    from ...core.teeth.fit_intervals import parameter_lines, summary

    fs.check_error, fs.check_image, fs.check_intervals = "", "", ""
    fs.check_parameters, fs.check_open = "", ""
    try:
        with open(os.path.join(out_dir, "fit_report.json")) as f:
            report = json.load(f)
    except (OSError, ValueError):
        return
    held = report.get("held_out", {})
    if held.get("lights"):
        fs.check_error = (f"Held-out lights: {held['rms_relative']:.1%} RMS per pixel, "
                          f"{held['rms_relative_tiles']:.1%} on 8 x 8 tiles")
        if held.get("light_angles_deg") and "training_cone_deg" in held:
            fs.check_error += (f" (lights up to {max(held['light_angles_deg']):.0f}\u00b0 off axis, "
                               f"trained within {held['training_cone_deg']:.0f}\u00b0)")
    intervals = report.get("intervals", {})
    if intervals.get("parameters"):
        fs.check_intervals = summary(intervals)
        fs.check_parameters = "\n".join(parameter_lines(intervals))
        fs.check_open = "\n".join(u["text"] for u in intervals.get("undetermined", []))
    png = os.path.join(out_dir, "check.png")
    if os.path.isfile(png):
        fs.check_image = png
        old = bpy.data.images.get(CHECK_IMAGE_NAME)
        if old is not None:
            bpy.data.images.remove(old)
        img = bpy.data.images.load(png)
        img.name = CHECK_IMAGE_NAME
        img.use_fake_user = True  # no material uses it: without a user it would not be saved at all
        img.pack()  # kept in the .blend: the picture reopens with the file, wherever the fit folder went
        img.preview_ensure()


class MS_OT_teeth_add_tooth(bpy.types.Operator):
    """Add a tooth: enamel shell + dentin core with the buccal/proximal/occlusal dentin modes as shape keys"""

    bl_idname = "material_structures.teeth_add_tooth"
    bl_label = "Add Tooth"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.EnumProperty(name="Source", items=[
        ("TEMPLATE", "Template", "A procedural tooth template"),
        ("MESH", "Active Mesh", "The active closed mesh is the enamel surface (z = tooth axis, crown up)")],
        default="TEMPLATE", description="Make the tooth from a template, or around the active mesh as its enamel")
    kind: bpy.props.EnumProperty(name="Type", items=TOOTH_KINDS, default="INCISOR",
                                 description="Which tooth template (and its dentin shape modes)")
    resolution: bpy.props.IntProperty(name="Resolution", default=40, min=8, max=256,
                                      description="Mesh resolution of the template (segments around; higher: "
                                                  "smoother, slower renders)")
    smooth: bpy.props.BoolProperty(name="Smooth Shading", default=True,
                                   description="Shade the tooth meshes smooth")
    light_paths: bpy.props.BoolProperty(name="Set Light Paths", default=True, description=LIGHT_PATHS_WORDS)

    def execute(self, context):
        from ...core.teeth.tooth_mesh import make_tooth

        scene = context.scene
        mm = _mm_per_unit(scene)
        try:
            if self.source == "MESH":
                src = context.active_object
                if src is None or src.type != "MESH":
                    self.report({"ERROR"}, "Select a closed mesh object (the enamel surface)")
                    return {"CANCELLED"}
                if src.mode == "EDIT":  # its mesh as edited (in Edit Mode the mesh holds it as Edit Mode began)
                    bpy.ops.object.mode_set(mode="OBJECT")
                context.view_layer.update()  # src.matrix_world as seen (after moves from scripts)
                # the source's world scale is baked into the millimetre vertices once; the tooth object
                # gets the source's world location and rotation and scale 1 / mm
                enamel, dentin = tooth_from_mesh_object(src, mm_per_unit=mm)
                placement = placement_from_mesh_object(src, mm_per_unit=mm)
                name, kind = src.name, "custom"
            else:
                key = self.kind.lower()  # the core's template name
                if key in ANATOMY_SPECS:
                    geo = make_anatomical_tooth(key, resolution=max(12, self.resolution))
                    name, kind = ANATOMY_SPECS[key].name.title(), ANATOMY_SPECS[key].kind
                else:
                    geo = make_tooth(key, resolution=self.resolution)
                    name, kind = key.title(), key
                enamel, dentin = geo.enamel, geo.dentin
            em = new_teeth_material("Enamel", f"Enamel {name}", scene=scene, mm_per_unit=mm)
            dm = new_teeth_material("Dentin", f"Dentin {name}", scene=scene, mm_per_unit=mm)
            e_obj, d_obj = build_tooth_pair(name, enamel, dentin, (0.0, 0.0, 0.0), em, dm,
                                            target_collection(context), mm, kind=kind,
                                            smooth=self.smooth)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if self.source == "MESH":
            e_obj.matrix_world = placement  # no parent: sets its location, rotation and scale
            if context.view_layer.objects.get(src.name) is not None:
                src.hide_set(True)
        else:
            e_obj.location = scene.cursor.location
        for o in context.selected_objects:
            o.select_set(False)
        e_obj.select_set(True)
        context.view_layer.objects.active = e_obj
        _report_light_paths(self, scene)
        return {"FINISHED"}


class MS_OT_teeth_set_dentin(bpy.types.Operator):
    """Set the dentin blend coefficients (buccal, proximal, occlusal) of the active tooth"""

    bl_idname = "material_structures.teeth_set_dentin"
    bl_label = "Set Dentin Shape"
    bl_options = {"REGISTER", "UNDO"}

    coefficients: bpy.props.FloatVectorProperty(name="Dentin Shape", size=3, default=(0.0, 0.0, 0.0), min=-0.8,
                                                max=0.8, description="Buccal, proximal and occlusal coefficients c "
                                                "of the dentin shape (no unit; 1 moves it by up to 1 mm)")

    def execute(self, context):
        obj = owner(context.active_object)
        if obj is None:
            self.report({"ERROR"}, "The active object is not a tooth (enamel shell or dentin core)")
            return {"CANCELLED"}
        reason = linked_tooth_reason(obj)
        if reason is not None:
            self.report({"ERROR"}, f"Cannot change the dentin shape: {reason}")
            return {"CANCELLED"}
        obj.ms_tooth.set_coefficients(self.coefficients)
        return {"FINISHED"}


class MS_OT_teeth_apply_fitted(bpy.types.Operator):
    """Set the dentin sliders to the coefficients of the last fit"""

    bl_idname = "material_structures.teeth_apply_fitted"
    bl_label = "Apply Fitted Coefficients"
    bl_options = {"REGISTER", "UNDO"}

    all_teeth: bpy.props.BoolProperty(name="All Teeth", default=False,
                                      description="Apply to every tooth of the scene, not only the active one")

    def execute(self, context):
        objs = ([o for o in context.scene.objects if o.ms_tooth.role == "ENAMEL"] if self.all_teeth
                else [owner(context.active_object)])
        objs = [o for o in objs if o is not None and o.ms_tooth.has_fit]
        if not objs:
            self.report({"ERROR"}, "No fitted coefficients on the selected tooth (run a fit first)")
            return {"CANCELLED"}
        reason = next(filter(None, map(linked_tooth_reason, objs)), None)
        if reason is not None:
            self.report({"ERROR"}, f"Cannot apply the fitted coefficients: {reason}")
            return {"CANCELLED"}
        for o in objs:
            o.ms_tooth.set_coefficients(tuple(o.ms_tooth.fitted))
        return {"FINISHED"}


def _group_op(kind: str):
    class _Op(AddGroupNode, bpy.types.Operator):
        __doc__ = f"Add the {kind} node group to the edited material"
        bl_idname = f"material_structures.teeth_add_{kind.lower()}_node"
        bl_label = kind
        marker = MARKER
        marker_value = kind

        def group(self, context):
            return ensure_group(kind, context.scene)

    _Op.__name__ = f"MS_OT_teeth_add_{kind.lower()}_node"
    return _Op


GROUP_OPERATORS = [_group_op(k) for k in GROUP_NAMES]


def apply_fit_file(context, path: str, copies: list | None = None) -> tuple[list[str], list[str]]:
    """Apply a fitted scene file to the teeth mapped under Fit to capture (by name where a capture tooth is not
    in the mapping). Returns (``"capture tooth -> object"`` for each tooth applied, the file's tooth names); the
    materials made a tooth's own on the way are appended to ``copies``."""
    from ...core.teeth.scene import load_scene

    ts = load_scene(path)
    names = [t.name for t in ts.teeth]
    targets = fit_targets(names, context.scene)
    done = apply_fit(ts, context.scene, source=path, targets=targets, copies=copies)
    return [f"{n} -> {targets[n].name}" for n in done], names


def _read_error(path: str, exc: Exception, verb: str = "cannot read") -> str:
    """One line for a scene file that could not be used: the core's own message (it names the file and the
    field) as it is, else ``verb path: what``; a bare missing key says the file is not a teeth scene."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    if isinstance(exc, KeyError):
        return f"{verb} {path}: not a teeth scene file (scene.json / scene_fit.json): it has no {text}"
    return text if path in text else f"{verb} {path}: {text}"


class MS_OT_teeth_read_capture_teeth(bpy.types.Operator):
    """Read the capture's teeth (its scene.json) to choose the tooth of this scene each one's fit is applied to
    (teeth of the same name are chosen for you)"""

    bl_idname = "material_structures.teeth_read_capture_teeth"
    bl_label = "Read Capture Teeth"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        capture = bpy.path.abspath(context.scene.ms_teeth_fit.capture_dir)
        try:
            names = capture_tooth_names(capture)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.report({"ERROR"}, f"cannot read the capture's teeth: {exc}")
            return {"CANCELLED"}
        mapped = fill_tooth_map(context.scene, names)
        self.report({"INFO"}, f"{len(names)} capture teeth, {mapped} mapped to teeth of this scene")
        return {"FINISHED"}


class MS_OT_teeth_map_by_position(bpy.types.Operator):
    """Map every capture tooth to the tooth of this scene that stands at its place (both sets of teeth moved so
    that their centres coincide; the pairing with the least total distance). For teeth whose names differ from
    the capture's, e.g. a smile made with Add Tooth"""

    bl_idname = "material_structures.teeth_map_by_position"
    bl_label = "Map by Position"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        capture = bpy.path.abspath(context.scene.ms_teeth_fit.capture_dir)
        try:
            mapped = map_teeth_by_position(context.scene, capture, _mm_per_unit(context.scene))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.report({"ERROR"}, f"cannot read the capture's teeth: {exc}")
            return {"CANCELLED"}
        n = len(context.scene.ms_teeth_fit.tooth_map)
        self.report({"INFO"}, f"{n} capture teeth, {mapped} mapped to teeth of this scene by position")
        return {"FINISHED"}


class MS_OT_teeth_apply_fit_file(FilePicker, bpy.types.Operator):
    """Write a fitted scene (scene_fit.json) into the teeth materials and dentin shape keys of the teeth chosen
    under Fit to capture (a tooth not listed there: the tooth of the same name)"""

    bl_idname = "material_structures.teeth_apply_fit_file"
    bl_label = "Apply Fit Result"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="Fit Result", subtype="FILE_PATH", options=BLEND_RELATIVE,
                                       description="A fit's result file, scene_fit.json in the fit's output folder")
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context):
        path = bpy.path.abspath(self.filepath)  # "//": beside the .blend, as Blender's file fields mean it
        if not os.path.isfile(path):
            self.report({"ERROR"}, f"file not found: {self.filepath}")
            return {"CANCELLED"}
        copies: list[str] = []
        try:
            done, names = apply_fit_file(context, path, copies)
        except (ValueError, KeyError, OSError) as exc:
            self.report({"ERROR"}, _read_error(self.filepath, exc, "cannot apply"))
            return {"CANCELLED"}
        if not done:  # nothing was changed
            self.report({"ERROR"}, no_mapping_message(names))
            return {"CANCELLED"}
        self.report({"INFO"}, applied_message(done, copies))
        return {"FINISHED"}


def applied_message(done: list[str], copies: list[str] | None = None) -> str:
    """The status line of Apply Fit Result: each "fit tooth -> Blender tooth" up to three, else a count (a smile's 16
    pairs would not fit the status bar); then the materials made a tooth's own, if any."""
    if len(done) <= 3:
        text = f"Applied the fit: {', '.join(done)}"
    else:
        text = f"Applied the fit to {len(done)} teeth: {', '.join(done[:2])} and {len(done) - 2} more"
    return text + copies_note(copies)


def copies_note(copies: list[str] | None) -> str:
    """What Apply Fit Result adds for the materials and dentin meshes it made a tooth's own: "" when none."""
    if not copies:
        return ""
    shown = ", ".join(copies[:2]) + (f" and {len(copies) - 2} more" if len(copies) > 2 else "")
    return f" (shared data copied so each tooth keeps its fit: {shown})"


class MS_OT_teeth_fit(bpy.types.Operator):
    """Fit the teeth model to a capture folder in a background process, then apply the result to the teeth
    chosen for the capture's teeth"""

    bl_idname = "material_structures.teeth_fit"
    bl_label = "Fit Teeth to Capture"
    bl_options = {"REGISTER", "UNDO"}

    resume: bpy.props.BoolProperty(name="Resume", default=False, options={"SKIP_SAVE"},
                                   description="Continue the fit that stopped in the output folder")

    _timer = None
    _job = None  # the job this (modal) operator watches

    @classmethod
    def description(cls, context, properties):
        if properties.resume:
            return ("Continue the fit that stopped in the output folder (cancelled, or Blender closed) from where "
                    "it stopped, to the result it would have reached; then apply it")
        return cls.__doc__

    @classmethod
    def poll(cls, context):
        if job_running():
            cls.poll_message_set("A teeth fit is already running")
            return False
        return True

    def _start(self, context):
        fs = context.scene.ms_teeth_fit
        capture = bpy.path.abspath(fs.capture_dir)
        out = fit_out_dir(fs)
        if job_running():
            self.report({"ERROR"}, "A teeth fit is already running")
            return None
        if not os.path.isfile(os.path.join(capture, "capture.json")):
            self.report({"ERROR"}, f"no capture.json in {capture!r}")
            return None
        if self.resume and not stopped_fit(out):
            self.report({"ERROR"}, f"no stopped fit to resume in {out!r}")
            return None
        # the fit applies to the teeth mapped to the capture's: refuse now rather than after an hour's fit
        try:
            names = capture_tooth_names(capture)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.report({"ERROR"}, f"cannot read the capture's teeth: {exc}")
            return None
        fill_tooth_map(context.scene, names)
        targets = fit_targets(names, context.scene)
        if not targets:
            self.report({"ERROR"}, no_mapping_message(names))
            return None
        reason = next(filter(None, map(linked_tooth_reason, targets.values())), None)
        if reason is not None:  # Apply Fit Result would refuse it at the end
            self.report({"ERROR"}, f"Cannot fit into this tooth: {reason}")
            return None
        try:
            # the fit's renders use every core (forked per render; cancel stops them too)
            job = FitJob(capture, out, fs.iterations, fs.init.lower(), extra=["--resume"] if self.resume else None,
                         workers=usable_cores()).start()
        except (FileNotFoundError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return None
        set_current_job(job)
        fs.last_result = ""
        return job

    def _finish(self, context, job, state):
        fs = context.scene.ms_teeth_fit
        if state == "FINISHED":
            copies: list[str] = []
            try:
                done, names = apply_fit_file(context, job.result_path, copies)
            except (ValueError, KeyError, OSError) as exc:
                done, names, error = [], [], f"cannot apply {job.result_path}: {exc}"
            else:
                error = no_mapping_message(names)
            job.settled = True
            if not done:  # e.g. the mapped tooth was deleted while the fit ran: say so, keep the result
                job.outcome = fs.last_result = f"finished, applied to no tooth: {job.result_path}"
                self.report({"ERROR"}, f"Teeth fit finished but applied to nothing: {error}; "
                                       f"then Apply Fit Result on {job.result_path}")
                return {"CANCELLED"}
            job.outcome = fs.last_result = f"done: applied {', '.join(done)}{copies_note(copies)}; log {job.log_path}"
            show_fit_check(fs, job.out_dir)
            self.report({"INFO"}, f"Teeth fit finished; loss plot {job.loss_plot}")
            return {"FINISHED"}
        job.outcome = f"{state.lower()}: see {job.log_path}"
        job.settled = True
        fs.last_result = job.outcome
        self.report({"WARNING" if state == "CANCELLED" else "ERROR"}, f"Teeth fit {state.lower()}: {job.last_line}")
        return {"CANCELLED"}

    def execute(self, context):  # blocking (scripts, tests, headless)
        job = self._start(context)
        if job is None:
            return {"CANCELLED"}
        return self._finish(context, job, job.wait())

    def invoke(self, context, event):
        job = self._start(context)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.5, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 1000)
        return {"RUNNING_MODAL"}

    def _cleanup(self, context):
        end_modal_progress(context, self._timer)
        self._timer = None

    def modal(self, context, event):
        job = getattr(self, "_job", None) or current_job()
        if job is None:
            self._cleanup(context)
            return {"CANCELLED"}
        if event.type == "ESC":
            job.cancel()
        if event.type in {"TIMER", "ESC"}:
            state = job.poll()  # the panel's running / progress / status read the job itself
            context.window_manager.progress_update(int(1000 * job.progress))
            if context.workspace is not None:
                context.workspace.status_text_set(job.status_text())
            for area in context.screen.areas if context.screen else ():
                area.tag_redraw()
            if state != "RUNNING":
                self._cleanup(context)
                return self._finish(context, job, state)
        return {"PASS_THROUGH"}


class MS_OT_teeth_fit_cancel(CancelBackgroundJob, bpy.types.Operator):
    """Cancel the running teeth fit (what it has done so far is kept in its folder)"""

    bl_idname = "material_structures.teeth_fit_cancel"
    bl_label = "Cancel Fit"
    job_kind = fit_job.KIND
    nothing_running = "No teeth fit is running"


class MS_OT_teeth_import_scene(FilePicker, bpy.types.Operator):
    """Import a core teeth scene (scene.json / scene_fit.json): teeth pairs, gums and oral-cavity proxy"""

    bl_idname = "material_structures.teeth_import_scene"
    bl_label = "Import Teeth Scene"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="Scene File", subtype="FILE_PATH", options=BLEND_RELATIVE,
                                       description="A teeth scene.json (or a fit's scene_fit.json): meshes and media")
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    light_paths: bpy.props.BoolProperty(name="Set Light Paths", default=True, description=LIGHT_PATHS_WORDS)

    def execute(self, context):
        from ...core.teeth.scene import load_scene

        try:
            ts = load_scene(bpy.path.abspath(self.filepath))  # "//": beside the .blend
        except (OSError, ValueError, KeyError) as exc:
            self.report({"ERROR"}, _read_error(self.filepath, exc))
            return {"CANCELLED"}
        build_teeth_scene(ts, target_collection(context), _mm_per_unit(context.scene),
                          smooth=True)
        _report_light_paths(self, context.scene)
        return {"FINISHED"}


class MS_OT_teeth_light_paths(bpy.types.Operator):
    """Raise the scene's Cycles light-path limits where they cut the teeth's scattering short (teeth render too dark
    under Blender's default limits)"""

    bl_idname = "material_structures.teeth_light_paths"
    bl_label = "Set Light Paths for Teeth"
    bl_options = {"REGISTER", "UNDO"}
    light_paths = True

    def execute(self, context):
        _report_light_paths(self, context.scene)
        return {"FINISHED"}


CLASSES: list[type] = [MS_OT_teeth_add_tooth, MS_OT_teeth_set_dentin, MS_OT_teeth_apply_fitted,
                       *GROUP_OPERATORS, MS_OT_teeth_read_capture_teeth, MS_OT_teeth_map_by_position,
                       MS_OT_teeth_apply_fit_file,
                       MS_OT_teeth_fit, MS_OT_teeth_fit_cancel,
                       MS_OT_teeth_import_scene, MS_OT_teeth_light_paths]
