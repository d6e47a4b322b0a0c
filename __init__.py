"""Material Structures: pile fabric, scratched metal and teeth appearance models for Blender.

The repository root is both the Blender extension (loaded as ``bl_ext.<repo>.material_structures``)
and the Python package ``material_structures``. Importing the package does not import ``bpy``;
only :func:`register` touches Blender.
"""


def _manifest_version() -> str:
    """The version in blender_manifest.toml, its one place (Blender requires it there; pyproject reads it here)."""
    import os
    import tomllib

    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "blender_manifest.toml"), "rb") as f:
        return tomllib.load(f)["version"]


__version__ = _manifest_version()


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
