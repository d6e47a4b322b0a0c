"""Scratched-metal operators: generate (modal with progress + EXEC), draw (modal + EXEC stroke replay),
import/export, sync lamps.

Every material owns its scratch set (``addon/scratch/material.py``): Generate and Import update the
active object's scratched material's own set, or give the object a new material with a new set.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable

import bpy

from ...core.errors import UserError
from ...core.scratch.scratch_io import EXR_FILES, load_scratch_set, save_kind, save_scratch_set
from ..common import (
    BLEND_RELATIVE,
    FilePicker,
    FileSaver,
    MeshUVLookup,
    SyncLamps,
    assign_material,
    end_modal_progress,
    require_uv_mesh,
    stroke_property,
    stroke_space_property,
    stroke_uvs,
)
from .editing import (
    FINE_WEAR_SIGMA_UM,
    PATTERNS,
    curves_set,
    generate_set,
    has_scratch_set,
    material_set,
    merge_sets,
    object_scratch_material,
)
from .material import (
    create_scratched_metal,
    material_scratch_group,
    sync_scratch_lamps,
    unique_set_name,
    update_scratch_group,
)

PATTERN_ITEMS = [(k, k.title(), v) for k, v in PATTERNS.items()]


def _um_range(name: str, what: str, default, lo: float, hi: float | None = None):
    """A (min, max) pair of micrometre lengths on the scratch's own scale (not a scene length: the unit is
    in the name and the tooltip); ``draw_um_range`` shows it as "Min" and "Max"."""
    kw = {} if hi is None else {"max": hi}
    return bpy.props.FloatVectorProperty(
        name=f"{name} (um)", size=2, default=default, min=lo, **kw,
        description=f"Smallest and largest {what} of a scratch, in micrometres (um); each scratch gets a "
        "random value between them",
    )


def draw_um_range(layout, op, prop: str) -> None:
    """One row of a micrometre range: its name, then its two values labelled Min and Max."""
    row = layout.row(align=True)
    row.label(text=op.bl_rna.properties[prop].name)
    row.prop(op, prop, index=0, text="Min")
    row.prop(op, prop, index=1, text="Max")


def _get_angle_deg(op) -> float:
    return math.degrees(op.angle)


def _set_angle_deg(op, value: float) -> None:
    op.angle = math.radians(max(-180.0, min(180.0, value)))


SEED_DESCRIPTION = "Random seed: the same seed and settings give the same scratches (a number, no unit)"
MODAL_MIN_COUNT = 2000  # fewer scratches take about a second or less: generated at once, no Esc needed
JOB_THREAD_NAME = "Material Structures scratch generation"


def apply_set(context, obj, scratch_set, set_name: str) -> bpy.types.Material:
    """Put ``scratch_set`` on ``obj``: update its scratched-metal material's own set, or give it a new
    material with a new set (``set_name``, made unique: no other material's set changes)."""
    mat = object_scratch_material(obj)
    group = material_scratch_group(mat) if mat is not None and mat.library is None else None
    if group is not None:
        update_scratch_group(group, scratch_set, context.scene)
    else:
        name = unique_set_name(set_name)
        mat = create_scratched_metal(f"Scratched Metal {name}", scratch_set, name, scene=context.scene)
        assign_material(obj, mat)
    sync_scratch_lamps(context.scene)
    return mat


class GenerationCancelled(Exception):
    """Raised by a job's progress callback after the user cancelled: unwinds the generator."""


class GenerateJob:
    """A scratch generation on a worker thread (core numpy code only, never bpy). ``fraction`` follows
    the generator's progress callback; :meth:`cancel` stops it at its next report (at most ~1 % of the
    work away)."""

    def __init__(self, generate: Callable[[Callable[[float], None]], object]) -> None:
        self.fraction = 0.0
        self.result = None
        self.error: Exception | None = None
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(generate,), name=JOB_THREAD_NAME, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _progress(self, fraction: float) -> None:
        if self._cancel.is_set():
            raise GenerationCancelled
        self.fraction = fraction

    def _run(self, generate) -> None:
        try:
            self.result = generate(self._progress)
        except GenerationCancelled:
            pass
        except Exception as exc:  # reported by the operator on the main thread
            self.error = exc

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def cancel(self) -> None:
        self._cancel.set()
        self._thread.join()


class MS_OT_scratch_generate(bpy.types.Operator):
    """Generate a scratch set (wear, polishing circles or hairline) on the active object's scratched metal.
    Thousands of scratches take seconds: the progress shows in the status bar, Esc cancels"""

    bl_idname = "material_structures.scratch_generate"
    bl_label = "Generate Scratches"
    bl_options = {"REGISTER", "UNDO"}

    pattern: bpy.props.EnumProperty(name="Pattern", items=PATTERN_ITEMS, default="WEAR",
                                    description="How the scratches are laid out on the patch")
    count: bpy.props.IntProperty(name="Scratches", description="Number of scratches on one patch", default=500,
                                 min=1, max=200000)
    patch_mm: bpy.props.FloatProperty(name="Patch Size (mm)", description="Side of the square patch that tiles "
                                      "the UV map, in millimetres (mm) on the object", default=20.0, min=0.5,
                                      max=1000.0)
    length_um: _um_range("Length", "length (random wear)", (300.0, 4000.0), 1.0)
    width_um: _um_range("Width", "width", (0.8, 6.0), 0.05, 100.0)
    depth_um: _um_range("Depth", "depth", (0.8, 6.0), 0.0, 100.0)
    angle: bpy.props.FloatProperty(
        name="Hairline Angle", default=0.0, min=-math.pi, max=math.pi, subtype="ANGLE",
        description="Hairline: direction of the lines, measured from the UV map's U axis toward V (degrees)",
    )
    # Before the angle had a unit it was this, in degrees: kept for scripts, stored in ``angle``.
    angle_deg: bpy.props.FloatProperty(
        name="Hairline Angle (Degrees)", min=-180.0, max=180.0, get=_get_angle_deg, set=_set_angle_deg,
        options={"HIDDEN", "SKIP_SAVE"},
        description="Hairline Angle as a plain number of degrees (for scripts written before it had a unit)",
    )
    fine_wear: bpy.props.BoolProperty(name="Fine Wear", description=f"Coherence length {FINE_WEAR_SIGMA_UM:g} um "
                                      "instead of 60 um", default=False)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0, description=SEED_DESCRIPTION)
    replace: bpy.props.BoolProperty(name="Replace", description="Replace the current set (else add to it)",
                                    default=True)
    set_name: bpy.props.StringProperty(name="Set Name", description="Name of a new material's set (made unique; "
                                       "an existing scratched material keeps its own set)", default="Scratches")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = False
        for prop in ("pattern", "count", "patch_mm"):
            layout.prop(self, prop)
        for prop in ("length_um", "width_um", "depth_um"):
            draw_um_range(layout, self, prop)
        for prop in ("angle", "fine_wear", "seed", "replace", "set_name"):
            layout.prop(self, prop)

    def _check(self, context) -> bool:
        if not require_uv_mesh(self, context.active_object):
            return False
        for label, (lo, hi) in (("length", self.length_um), ("width", self.width_um), ("depth", self.depth_um)):
            if lo > hi:
                self.report({"ERROR"}, f"{label} range is empty ({lo} > {hi})")
                return False
        return True

    def _generate(self, progress=None):
        sigma = FINE_WEAR_SIGMA_UM if self.fine_wear else 60.0
        return generate_set(self.pattern, self.count, self.patch_mm, tuple(self.length_um), tuple(self.width_um),
                            tuple(self.depth_um), self.seed, sigma, self.angle_deg, progress=progress)

    def _apply(self, context, obj, new) -> set[str]:
        try:
            current = None if self.replace else material_set(object_scratch_material(obj))
            s = merge_sets(current[1] if current else None, new)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        try:
            mat = apply_set(context, obj, s, self.set_name)
        except UserError as exc:  # e.g. a group whose script node the artist deleted
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        lost = self.count - new.n_scratches
        why = ""
        if lost > 0:  # arcs or lines that lie wholly outside the square patch are clipped away
            why = (f"; {lost} of the {self.count} generated lie wholly outside the "
                   f"{self.patch_mm:g} mm patch and were left out")
        self.report({"WARNING" if lost > 0 else "INFO"},
                    f"{s.n_scratches} scratches ({s.n_segments} segments) on '{mat.name}'{why}")
        return {"FINISHED"}

    def execute(self, context):
        """Generate at once (scripts, Adjust Last Operation): progress in the window manager's bar."""
        if not self._check(context):
            return {"CANCELLED"}
        wm = context.window_manager
        wm.progress_begin(0, 1000)
        try:
            new = self._generate(lambda f: wm.progress_update(int(1000 * f)))
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        return self._apply(context, context.active_object, new)

    # -- interactive: the generation runs beside Blender; TIMER events show its progress, Esc cancels ----
    def invoke(self, context, event):
        if self.count < MODAL_MIN_COUNT or context.window is None:
            return self.execute(context)
        if not self._start_job(context):
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _start_job(self, context) -> bool:
        if not self._check(context):
            return False
        self._obj_name = context.active_object.name
        self._timer = None
        self._job = GenerateJob(self._generate)
        self._job.start()
        context.window_manager.progress_begin(0, 1000)
        self._show(context, 0.0)
        return True

    def _show(self, context, fraction: float) -> None:
        context.window_manager.progress_update(int(1000 * fraction))
        if context.workspace is not None:
            context.workspace.status_text_set(
                f"Generating {self.count} scratches: {100 * fraction:.0f} %  (Esc cancels)")

    def _end(self, context) -> None:
        end_modal_progress(context, self._timer)
        self._timer = None

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            self._end(context)
            self.report({"WARNING"}, "Scratch generation cancelled: nothing changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        self._show(context, job.fraction)
        if not job.done:
            return {"RUNNING_MODAL"}
        self._end(context)
        if job.error is not None:
            self.report({"ERROR"}, str(job.error))
            return {"CANCELLED"}
        obj = bpy.data.objects.get(self._obj_name)
        if obj is None or job.result is None:
            self.report({"ERROR"}, f"'{self._obj_name}' is gone: the scratches were not applied")
            return {"CANCELLED"}
        return self._apply(context, obj, job.result)


class MS_OT_scratch_draw(bpy.types.Operator):
    """Draw scratches on the active object with the mouse (drag with the left button; Esc or right click when
    done)"""

    bl_idname = "material_structures.scratch_draw"
    bl_label = "Draw Scratches"
    bl_options = {"REGISTER", "UNDO"}

    stroke: stroke_property()
    stroke_space: stroke_space_property()
    width_um: _um_range("Width", "width", (2.0, 4.0), 0.05, 100.0)
    depth_um: _um_range("Depth", "depth", (1.0, 3.0), 0.0, 100.0)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0, description=SEED_DESCRIPTION)

    def draw(self, context):
        layout = self.layout
        for prop in ("width_um", "depth_um"):
            draw_um_range(layout, self, prop)
        layout.prop(self, "seed")

    @classmethod
    def poll(cls, context):
        mat = object_scratch_material(context.active_object)
        if mat is not None and mat.library is not None:  # as Blender keeps linked data from edits
            cls.poll_message_set(f"'{mat.name}' is linked from another file: make it local (Object > Relations > "
                                 "Make Local) to draw on it")
            return False
        return has_scratch_set(mat)

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
        # recorded points lie on the surface: one farther than 1 % of the object's size missed it
        points = stroke_uvs(self.stroke, self.stroke_space, obj, context.evaluated_depsgraph_get(), tolerance=0.01)
        return [uv for uv, _ in points]

    def _add_curves(self, context, obj, curves):
        mat = object_scratch_material(obj)
        found = material_set(mat)
        if found is None:
            raise ValueError(f"'{obj.name}' has no scratched-metal material")
        current = found[1]
        new = curves_set(curves, current.patch_size_um, tuple(self.width_um), tuple(self.depth_um),
                         current.sigma_um, self.seed, current.query_radius_um - 3.5 * current.sigma_um)
        if new.n_segments == 0:
            raise ValueError("the stroke adds no scratch (it lies outside the UV square [0, 1] or has no length)")
        update_scratch_group(material_scratch_group(mat), merge_sets(current, new), context.scene)

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


