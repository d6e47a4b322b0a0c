"""Operators of the whole add-on (``bl_idname`` under ``material_structures.``): switch the scene to Cycles
with OSL on the CPU (what the shaders need), register the shipped material library in the Asset Browser.
Each feature's own operators are in ``<feature>/operators.py``."""

from __future__ import annotations

import os

import bpy

LIBRARY_NAME = "Material Structures"
LIBRARY_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "samples", "library")


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


CLASSES: list[type] = [MS_OT_setup_cycles_osl, MS_OT_register_asset_library]
