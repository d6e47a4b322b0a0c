"""Handlers of the fabric shader: lamp and world sync (depsgraph, render_pre: moving a lamp just works), the brush
sessions' maps packed before a save and dropped when another file is loaded."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .brushing import drop_sessions, pack_sessions
from .material import fabric_script_nodes, has_fabric_links, sync_fabric_lamps

# Updates that can change which lamps the fabric evaluates or which objects wear it: lamps, objects,
# meshes (material slots on the data), materials and their node trees (the fabric group unlinked), the
# scene (render engine, OSL switch) and the world (its environment is the exact world light's).
_FABRIC_UPDATES = (bpy.types.Light, bpy.types.Object, bpy.types.Mesh, bpy.types.Material, bpy.types.NodeTree,
                   bpy.types.Scene, bpy.types.World)


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


def sync_fabric_after_load() -> None:
    """After a file is loaded (and its shaders refreshed): lamps and world into the fabric shaders."""
    scene = bpy.context.scene
    if scene is not None and _has_fabric():
        sync_fabric_lamps(scene, update_matrices=False)


@persistent
def on_save_pre(*_args) -> None:
    """Pack painted fabric maps that changed since their last pack (a save in the middle of a stroke)."""
    pack_sessions()


@persistent
def on_load_pre(*_args) -> None:
    """Brush sessions hold the images of the file being closed: drop them."""
    drop_sessions()


FABRIC_HANDLERS = [
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.render_pre, on_render_pre),
    (bpy.app.handlers.save_pre, on_save_pre),
    (bpy.app.handlers.load_pre, on_load_pre),
]
