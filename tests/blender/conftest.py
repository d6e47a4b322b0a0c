"""Blender-side fixtures. Runs under both bpy 5.2 (.venv) and bpy 4.5 (.venv-compat).

``bpy`` imports once per process, so user resources are redirected before the first import.
The add-on is enabled from this checkout through a temporary extension repository.
Every test starts from an empty file (``fresh_file``, automatic): what a test leaves in ``bpy.data`` is
never the next test's starting point.
"""

from __future__ import annotations

import os
import tempfile

import pytest

from material_structures.render.session import prepare_user_resources

prepare_user_resources()
bpy = pytest.importorskip("bpy")

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEV_REPO = "ms_dev"
ADDON_MODULE = f"bl_ext.{DEV_REPO}.material_structures"


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "tests/blender/" in str(item.fspath).replace(os.sep, "/"):
            item.add_marker(pytest.mark.blender)


@pytest.fixture(scope="session")
def addon_module() -> str:
    """Enable this checkout as the extension ``bl_ext.ms_dev.material_structures``."""
    import addon_utils

    repo_dir = tempfile.mkdtemp(prefix="ms-dev-repo-")
    os.symlink(ROOT, os.path.join(repo_dir, "material_structures"))
    repos = bpy.context.preferences.extensions.repos
    if not any(r.module == DEV_REPO for r in repos):
        repos.new(name=DEV_REPO, module=DEV_REPO, custom_directory=repo_dir, source="USER")
    mod = addon_utils.enable(ADDON_MODULE, default_set=True, handle_error=_raise)
    assert mod is not None, f"could not enable {ADDON_MODULE}"
    yield ADDON_MODULE
    addon_utils.disable(ADDON_MODULE, default_set=True)


@pytest.fixture(autouse=True)
def fresh_file() -> None:
    """An empty file before every test (Blender's File > New > General without its objects). A test that
    needs several files in turn resets again itself."""
    bpy.ops.wm.read_homefile(use_empty=True)


def _raise(exc):
    raise exc


@pytest.fixture
def update_refs(request) -> bool:
    return bool(request.config.getoption("--update-refs"))
