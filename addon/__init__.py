"""The Blender layer: translates between Blender data and ``core`` arrays.

One ``CLASSES`` list, registered in one place (here). Feature modules under ``operators/``,
``nodes/`` and ``panels/`` each expose their own ``CLASSES``; order matters (property groups
before the classes that point at them).
"""

from __future__ import annotations

import bpy

from . import handlers, nodes, operators, panels, preferences, properties

CLASSES: list[type] = [
    *properties.CLASSES,
    *preferences.CLASSES,
    *operators.CLASSES,
    *nodes.CLASSES,
    *panels.CLASSES,
]


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register_pointers()
    nodes.register_menus()
    handlers.register_handlers()


def unregister() -> None:
    handlers.unregister_handlers()
    nodes.unregister_menus()
    properties.unregister_pointers()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
