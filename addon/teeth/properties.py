"""Per-object tooth settings (``Object.ms_tooth``): saved in the .blend, undone with it.

The dentin coefficients c (eq. 5.5) are the values of the enamel object's settings; changing one
writes the shape-key values of both the dentin core and the enamel shell's inner surface, so the
viewport mesh follows immediately. ``fitted`` keeps the last fit's coefficients (applied on demand).
Slider range: the optimiser's clamp range of c (core.teeth.param_vector.RANGES["c"], +-0.8: one unit
moves the extreme dentin points by 1 mm, see core.teeth.dentin_blend_shapes.canonical_modes).
"""

from __future__ import annotations

import os

import bpy

from ...core.teeth.dentin_blend_shapes import MODE_NAMES
from ...core.teeth.fit_settings import FitSettings
from ...core.teeth.param_vector import RANGES
from .fit_job import current_job, job_running
from .scene_build import capture_tooth_names, fill_tooth_map

C_MIN, C_MAX = RANGES["c"]
ROLE_ITEMS = [("NONE", "None", ""), ("ENAMEL", "Enamel", "Enamel shell of a tooth"),
              ("DENTIN", "Dentin", "Dentin core of a tooth"), ("GUMS", "Gums", "Gingiva"),
              ("CAVITY", "Oral Cavity", "Stand-in for the oral cavity behind the teeth"),
              ("BLEND", "Blend Volume", "The gradual change from enamel to dentin inside a tooth: the volume that "
               "renders it")]


def owner(obj):
    """The enamel object that owns the tooth settings of ``obj`` (itself, or its partner)."""
    if obj is None or not hasattr(obj, "ms_tooth"):
        return None
    st = obj.ms_tooth
    if st.role == "ENAMEL":
        return obj
    if st.role == "DENTIN" and st.partner is not None and st.partner.ms_tooth.role == "ENAMEL":
        return st.partner
    return None


def _apply_keys(obj, values) -> None:
    keys = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    if keys is None:
        return
    for name, v in zip(MODE_NAMES, values, strict=True):
        kb = keys.key_blocks.get(name)
        if kb is not None and abs(kb.value - v) > 0.0:
            kb.value = v


def _update_coefficients(self, context) -> None:
    obj = self.id_data
    values = (self.buccal, self.proximal, self.occlusal)
    _apply_keys(obj, values)
    if self.partner is not None:
        _apply_keys(self.partner, values)


def _coefficient(name: str, desc: str):
    desc += (" (a dentin shape coefficient: no unit; 1 moves the dentin surface by up to 1 mm, "
             "0 is the template's shape)")
    return bpy.props.FloatProperty(name=name, description=desc, default=0.0, min=C_MIN, max=C_MAX,
                                   soft_min=C_MIN, soft_max=C_MAX, step=1, precision=3,
                                   update=_update_coefficients)


class MS_ToothSettings(bpy.types.PropertyGroup):
    role: bpy.props.EnumProperty(name="Role", items=ROLE_ITEMS, default="NONE",
                                 description="Which part of a tooth this object is (set by Add Tooth)")
    kind: bpy.props.StringProperty(name="Tooth Type", default="",
                                   description="The tooth template this object was made from (e.g. INCISOR)")
    tooth_name: bpy.props.StringProperty(name="Tooth Name",
                                         description="Name of the tooth in teeth scene files and fits")
    partner: bpy.props.PointerProperty(name="Partner", type=bpy.types.Object,
                                       description="The dentin core of an enamel shell, and vice versa")
    mm_per_unit: bpy.props.FloatProperty(name="mm per Unit", default=1000.0, min=1e-6,
                                         description="Millimetres per Blender unit (1000: the scene is in metres; "
                                                     "1: one unit is one millimetre); scales the media's 1/mm "
                                                     "coefficients")
    buccal: _coefficient("Buccal", "How far the dentin bulges toward the cheek or tongue side")
    proximal: _coefficient("Proximal", "How far the dentin bulges toward the neighbouring teeth")
    occlusal: _coefficient("Occlusal", "How far the dentin reaches toward the biting edge")
    fitted: bpy.props.FloatVectorProperty(name="Fitted c", size=3, default=(0.0, 0.0, 0.0),
                                          description="Dentin shape found by the last fit")
    has_fit: bpy.props.BoolProperty(name="Has Fit", default=False,
                                     description="Whether fitted values from a capture were applied to this tooth")
    fit_source: bpy.props.StringProperty(name="Fit Source", default="", subtype="FILE_PATH",
                                         description="The fit result (scene_fit.json) whose values this tooth wears")

    def coefficients(self) -> tuple[float, float, float]:
        return (self.buccal, self.proximal, self.occlusal)

    def set_coefficients(self, c) -> None:
        self.buccal, self.proximal, self.occlusal = (float(x) for x in c)
        _update_coefficients(self, None)


FIT_DEFAULTS = FitSettings()  # the panel's defaults are the fit's own (tests/blender/test_teeth_fit.py)
CHECK_IMAGE_NAME = "Teeth Fit Check"  # the Image datablock showing the last fit's held-out check


def _get_running(_self) -> bool:
    return job_running()


