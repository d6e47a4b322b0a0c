"""Render regression of every library material and showcase scene against tests/references/.

Everything registered in the library is covered (at 48 x 36 pixels, 4 samples), so a new material or scene
fails here until its reference exists. A reference is the per-value mean and variance of K renders of one
built scene (seeds 0..K-1, ``make refs``; K = 16, 8 for the teeth entries, whose volumes render slowly) and its
seed-0 render; the test renders seed 0 and compares statistically (``tests/regression.py``), so one reference set
serves every CPU. Each test also plants a 1 % darker copy of its render, which must fail.

``--cycles-kernel=sse42`` forces Cycles' SSE4.2 CPU kernel (its debug flags; ``make test-all`` runs this
suite so as well) to show that the references hold for another instruction set.
"""

from __future__ import annotations

import numpy as np
import pytest
from regression import RegressionMismatch, check_render, compare

from material_structures.showcase import library

RESOLUTION, SAMPLES = (48, 36), 4
EXACT = {"test-card"}  # emission only: the same on 4.5, compared there too
DARKER = np.array([0.99, 0.99, 0.99, 1.0], dtype=np.float32)  # the planted regression: RGB 1 % darker

# Nightly only (make test-all): the 16-tooth smile (its Cycles volume set-up takes minutes; make test checks its
# build in test_teeth_scenes.py and renders its materials and Blend Volumes on one tooth, "Dentin Shade A1") and
# two of the three dentin shades (the same tooth and node groups with other values: A1 stays).
# The teeth fit demo (a fit, then its fitted tooth in Cycles) likewise: make test fits from the Teeth panel and
# applies the result (test_teeth_fit.py) and renders the teeth materials (Dentin Shade A1).
NIGHTLY = {"teeth-smile", "teeth-fit-demo", "Dentin Shade A3 (yellowish)", "Dentin Shade C2 (greyish)"}


def _entry(name: str):
    marks = [pytest.mark.slow] if name in NIGHTLY else []
    if name == "teeth-fit-demo":  # fits with the compiled tracer: waits for the numba warm-up (tests/conftest.py)
        marks.append(pytest.mark.numba)
    return pytest.param(name, marks=marks)


SCENES = [_entry(n) for n in library.available_scenes()]
MATERIALS = [_entry(n) for n in library.available_materials()]


def _slug(name: str) -> str:
    return "".join(c.lower() if c.isalnum() else "-" for c in name).strip("-")


def _skip_on_45(name):
    import bpy

    if bpy.app.version < (5, 0, 0) and name not in EXACT:
        pytest.skip("lit references are rendered with Blender 5.2; 4.5 differs by design")


@pytest.fixture
def seeded_render(monkeypatch, cycles_kernel):
    """``render(build, seeds)``: runs ``build`` (a library render call) once and returns its scene rendered
    with each of ``seeds`` (Cycles' seed set just before rendering; the scene is built once, the teeth fit demo's
    fit included), on the CPU kernel ``--cycles-kernel`` asks for."""
    return _seeded_render(monkeypatch, cycles_kernel)


def _seeded_render(monkeypatch, cycles_kernel):
    import bpy

    want: list[int] = []
    images: list[np.ndarray] = []
    original = library.render_to_array

    def render_to_array(scene, path=None, *args, **kwargs):
        if cycles_kernel != "native":
            scene.cycles.debug_use_cpu_avx2 = False
            scene.cycles.debug_use_cpu_sse42 = cycles_kernel == "sse42"
        for seed in want:
            scene.cycles.seed = seed
            images.append(original(scene, path, *args, **kwargs))
        return images[0]

    monkeypatch.setattr(library, "render_to_array", render_to_array)
    if cycles_kernel != "native":  # Cycles reads the scene's debug flags only with the developer options on
        prefs = bpy.context.preferences
        monkeypatch.setattr(prefs.experimental, "use_cycles_debug", True)
        monkeypatch.setattr(prefs.view, "show_developer_ui", True)

    def render(build, seeds):
        want[:], images[:] = seeds, []
        build()
        assert len(images) == len(seeds), "the library call rendered more than once"
        return list(images)

    return render


def _check(name, build, seeded_render, update_refs, tmp_path):
    rgba = check_render(name, lambda seeds: seeded_render(build, seeds), update_refs)
    if update_refs:
        return
    with pytest.raises(RegressionMismatch):  # the test can fail: a 1 % darker render does
        compare(name, rgba * DARKER, output_dir=str(tmp_path / "planted"))


@pytest.mark.regression
@pytest.mark.parametrize("name", SCENES)
def test_library_scene_matches_reference(name, tmp_path, update_refs, addon_module, seeded_render):
    _skip_on_45(name)
    _check(f"library-{name}",
           lambda: library.render_library_scene(name, str(tmp_path), RESOLUTION, SAMPLES),
           seeded_render, update_refs, tmp_path)


@pytest.mark.regression
@pytest.mark.parametrize("name", MATERIALS)
def test_library_material_matches_reference(name, tmp_path, update_refs, addon_module, seeded_render):
    _skip_on_45(name)
    _check(f"material-{_slug(name)}",
           lambda: library.render_material_preview(name, str(tmp_path), RESOLUTION, SAMPLES),
           seeded_render, update_refs, tmp_path)


SSE42_SHORT = ["studio-ball", "material:Heavy Wear Brass"]  # one scene, one material: the nightly runs all


@pytest.mark.regression
@pytest.mark.parametrize("entry", SSE42_SHORT)
def test_sse42_kernel_matches_reference(entry, tmp_path, addon_module, monkeypatch, cycles_kernel):
    """The short version in `make test` of the nightly run of this suite on Cycles' SSE4.2 CPU kernel (`make
    test-all`): the same references hold for the kernel below this machine's, and a 1 % darker render fails."""
    import bpy

    if bpy.app.version < (5, 0, 0) or cycles_kernel != "native":
        pytest.skip("5.2 references; the whole suite runs on SSE4.2 with --cycles-kernel=sse42")
    render = _seeded_render(monkeypatch, "sse42")
    kind, _, name = entry.rpartition(":")
    if kind == "material":
        _check(f"material-{_slug(name)}",
               lambda: library.render_material_preview(name, str(tmp_path), RESOLUTION, SAMPLES), render, False,
               tmp_path)
    else:
        _check(f"library-{name}",
               lambda: library.render_library_scene(name, str(tmp_path), RESOLUTION, SAMPLES), render, False,
               tmp_path)
