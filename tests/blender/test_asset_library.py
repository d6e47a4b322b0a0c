"""The artist material library: asset-marked materials, catalogs, previews, registration."""

from __future__ import annotations

import os

import bpy
import pytest

pytest.importorskip("PIL")


@pytest.fixture(scope="module")
def built_library(tmp_path_factory, addon_module):
    """The library built as ``make library`` builds it, with one material's preview rendered and the others'
    flat grey (each preview is that material's library render, which test_library_regression.py checks; a teeth
    preview alone costs ~20 s of Cycles volume set-up). ``make test-bare`` builds the whole library for real."""
    import numpy as np

    from material_structures.showcase import asset_library

    folder = str(tmp_path_factory.mktemp("library"))
    render = asset_library.render_material_preview
    rendered = []

    def preview(name, work, resolution, samples):
        if not rendered:
            rendered.append(name)
            return render(name, work, resolution, samples)
        return np.full((resolution[1], resolution[0], 4), 0.5, dtype=np.float32)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(asset_library, "render_material_preview", preview)
        path = asset_library.build_asset_library(folder, preview_size=24, samples=1, progress=False)
    assert len(rendered) == 1
    return folder, path


def test_library_holds_every_material_as_an_asset(built_library):
    from material_structures.showcase.asset_library import catalog_uuid
    from material_structures.showcase.library import MATERIALS, available_materials

    folder, path = built_library
    names = available_materials()
    assert len(names) >= 3
    with bpy.data.libraries.load(path, assets_only=True) as (src, dst):
        stored = list(src.materials)
        assert sorted(stored) == sorted(names)
        dst.materials = list(stored)
    cats = open(os.path.join(folder, "blender_assets.cats.txt")).read()
    for name, mat in zip(stored, dst.materials, strict=True):
        entry = MATERIALS[name]
        assert mat.asset_data is not None
        assert mat.asset_data.catalog_id == catalog_uuid(entry.catalog)
        assert f"{catalog_uuid(entry.catalog)}:{entry.catalog}:" in cats
        assert mat.preview is not None and tuple(mat.preview.image_size) == (24, 24)
        for node in mat.node_tree.nodes:  # maps travel inside the library file
            if node.type == "TEX_IMAGE":
                assert node.image.packed_file is not None
        slug = "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")
        assert os.path.isfile(os.path.join(folder, "previews", slug + ".png"))


def test_register_operator_adds_the_library(built_library, monkeypatch):
    from material_structures.addon import operators as op_module

    folder, _ = built_library
    module = next(
        m
        for n, m in __import__("sys").modules.items()
        if n.endswith("addon.operators") and m is not op_module and hasattr(m, "LIBRARY_DIR")
    )
    monkeypatch.setattr(module, "LIBRARY_DIR", folder)
    assert bpy.ops.material_structures.register_asset_library() == {"FINISHED"}
    libs = bpy.context.preferences.filepaths.asset_libraries
    assert any(os.path.normpath(lib.path) == os.path.normpath(folder) for lib in libs)
    assert bpy.ops.material_structures.register_asset_library() == {"FINISHED"}  # idempotent
    assert sum(os.path.normpath(lib.path) == os.path.normpath(folder) for lib in libs) == 1


def test_rebuilding_leaves_no_backup_and_the_zip_ships_none(built_library, tmp_path, monkeypatch):
    """``make library`` twice must not leave a ``.blend1`` backup for ``make build`` to ship. (The second build
    writes over a copy of the built library with one material: what it checks, saving over an existing
    library file, is the same for one material as for all.)"""
    import shutil
    import tomllib

    from material_structures.showcase import asset_library

    folder = str(tmp_path / "library")
    shutil.copytree(built_library[0], folder)
    path = os.path.join(folder, os.path.basename(built_library[1]))
    first = asset_library.available_materials()[:1]
    monkeypatch.setattr(asset_library, "available_materials", lambda: first)
    assert asset_library.build_asset_library(folder, preview_size=24, samples=1, progress=False) == path
    assert sorted(f for f in os.listdir(folder) if ".blend" in f) == [os.path.basename(path)]
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    with open(os.path.join(root, "blender_manifest.toml"), "rb") as f:
        assert "*.blend1" in tomllib.load(f)["build"]["paths_exclude_pattern"]
