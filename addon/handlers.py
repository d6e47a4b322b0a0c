"""App handlers: keep lamp data in the exact-path shaders current (moving a lamp just works), embedded
shaders current after loading a file."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .fabric.material import fabric_script_nodes, has_fabric_links, sync_fabric_lamps

# Updates that can change which lamps the fabric evaluates or which objects wear it: lamps, objects,
# meshes (material slots on the data), materials, and the scene (render engine, OSL switch).
_FABRIC_UPDATES = (bpy.types.Light, bpy.types.Object, bpy.types.Mesh, bpy.types.Material, bpy.types.Scene)


def _has_fabric() -> bool:
    return next(fabric_script_nodes(), None) is not None or has_fabric_links()


@persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    if not _has_fabric():
        return
    for update in depsgraph.updates:
        idb = update.id
        is_other_object = isinstance(idb, bpy.types.Object) and idb.type not in {"LIGHT", "MESH"}
        if isinstance(idb, _FABRIC_UPDATES) and not is_other_object:
            sync_fabric_lamps(scene, update_matrices=False)
            return


@persistent
def on_render_pre(scene, *_args) -> None:
    if _has_fabric():
        sync_fabric_lamps(scene, update_matrices=False)


@persistent
def on_save_pre(*_args) -> None:
    """Pack painted fabric maps that changed since their last pack (a save in the middle of a stroke)."""
    from .operators.fabric_brush import pack_sessions

    pack_sessions()


@persistent
def on_load_pre(*_args) -> None:
    """Brush sessions hold the images of the file being closed: drop them."""
    from .operators.fabric_brush import drop_sessions

    drop_sessions()


@persistent
def on_load_post(*_args) -> None:
    """Shaders are embedded in the file; bring files from older versions (or an older extension) up to date."""
    from ..render.osl import refresh_embedded_scripts

    refresh_embedded_scripts()  # compiles under Cycles + OSL lent to the scene, its own engine restored


HANDLERS = [
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.render_pre, on_render_pre),
    (bpy.app.handlers.load_post, on_load_post),
    (bpy.app.handlers.save_pre, on_save_pre),
    (bpy.app.handlers.load_pre, on_load_pre),
]

from .scratch.handlers import SCRATCH_HANDLERS  # noqa: E402  (scratched metal: lamps, table cache)

HANDLERS += SCRATCH_HANDLERS


def register_handlers() -> None:
    for handler_list, fn in HANDLERS:
        if fn not in handler_list:
            handler_list.append(fn)


def unregister_handlers() -> None:
    for handler_list, fn in HANDLERS:
        while fn in handler_list:
            handler_list.remove(fn)
