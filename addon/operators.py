"""Switch the scene to what the Material Structures shaders need: Cycles with OSL on the CPU."""

from __future__ import annotations

import bpy


def osl_ready(scene) -> bool:
    return scene.render.engine == "CYCLES" and bool(getattr(scene.cycles, "shading_system", False))


class MS_OT_setup_cycles_osl(bpy.types.Operator):
    """Use Cycles with Open Shading Language on the CPU (needed by the exact fabric and scratch shaders)"""

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


CLASSES: list[type] = [MS_OT_setup_cycles_osl]
