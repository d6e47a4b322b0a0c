"""Register the shipped material library in the user's asset libraries (Asset Browser)."""

from __future__ import annotations

import os

import bpy

LIBRARY_NAME = "Material Structures"
LIBRARY_DIR = os.path.join(
    os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "samples", "library"
)


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


CLASSES: list[type] = [MS_OT_register_asset_library]
