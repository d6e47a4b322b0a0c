"""The Blender layer: translates between Blender data and ``core`` arrays.

One folder per feature (``fabric/``, ``scratch/``, ``teeth/``), each with its ``operators.py``,
``panels.py``, ``properties.py`` beside the modules that do the work; what the features share is in
``common.py`` (and ``lamp_sync.py``); what belongs to the whole add-on is in the modules here.

One ``CLASSES`` list, registered in one place (here), gathered from each module's own ``CLASSES``. Order
matters: property groups before the classes that point at them, the sidebar's parent panel before its
children.
"""

from __future__ import annotations

import atexit

import bpy

from . import background_job, common, handlers, nodes, operators, panels, preferences, properties
from .fabric import operators as fabric_operators
from .fabric import panels as fabric_panels
from .fabric import properties as fabric_properties
from .scratch import operators as scratch_operators
from .scratch import panels as scratch_panels
from .teeth import operators as teeth_operators
from .teeth import panels as teeth_panels
from .teeth import properties as teeth_properties

CLASSES: list[type] = [
    # property groups: the features' first, MS_SceneSettings points at them
    *common.CLASSES,
    *fabric_properties.CLASSES,
    *teeth_properties.CLASSES,
    *properties.CLASSES,
    *preferences.CLASSES,
    # operators
    *operators.CLASSES,
    *fabric_operators.CLASSES,
    *teeth_operators.CLASSES,
    *scratch_operators.CLASSES,
    *nodes.CLASSES,
    # panels: the sidebar tab first (the fabric's panel is its child)
    *panels.CLASSES,
    *fabric_panels.CLASSES,
    *teeth_panels.CLASSES,
    *scratch_panels.CLASSES,
]


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register_pointers()
    teeth_properties.register_pointers()
    nodes.register_menus()
    handlers.register_handlers()
    atexit.register(background_job.stop_at_exit)  # a fit running when Blender quits stops with it


def unregister() -> None:
    background_job.stop_all()  # running fits, and the timers that would apply their results, go with the buttons
    atexit.unregister(background_job.stop_at_exit)
    handlers.unregister_handlers()
    nodes.unregister_menus()
    teeth_properties.unregister_pointers()
    properties.unregister_pointers()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
