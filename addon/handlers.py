"""App handlers: each feature's (``<feature>/handlers.py``: lamps kept current in the shaders that
evaluate them, so moving a lamp just works; a tooth's Blend Volume kept on the materials the tooth
wears), the embedded shaders brought up to date after a file is loaded, and images that match their
stored data after an undo or redo. Registered in this order: within one handler list, the world images' (an edited
environment image is read again) first, then the fabric's, the scratches', the teeth's."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from ..render.osl import refresh_embedded_scripts
from .common import reload_stale_images
from .fabric.brushing import drop_sessions
from .fabric.handlers import FABRIC_HANDLERS, sync_fabric_after_load
from .fabric.material import MARKER as FABRIC_MARKER
from .fabric.material import ensure_closures_without_osl
from .scratch.handlers import SCRATCH_HANDLERS
from .scratch.material import MARKER as SCRATCH_MARKER
from .scratch.material import ensure_base_metal
from .teeth.blend_volume import upgrade_after_load as upgrade_teeth_after_load
from .teeth.handlers import TEETH_HANDLERS
from .world_environment import forget_edits, forget_packed


@persistent
def on_image_update(_scene, depsgraph) -> None:
    """An image updated (painted, its pixels set and tagged): a world that shows it is read again."""
    for update in depsgraph.updates:
        if isinstance(update.id, bpy.types.Image):
            forget_edits(update.id.original)


@persistent
def on_render_forget_edits(*_args) -> None:
    """Every render reads the pixels of an edited world image again (edits from Python need no update tag)."""
    forget_edits()


@persistent
def on_load_post(*_args) -> None:
    """Shaders are embedded in the file; bring files from older versions (or an older extension) up to date."""
    global _loaded_since_register
    _loaded_since_register = True
    refresh_embedded_scripts()  # compiles under Cycles + OSL lent to the scene, its own engine restored
    for group in bpy.data.node_groups:  # groups of older files: the closures that render without OSL
        if group.library is None and group.get(FABRIC_MARKER):
            ensure_closures_without_osl(group)
        elif group.library is None and group.get(SCRATCH_MARKER):
            ensure_base_metal(group)
    forget_edits()  # the pixel digests name images of the file before
    forget_packed()
    sync_fabric_after_load()  # the world tables live in the temp folder: re-extract them for this file
    upgrade_teeth_after_load()  # the teeth's node layouts of older files


@persistent
def on_undo_redo_post(*_args) -> None:
    """After Ctrl+Z / Ctrl+Shift+Z: images show what the restored file stores (painted maps, scratch tables),
    and the brush sessions, which hold images the undo replaced, start again from the images."""
    reload_stale_images()
    drop_sessions()
    forget_edits()  # the restored images' pixels
    forget_packed()


# The world images' digests are dropped before the fabric's and the scratches' handlers read the world.
WORLD_HANDLERS = [(bpy.app.handlers.depsgraph_update_post, on_image_update),
                  (bpy.app.handlers.render_pre, on_render_forget_edits)]
HANDLERS = [*WORLD_HANDLERS, *FABRIC_HANDLERS, (bpy.app.handlers.load_post, on_load_post), *SCRATCH_HANDLERS,
            *TEETH_HANDLERS, (bpy.app.handlers.undo_post, on_undo_redo_post),
            (bpy.app.handlers.redo_post, on_undo_redo_post)]


def after_enable() -> None:
    """The extension enabled with a file open (installed, enabled or updated during a session): the file gets the
    work opening it would have done (its shaders brought up to date, the scratch tables and world tables
    extracted, the teeth's layouts upgraded). Run once by a timer (with a window; scripts enable the extension
    before they open files): while an extension registers, Blender keeps ``bpy.data`` from it. Not where a file
    was opened since (Blender's start: the extensions register, then the startup file loads)."""
    if _loaded_since_register:
        return
    for handler_list, fn in HANDLERS:
        if handler_list is bpy.app.handlers.load_post:
            fn()
    # an undo step of the file as brought up to date, for Ctrl+Z to return to (an opened file's first step is
    # recorded after its load handlers ran)
    if bpy.ops.ed.undo_push.poll():
        bpy.ops.ed.undo_push(message="Material Structures: file brought up to date")


_loaded_since_register = False


def register_handlers() -> None:
    global _loaded_since_register
    _loaded_since_register = False
    for handler_list, fn in HANDLERS:
        if fn not in handler_list:
            handler_list.append(fn)
    # not without a window: no event loop runs the timer there, and a timer left registered keeps the bpy module
    # alive through Python's teardown, where bpy 4.5's exit then hangs (its delayed-close thread)
    if not bpy.app.background and not bpy.app.timers.is_registered(after_enable):
        bpy.app.timers.register(after_enable, first_interval=0.0)


def unregister_handlers() -> None:
    for handler_list, fn in HANDLERS:
        while fn in handler_list:
            handler_list.remove(fn)
    if bpy.app.timers.is_registered(after_enable):
        bpy.app.timers.unregister(after_enable)
