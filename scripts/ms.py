"""Run the Material Structures CLI inside a real Blender:

    blender -b --python scripts/ms.py -- SUBCOMMAND [ARGS...]

The repository root is loaded as the package ``material_structures`` whatever its folder is called.
When the project venv's Python matches Blender's, its site-packages (scipy, OpenEXR, ...) are added
so that every subcommand has what it needs; EXR files otherwise go through Blender's OpenImageIO.
"""

import glob
import importlib.util
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _add_venv_site_packages() -> None:
    tag = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    for venv in (".venv", ".venv-compat"):
        for path in glob.glob(os.path.join(ROOT, venv, "lib", tag, "site-packages")):
            if path not in sys.path:
                sys.path.append(path)  # after Blender's own packages: bpy/numpy stay Blender's


def _load_package():
    if "material_structures" in sys.modules:
        return sys.modules["material_structures"]
    spec = importlib.util.spec_from_file_location(
        "material_structures", os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["material_structures"] = module
    spec.loader.exec_module(module)
    return module


_add_venv_site_packages()
_load_package()
from material_structures.cli import main  # noqa: E402

code = main()
if code:
    sys.exit(code)
