"""Operators (``bl_idname`` under ``material_structures.``)."""

from . import asset_library, fabric, fabric_brush, scene_setup, scratch, teeth

CLASSES: list[type] = [
    *scene_setup.CLASSES,
    *asset_library.CLASSES,
    *fabric.CLASSES,
    *fabric_brush.CLASSES,
    *teeth.CLASSES,
    *scratch.CLASSES,
]
