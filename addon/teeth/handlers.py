"""Handlers of the teeth: a tooth's Blend Volume follows the materials its enamel and dentin wear (depsgraph,
render_pre; after a file is opened and after an undo or redo, every tooth), so a material the artist assigns, e.g.
a library Dentin Shade, renders as that material."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .blend_volume import follow_materials, follow_places, sync_spreads
from .materials import gate_for_linking, ungate_local


def _enamel_of(obj):
    ms = getattr(obj, "ms_tooth", None)
    if ms is None:
        return None
    if ms.role == "ENAMEL":
        return obj
    return ms.partner if ms.role == "DENTIN" else None


_scene_counts: dict = {}  # scene -> objects in its own (master) collection, at the last look


def _scene_objects_changed() -> bool:
    """Whether an object joined or left a scene's own collection since the last look (a few microseconds: a
    selection click, which updates the scene too, does not scan every object)."""
    counts = {sc.name_full: len(sc.collection.objects) for sc in bpy.data.scenes}
    changed = counts != _scene_counts
    _scene_counts.clear()
    _scene_counts.update(counts)
    return changed


@persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    enamels = {}
    places = False
    for update in depsgraph.updates:
        if isinstance(update.id, bpy.types.Object):
            enamel = _enamel_of(update.id.original)
            if enamel is not None:
                enamels[enamel.name_full] = enamel
        elif isinstance(update.id, bpy.types.Collection):
            places = True  # objects deleted, moved between collections, linked into one
        elif isinstance(update.id, bpy.types.Scene):
            places |= _scene_objects_changed()  # linked into a scene's own collection; not a selection click
    if places:
        follow_places()
    if enamels:
        follow_materials(enamels.values())


@persistent
def on_depsgraph_update_pre(*_args) -> None:
    """A spread edited (or keyframed) in a Blend Volume's material: its grids' band, evaluated in this update; also
    before a frame is evaluated (frame_change_pre), for keyframes set by a script without an update since."""
    sync_spreads()


@persistent
def on_render_pre(scene, *_args) -> None:
    follow_places()
    follow_materials([o for o in scene.objects if _enamel_of(o) is o])
    sync_spreads()


@persistent
def on_file_change(*_args) -> None:
    """A file opened (one saved before the handlers, or by a Blender without the extension) or restored by undo."""
    ungate_local()  # written gated (on_save_pre)
    follow_places()
    follow_materials([o for o in bpy.data.objects if _enamel_of(o) is o])
    sync_spreads()


@persistent
def on_save_pre(*_args) -> None:
    """The file as written: its Enamel/Dentin groups read the tooth object's property (``materials.set_gate``), so
    that a shade another file links from it hands its medium to that tooth's Blend Volume."""
    gate_for_linking()


@persistent
def on_save_post(*_args) -> None:
    """Written (or the write failed): the file in memory leaves the property out again."""
    ungate_local()


TEETH_HANDLERS = [
    (bpy.app.handlers.save_pre, on_save_pre),
    (bpy.app.handlers.save_post, on_save_post),
    (bpy.app.handlers.save_post_fail, on_save_post),
    (bpy.app.handlers.depsgraph_update_pre, on_depsgraph_update_pre),
    (bpy.app.handlers.frame_change_pre, on_depsgraph_update_pre),
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.render_pre, on_render_pre),
    (bpy.app.handlers.load_post, on_file_change),
    (bpy.app.handlers.undo_post, on_file_change),
    (bpy.app.handlers.redo_post, on_file_change),
]
