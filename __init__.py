"""Material Structures: pile fabric, scratched metal and teeth appearance models for Blender.

The repository root is both the Blender extension (loaded as ``bl_ext.<repo>.material_structures``)
and the Python package ``material_structures``. Importing the package does not import ``bpy``;
only :func:`register` touches Blender.
"""

__version__ = "0.1.0"


def register() -> None:
    from .addon import register as _register
    from .cli.blender_command import register_command

    _register()
    register_command()  # blender -c material_structures ...


def unregister() -> None:
    from .addon import unregister as _unregister
    from .cli.blender_command import unregister_command

    unregister_command()
    _unregister()
