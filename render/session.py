"""Process-level set-up for running Blender as a Python module."""

from __future__ import annotations

import atexit
import glob
import os
import shutil
import sys
import tempfile

OSL_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "cycles_osl")


def prepare_user_resources() -> str:
    """Point Blender's user resources at a temp dir (call before the first ``import bpy``).

    Keeps headless runs from reading or writing the user's real preferences and extensions.
    An existing ``BLENDER_USER_RESOURCES`` is respected; a temp dir made here is removed at exit.
    """
    path = os.environ.get("BLENDER_USER_RESOURCES")
    if not path:
        path = tempfile.mkdtemp(prefix="ms-blender-user-")
        os.environ["BLENDER_USER_RESOURCES"] = path
        atexit.register(shutil.rmtree, path, True)
    return path


def ensure_bundled_paths() -> None:
    """Put the wheel's bundled site-packages (holds ``oslquery``) on ``sys.path``.

    Without it, OSL script nodes silently get no sockets.
    """
    import bpy

    local = bpy.utils.resource_path("LOCAL")
    for path in sorted(glob.glob(os.path.join(local, "python", "lib", "python3.*", "site-packages"))):
        if path not in sys.path:
            sys.path.append(path)


def blender_version() -> tuple[int, int, int]:
    import bpy

    return tuple(bpy.app.version)


def osl_flip_t() -> int:
    """1 when OSL ``texture()`` needs ``t = 1 - UV[1]`` (Blender 4.x), 0 when ``t = UV[1]`` (5.x).

    With the right flag, ``UV[1] = 0`` addresses the bottom row of the image file on both versions.
    """
    return 1 if blender_version()[0] < 5 else 0


def osl_shader_path(name: str) -> str:
    """Absolute path of a shader shipped in ``cycles_osl/`` (``name`` with or without ``.osl``)."""
    if not name.endswith(".osl"):
        name += ".osl"
    path = os.path.join(OSL_DIR, name)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"OSL shader not found: {path}")
    return path