def _get_progress(_self) -> float:
    job = current_job()
    return 0.0 if job is None else float(job.progress)


def _get_status(self) -> str:
    job = current_job()
    if job is not None and job.is_alive():
        return job.status_text()
    if job is not None and not job.settled:  # ended with no one to apply it (e.g. a file was opened meanwhile)
        return job.ended_text()
    return self.last_result


def _is_enamel(_self, obj) -> bool:
    return getattr(obj, "ms_tooth", None) is not None and obj.ms_tooth.role == "ENAMEL"


class MS_TeethFitToothMap(bpy.types.PropertyGroup):
    """One capture tooth and the tooth of the scene its fit is applied to."""

    capture_tooth: bpy.props.StringProperty(name="Capture Tooth",
                                            description="The tooth's name in the capture's scene.json")
    enamel: bpy.props.PointerProperty(name="Tooth", type=bpy.types.Object, poll=_is_enamel,
                                      description="The tooth of this scene (its enamel) that the fit of this "
                                                  "capture tooth is applied to")


def _capture_dir_changed(self, _context) -> None:
    """Setting the capture folder reads its teeth into the mapping (left as it was when there are none)."""
    try:
        names = capture_tooth_names(bpy.path.abspath(self.capture_dir))
    except (OSError, ValueError, KeyError, TypeError):
        return
    fill_tooth_map(self.id_data, names)


def fit_out_dir(fs) -> str:
    """The fit's output folder: the panel's Output, else the capture folder's ``fit``."""
    return bpy.path.abspath(fs.out_dir) if fs.out_dir else os.path.join(bpy.path.abspath(fs.capture_dir), "fit")


class MS_TeethFitSettings(bpy.types.PropertyGroup):
    """Scene-wide settings of the fitting operator (``Scene.ms_teeth_fit``)."""

    capture_dir: bpy.props.StringProperty(name="Capture", subtype="DIR_PATH", update=_capture_dir_changed,
                                          description="Capture folder (capture.json, images/, masks/, scene.json)")
    tooth_map: bpy.props.CollectionProperty(type=MS_TeethFitToothMap, name="Capture Teeth",
                                            description="Which tooth of this scene each capture tooth's fit "
                                                        "is applied to")
    out_dir: bpy.props.StringProperty(name="Output", subtype="DIR_PATH",
                                      description="Fit folder: log, loss plot, checkpoint, scene_fit.json")
    iterations: bpy.props.IntProperty(name="Iterations", default=FIT_DEFAULTS.iterations, min=1, max=100000,
                                      description="Fit iterations (5-20 s each for a 3-camera capture on 2 cores; "
                                                  "fewer: a quicker, rougher fit)")
    init: bpy.props.EnumProperty(name="Start", default="LITERATURE",
                                 description="Where the fit starts its search", items=[
        ("LITERATURE", "Literature", "Best match among published tooth measurements"),
        ("SCENE", "Scene", "The values in the capture's scene.json"),
        ("PERTURBED", "Perturbed", "The capture's scene.json values, perturbed (for testing the fit)")])
    check_image: bpy.props.StringProperty(name="Check Image", default="", subtype="FILE_PATH",
                                          description="The last fit's held-out lights: capture | fit | difference")
    check_error: bpy.props.StringProperty(name="Held-out Error", default="",
                                          description="The last fit's error on lights it never used")
    check_intervals: bpy.props.StringProperty(
        name="What the Capture Determines", default="",
        description="How many of the last fit's parameters the capture determines (fit_report.json)")
    check_parameters: bpy.props.StringProperty(
        name="Fitted Parameters", default="",
        description="The last fit's parameters, one per line: value and 2-sigma interval, measured or open")
    check_open: bpy.props.StringProperty(
        name="Left Open", default="",
        description="What the last fit's capture leaves open, one trade-off per line, in words")
    show_check_parameters: bpy.props.BoolProperty(
        name="Parameters and Intervals", default=False,
        description="Show each fitted parameter with its interval, and what the capture leaves open")
    # Job state: read from this Blender session's background fit, never stored in the .blend (a file saved
    # while a fit ran reopens idle). ``last_result`` is what became of the last fit, kept with the file.
    running: bpy.props.BoolProperty(name="Running", get=_get_running,
                                    description="A teeth fit of this Blender session is running")
    progress: bpy.props.FloatProperty(name="Progress", min=0.0, max=1.0, subtype="FACTOR", get=_get_progress,
                                      description="Iterations done of the running (or last) fit of this session")
    status: bpy.props.StringProperty(name="Status", get=_get_status,
                                     description="The running fit's iteration and loss, else the last fit's result")
    last_result: bpy.props.StringProperty(name="Last Fit", default="",
                                          description="What became of the last fit started from this scene")


CLASSES: list[type] = [MS_ToothSettings, MS_TeethFitToothMap, MS_TeethFitSettings]


def register_pointers() -> None:
    bpy.types.Object.ms_tooth = bpy.props.PointerProperty(type=MS_ToothSettings)
    bpy.types.Scene.ms_teeth_fit = bpy.props.PointerProperty(type=MS_TeethFitSettings)


def unregister_pointers() -> None:
    del bpy.types.Scene.ms_teeth_fit
    del bpy.types.Object.ms_tooth
