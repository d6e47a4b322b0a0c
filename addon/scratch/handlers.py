"""Handlers of the scratched-metal shader: lamp sync (depsgraph, render_pre), table extraction (load)."""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from .material import adopt_named_images, ensure_tables_extracted, scratch_groups, sync_scratch_lamps
from .tables import release_table_images


@persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    if not scratch_groups():
        return
    for update in depsgraph.updates:
        idb = update.id
        if isinstance(idb, (bpy.types.Light, bpy.types.World)) or (
            isinstance(idb, bpy.types.Object) and idb.type == "LIGHT"
        ):
            sync_scratch_lamps(scene, update_matrices=False)
            return


@persistent
def on_render_pre(scene, *_args) -> None:
    if scratch_groups():
        ensure_tables_extracted()
        sync_scratch_lamps(scene, update_matrices=False)


@persistent
def on_load_post(*_args) -> None:
    if scratch_groups():
        adopt_named_images()  # files from before: sets found by name -> by pointer
        ensure_tables_extracted()
    release_table_images()  # files from before: table images with fake users


SCRATCH_HANDLERS = [
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.render_pre, on_render_pre),
    (bpy.app.handlers.load_post, on_load_post),
]
