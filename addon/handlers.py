"""App handlers: each feature's (``<feature>/handlers.py``: lamps kept current in the shaders that
evaluate them, so moving a lamp just works) and the embedded shaders brought up to date after a file
is loaded. Registered in this order: within one handler list, the fabric's run before the scratches'."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from ..render.osl import refresh_embedded_scripts
from .fabric.handlers import FABRIC_HANDLERS, sync_fabric_after_load
from .scratch.handlers import SCRATCH_HANDLERS


@persistent
def on_load_post(*_args) -> None:
    """Shaders are embedded in the file; bring files from older versions (or an older extension) up to date."""
    refresh_embedded_scripts()  # compiles under Cycles + OSL lent to the scene, its own engine restored
    sync_fabric_after_load()  # the world tables live in the temp folder: re-extract them for this file


HANDLERS = [*FABRIC_HANDLERS, (bpy.app.handlers.load_post, on_load_post), *SCRATCH_HANDLERS]


def register_handlers() -> None:
    for handler_list, fn in HANDLERS:
        if fn not in handler_list:
            handler_list.append(fn)


def unregister_handlers() -> None:
    for handler_list, fn in HANDLERS:
        while fn in handler_list:
            handler_list.remove(fn)
