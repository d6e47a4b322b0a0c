"""``blender -c material_structures <subcommand> ...``: the command-line interface inside Blender.

Blender 4.2+ lets an extension add a command to ``blender --command`` (``-c``) with
``bpy.utils.register_cli_command``. Ours runs the same parser as ``python -m material_structures``
(``cli.main``): the same subcommands, options and exit codes (0 done, 2 a usage error in one line, 1 a runtime
error in one line or a bug with its traceback), with nothing but an installed extension: no checkout, no virtual
environment.
``blender -b -c material_structures render test-card --out card.png``. In the ``bpy`` module (no
``blender`` executable, no command line) the registered function is :func:`run`, called with the arguments.
"""

from __future__ import annotations

import bpy

COMMAND = "material_structures"
_handle = None


def run(argv: list[str]) -> int:
    """Run the CLI with ``argv`` (the words after ``-c material_structures``); returns its exit code."""
    from . import main

    return main(list(argv))


def register_command() -> None:
    global _handle
    if _handle is None and hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command(COMMAND, run)


def unregister_command() -> None:
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
