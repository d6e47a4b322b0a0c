"""Render regression of every library material and showcase scene against tests/references/.

``make refs`` rewrites the references deliberately. Everything registered in the library is covered
(at 48 x 36 pixels, 4 samples), so a new material or scene fails here until its reference exists.
"""

from __future__ import annotations

import pytest
from regression import compare_to_reference

from material_structures.showcase import library

RESOLUTION, SAMPLES = (48, 36), 4
EXACT = {"test-card"}  # emission-only: bit-exact; lit scenes allow float-summation differences
ATOL = 2e-3

SCENES = library.available_scenes()
MATERIALS = library.available_materials()


def _slug(name: str) -> str:
    return "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")


def _skip_on_45(name):
    import bpy

    if bpy.app.version < (5, 0, 0) and name not in EXACT:
        pytest.skip("lit references are rendered with Blender 5.2; 4.5 differs by design")


@pytest.mark.regression
@pytest.mark.parametrize("name", SCENES)
def test_library_scene_matches_reference(name, tmp_path, update_refs, addon_module):
    _skip_on_45(name)
    rgba = library.render_library_scene(name, str(tmp_path), RESOLUTION, SAMPLES)
    compare_to_reference(f"library-{name}", rgba, update_refs, atol=0.0 if name in EXACT else ATOL)


@pytest.mark.regression
@pytest.mark.parametrize("name", MATERIALS)
def test_library_material_matches_reference(name, tmp_path, update_refs, addon_module):
    _skip_on_45(name)
    rgba = library.render_material_preview(name, str(tmp_path), RESOLUTION, SAMPLES)
    compare_to_reference(f"material-{_slug(name)}", rgba, update_refs, atol=ATOL)
