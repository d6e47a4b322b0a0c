"""Operators (``bl_idname`` under ``material_structures.``)."""

from . import fabric, fabric_brush, scene_setup

CLASSES: list[type] = [*scene_setup.CLASSES, *fabric.CLASSES, *fabric_brush.CLASSES]
