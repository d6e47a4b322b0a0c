"""Material Structures: pile fabric, scratched metal and teeth appearance models for Blender.

The repository root is both the Blender extension (loaded as ``bl_ext.<repo>.material_structures``)
and the Python package ``material_structures``. Importing the package does not import ``bpy``;
only :func:`register` touches Blender.
"""

__version__ = "0.1.0"


def register() -> None:
    from .addon import register as _register

    _register()


def unregister() -> None:
    from .addon import unregister as _unregister

    _unregister()