def is_exr_table_folder(folder: str) -> bool:
    return os.path.isdir(folder) and any(os.path.isfile(os.path.join(folder, f)) for f in EXR_FILES)


def import_source(path: str) -> str:
    """What Import reads for a picked ``path``: a folder as it is; a file inside an EXR-table folder (one
    of its tables, or a name typed into the file browser there) -> that folder; anything else as it is
    (core ``load_scratch_set`` refuses a file that is not ``.npz`` with one clear line)."""
    if os.path.isdir(path) or path.lower().endswith(".npz"):
        return path
    folder = os.path.dirname(path)
    return folder if is_exr_table_folder(folder) else path


class MS_OT_scratch_import(FilePicker, bpy.types.Operator):
    """Import a scratch set onto the active object: a .npz file, or an EXR-table folder (pick the folder or
    any table inside it)"""

    bl_idname = "material_structures.scratch_import"
    bl_label = "Import Scratch Set"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="File or Folder", subtype="FILE_PATH", options=BLEND_RELATIVE,
                                       description="A scratch set's .npz file, or its folder of EXR tables")
    set_name: bpy.props.StringProperty(name="Set Name", default="",
                                       description="Name of a new material's set (empty: the file's name)")

    def execute(self, context):
        obj = context.active_object
        if not require_uv_mesh(self, obj):
            return {"CANCELLED"}
        path = import_source(bpy.path.abspath(self.filepath))
        try:
            s = load_scratch_set(path)
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot import scratch set: {exc}")
            return {"CANCELLED"}
        name = self.set_name or os.path.splitext(os.path.basename(path.rstrip(os.sep)))[0] or "Imported"
        try:
            apply_set(context, obj, s, name)
        except UserError as exc:
            self.report({"ERROR"}, f"Cannot import scratch set: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Imported {s.n_scratches} scratches from {path}")
        return {"FINISHED"}


