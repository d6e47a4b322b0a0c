"""The artist material library: asset-marked materials, catalogs, previews, registration."""

from __future__ import annotations

import os

import bpy
import pytest

pytest.importorskip("PIL")

RENDERED = "Light Wear Steel"  # the material whose preview the built library renders (the others are copied)


@pytest.fixture(scope="module")
def built_library(tmp_path_factory, addon_module):
    """The library built as ``make library`` builds it (default preview size and samples), with one material's
    preview rendered (the quickest to render: 1.5 s against 2.7 s for the first, Corduroy, and 12 s for the
    spectral scratch materials) and the others copied from the stored previews (a build copies them; that each one
    is still its material's render is ``test_stored_previews_are_what_the_materials_render``, nightly)."""
    from material_structures.showcase import asset_library

    folder = str(tmp_path_factory.mktemp("library"))
    stored = asset_library.stored_preview
    render = asset_library.render_material_preview
    first = RENDERED
    assert first in asset_library.available_materials()
    rendered = []

    def preview(name, work, resolution, samples):
        rendered.append(name)
        return render(name, work, resolution, samples)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(asset_library, "render_material_preview", preview)
        mp.setattr(asset_library, "stored_preview", lambda name, *a: None if name == first else stored(name, *a))
        path = asset_library.build_asset_library(folder, progress=False)
    assert rendered == [first]
    return folder, path


def test_a_default_build_copies_the_stored_previews(built_library):
    """Every library material has a stored preview at the default size; a default build copies it byte for byte
    (rendering only where there is none), another size or sample count renders."""
    from PIL import Image

    from material_structures.showcase import asset_library as A

    folder, _ = built_library
    names = A.available_materials()
    for name in names:
        stored = A.stored_preview(name)
        assert stored is not None, f"no stored preview of {name!r}: run make previews"
        with Image.open(stored) as im:
            assert im.size == (A.PREVIEW_SIZE, A.PREVIEW_SIZE)
        assert A.stored_preview(name, 24, A.PREVIEW_SAMPLES) is None
        assert A.stored_preview(name, A.PREVIEW_SIZE, 1) is None
        if name != RENDERED:  # the fixture rendered this one
            with open(stored, "rb") as a, open(os.path.join(folder, "previews", A.preview_file_name(name)), "rb") as b:
                assert a.read() == b.read(), name
    assert sorted(os.listdir(A.STORED_PREVIEWS)) == sorted(A.preview_file_name(n) for n in names)


@pytest.mark.slow
def test_stored_previews_are_what_the_materials_render(addon_module, tmp_path):
    """Nightly (about 100 s): each stored preview is its material's render now, so a material edited without
    ``make previews`` is caught: image means within 5 % per channel and the median 8 x 8 block within 10 %
    (16 spp: another CPU's kernel gives other noise). Dentin previews rendered with a Blend Volume of another node
    layout differed by 16-94 % in their channel means."""
    import numpy as np
    from PIL import Image

    from material_structures.showcase import asset_library as A

    for name in A.available_materials():
        out = A.render_preview_png(name, str(tmp_path / "work"), str(tmp_path / A.preview_file_name(name)))
        now = np.asarray(Image.open(out), dtype=float)[..., :3]
        stored = np.asarray(Image.open(A.stored_preview(name)), dtype=float)[..., :3]
        means_now, means_stored = now.mean(axis=(0, 1)), stored.mean(axis=(0, 1))
        assert np.all(np.abs(means_now / means_stored - 1.0) <= 0.05), (name, means_now, means_stored)
        n = A.PREVIEW_SIZE // 8
        blocks_now = now.reshape(n, 8, n, 8, 3).mean(axis=(1, 3))
        blocks_stored = stored.reshape(n, 8, n, 8, 3).mean(axis=(1, 3))
        lit = blocks_stored.mean(axis=-1) > 5.0
        rel = np.abs(blocks_now - blocks_stored)[lit] / blocks_stored[lit].clip(1.0)
        assert np.median(rel) <= 0.10, (name, float(np.median(rel)))


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
        assert mat.preview is not None and tuple(mat.preview.image_size) == (128, 128)
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
