"""The benchmarks' Blender session: bpy with this checkout's add-on registered."""

from __future__ import annotations


def blender_with_addon():
    """``bpy``, its user resources in a temporary folder (``render.session.prepare_user_resources``, before the
    first import), with the add-on's classes registered from this checkout (no extension repository needed)."""
    from ..render.session import prepare_user_resources

    prepare_user_resources()
    import bpy

    from .. import addon

    if not hasattr(bpy.types.Scene, "material_structures"):
        addon.register()
    return bpy
