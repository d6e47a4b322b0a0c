"""Render regression of the library scenes against tests/references/ (``make refs`` updates)."""

from __future__ import annotations

import pytest
from regression import compare_to_reference

from material_structures.render import library

# (scene, resolution, samples, absolute tolerance). Emission-only scenes are exact; lit scenes
# are compared with a tolerance that absorbs float-summation differences between builds.
CASES = [
    ("test-card", (32, 32), 2, 0.0),
    ("studio-ball", (64, 48), 8, 2e-3),
    ("fabric-velvet", (48, 36), 4, 2e-3),
    ("fabric-corduroy", (48, 36), 4, 2e-3),
    ("fabric-plush", (48, 36), 4, 2e-3),
]


@pytest.mark.regression
@pytest.mark.parametrize(("name", "resolution", "samples", "atol"), CASES, ids=[c[0] for c in CASES])
def test_library_scene_matches_reference(name, resolution, samples, atol, tmp_path, update_refs, request):
    import bpy

    if bpy.app.version < (5, 0, 0) and atol > 0:
        pytest.skip("lit-scene references are rendered with Blender 5.2; 4.5 differs by design")
    rgba = library.render_library_scene(name, str(tmp_path), resolution, samples)
    compare_to_reference(f"library-{name}", rgba, update_refs, atol=atol)
