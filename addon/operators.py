"""Operators of the whole add-on (``bl_idname`` under ``material_structures.``): switch the scene to Cycles
with OSL on the CPU (what the shaders need), register the shipped material library in the Asset Browser, put the
shipped sample data into a panel (``use_sample``). Each feature's own operators are in ``<feature>/operators.py``."""

from __future__ import annotations

import os

import bpy

LIBRARY_NAME = "Material Structures"
SAMPLES_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "samples")
LIBRARY_DIR = os.path.join(SAMPLES_DIR, "library")
# the sample data shipped in samples/ (scripts/make_samples.py writes it): the use_sample choice -> its folder
SAMPLE_FOLDERS = {"BTF": "fabric_btf", "CAPTURE": "teeth_capture", "STATES": "brush_states"}


def osl_ready(scene) -> bool:
    return scene.render.engine == "CYCLES" and bool(getattr(scene.cycles, "shading_system", False))


class MS_OT_setup_cycles_osl(bpy.types.Operator):
    """Render this scene with Cycles and Open Shading Language on the CPU: the exact fabric, scratch and enamel
    shaders (without it they render their closure path). Changes the scene's render engine, device and shading
    system"""

    bl_idname = "material_structures.setup_cycles_osl"
    bl_label = "Use Cycles + OSL"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.shading_system = True
        self.report({"INFO"}, "Cycles with OSL (CPU) enabled")
        return {"FINISHED"}


def library_registered(prefs=None) -> bool:
    prefs = prefs or bpy.context.preferences
    return any(os.path.normpath(lib.path) == os.path.normpath(LIBRARY_DIR) for lib in prefs.filepaths.asset_libraries)


class MS_OT_register_asset_library(bpy.types.Operator):
    """Add the Material Structures material library to Preferences > File Paths > Asset Libraries"""

    bl_idname = "material_structures.register_asset_library"
    bl_label = "Register Material Library"
    bl_options = {"REGISTER"}

    def execute(self, context):
        if not os.path.isfile(os.path.join(LIBRARY_DIR, "material_structures_library.blend")):
            self.report({"ERROR"}, f"The library is not built: {LIBRARY_DIR} (run `make library`)")
            return {"CANCELLED"}
        prefs = context.preferences
        if library_registered(prefs):
            self.report({"INFO"}, "The Material Structures library is already registered")
            return {"FINISHED"}
        prefs.filepaths.asset_libraries.new(name=LIBRARY_NAME, directory=LIBRARY_DIR)
        prefs.is_dirty = True
        self.report({"INFO"}, "Registered: drag materials from the Asset Browser (Material Structures library)")
        return {"FINISHED"}


SAMPLE_ITEMS = [
    ("BTF", "Fit Sample BTF", "Fit the sample BTF (16 x 16 texels, 8 lights x 8 views) as Fit BTF does and give the "
                              "active mesh the fitted fabric material; the maps go to the extension's user folder"),
    ("CAPTURE", "Sample Capture", "Set Fit to capture's folder to the sample capture (one tooth, one camera, 4 "
                                  "lights) and its output to the extension's user folder; imports the capture's "
                                  "tooth when no tooth of the scene has its name"),
    ("STATES", "Sample States", "Set the brush's Data-Driven states to the sample states (state_0 ... state_7: "
                                "fibres brushed toward 0, 45, ... 315 degrees)"),
]


def sample_path(sample: str) -> str:
    """The installed extension's folder of ``sample`` (a key of ``SAMPLE_FOLDERS``)."""
    return os.path.join(SAMPLES_DIR, SAMPLE_FOLDERS[sample])


def sample_fit_dir(name: str) -> str:
    """A writable folder for a fit of a sample (never inside the installed extension, which an update replaces):
    the extension's user folder (``extension_path_user``), else Blender's user data folder."""
    package = __package__.rpartition(".")[0]
    try:
        base = bpy.utils.extension_path_user(package, path="sample_fits", create=True)
    except (ValueError, AttributeError, OSError):  # not loaded as an extension (a script, an old Blender)
        base = bpy.utils.user_resource("DATAFILES", path=os.path.join("material_structures", "sample_fits"),
                                       create=True)
    return os.path.join(base, name)


class MS_OT_use_sample(bpy.types.Operator):
    """Try a panel on the sample data shipped with the extension: fit the sample BTF, fill the Teeth panel's
    capture folder with the sample capture (importing its tooth), or fill the brush's Data-Driven states folder"""

    bl_idname = "material_structures.use_sample"
    bl_label = "Open Sample"
    bl_options = {"REGISTER", "UNDO"}

    sample: bpy.props.EnumProperty(name="Sample", default="CAPTURE", items=SAMPLE_ITEMS,
                                   description="Which sample data to use")

    @classmethod
    def description(cls, context, properties):
        return next(d for k, _n, d in SAMPLE_ITEMS if k == properties.sample)

    def execute(self, context):
        folder = sample_path(self.sample)
        if not os.path.isdir(folder):
            self.report({"ERROR"}, f"The sample is not installed: {folder} (run `make samples`)")
            return {"CANCELLED"}
        scene = context.scene
        if self.sample == "BTF":  # Fit BTF on the sample (its reports are the fit's)
            if not bpy.ops.material_structures.fabric_fit_btf.poll():
                self.report({"ERROR"}, "A fabric fit is already running")
                return {"CANCELLED"}
            return self._call(bpy.ops.material_structures.fabric_fit_btf, directory=folder,
                              out_dir=sample_fit_dir("fabric_btf_fit"))
        if self.sample == "STATES":
            scene.material_structures.fabric_brush.states_dir = folder
            self.report({"INFO"}, f"Data-Driven states: {folder}")
            return {"FINISHED"}
        from .teeth.scene_build import capture_tooth_names, fill_tooth_map

        fs = scene.ms_teeth_fit
        fs.capture_dir = folder  # its update reads the capture's teeth into the mapping
        fs.out_dir = sample_fit_dir("teeth_capture_fit")
        if not fs.tooth_map or any(m.enamel is None for m in fs.tooth_map):
            res = self._call(bpy.ops.material_structures.teeth_import_scene,
                             filepath=os.path.join(folder, "scene.json"))
            if res != {"FINISHED"}:
                return res
            fill_tooth_map(scene, capture_tooth_names(folder))
        self.report({"INFO"}, f"Sample capture: {folder}; fit output: {fs.out_dir}")
        return {"FINISHED"}

    def _call(self, operator, **props) -> set[str]:
        """Run another operator of the add-on; its error (a report, raised when called from Python) is this one's."""
        try:
            return operator(**props)
        except RuntimeError as exc:
            self.report({"ERROR"}, str(exc).removeprefix("Error: ").strip())
            return {"CANCELLED"}


CLASSES: list[type] = [MS_OT_setup_cycles_osl, MS_OT_register_asset_library, MS_OT_use_sample]
