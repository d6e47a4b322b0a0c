"""Operators (``bl_idname`` under ``material_structures.``)."""

from . import fabric, scene_setup

CLASSES: list[type] = [*scene_setup.CLASSES, *fabric.CLASSES]