class MS_OT_scratch_export(FileSaver, bpy.types.Operator):
    """Export the active object's scratch set: a path ending .npz writes one file, a path without an
    extension a folder of EXR tables; any other extension is refused"""

    bl_idname = "material_structures.scratch_export"
    bl_label = "Export Scratch Set"
    bl_options = {"REGISTER"}

    filepath: bpy.props.StringProperty(
        name="File", subtype="FILE_PATH", options=BLEND_RELATIVE,
        description="Where to write: a path ending .npz writes one file, a path without an extension a folder "
        "of EXR tables",
    )
    filename_ext = ".npz"
    check_extension = None  # a path without an extension writes a folder of EXR tables: keep it as typed

    @classmethod
    def poll(cls, context):
        return object_scratch_material(context.active_object) is not None

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = "scratches.npz"
        return super().invoke(context, event)

    def execute(self, context):
        found = material_set(object_scratch_material(context.active_object))
        if found is None:
            self.report({"ERROR"}, "The active object has no scratch set")
            return {"CANCELLED"}
        path = bpy.path.abspath(self.filepath)
        kind = save_kind(path)
        if kind not in ("npz", "folder"):
            self.report({"ERROR"}, f"Cannot export to a '{kind}' file extension: use .npz for one file, or a "
                        "folder path without an extension for EXR tables")
            return {"CANCELLED"}
        try:
            save_scratch_set(path, found[1])
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"Cannot export scratch set: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Exported {found[1].n_scratches} scratches to {path}")
        return {"FINISHED"}


class MS_OT_scratch_sync_lamps(SyncLamps, bpy.types.Operator):
    """Copy the scene's lights into the scratched-metal shaders now (normally automatic)"""

    bl_idname = "material_structures.scratch_sync_lamps"
    bl_label = "Sync Scratch Lights"
    sync = staticmethod(sync_scratch_lamps)
    evaluated_by = "by the scratch term"


CLASSES: list[type] = [
    MS_OT_scratch_generate,
    MS_OT_scratch_draw,
    MS_OT_scratch_import,
    MS_OT_scratch_export,
    MS_OT_scratch_sync_lamps,
]
