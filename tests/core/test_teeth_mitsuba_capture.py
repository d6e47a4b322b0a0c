"""``teeth synth --renderer mitsuba``: a synthetic capture rendered by Mitsuba 3 (volpath, all bounces) in our
capture format, agreeing with our tracer's render of the scene it wrote (scene.json: the synthetic scene with its
thin dielectric boundaries, eta 1.631 / 1.33, and a sharp enamel/dentin boundary)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from material_structures.cli import main
from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.path_tracer import RenderSettings, render
from material_structures.core.teeth.scene import TeethScene
from material_structures.core.teeth.synthetic import make_scene, scene_target, tooth_masks

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`

pytest.importorskip("mitsuba")

SEEDS = (11, 12, 13)
SYNTH = ["--teeth", "1", "--width", "20", "--height", "14", "--lights", "3", "--cameras", "2", "--samples", "256",
         "--mesh-resolution", "12", "--renderer", "mitsuba"]


def _tooth_mean(batches: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the mean over the tooth pixels (all cameras) of the batches' mean image, and its standard
    error from the per-pixel variance over the independent batches. ``batches`` (n_batches, n_cam, H, W, 3)."""
    v = batches[:, mask]  # (batches, pixels, 3)
    return v.mean(axis=(0, 1)), np.sqrt(v.var(axis=0, ddof=1).sum(axis=0) / len(v)) / v.shape[1]


def test_synth_mitsuba_capture_matches_our_tracer(tmp_path, capsys):
    caps = []
    for s in SEEDS:
        assert main(["teeth", "synth", "--out", str(tmp_path / f"cap{s}"), *SYNTH, "--seed", str(s)]) == 0
        caps.append(Capture.load(tmp_path / f"cap{s}"))
    out = capsys.readouterr().out
    assert "Mitsuba 3" in out and "blend spread 1e-5 mm" in out
    cap = caps[0]
    assert cap.images.shape == (2, 3, 14, 20, 3) and cap.images.dtype == np.float32
    assert cap.masks.shape == (2, 14, 20) and cap.masks.sum() > 20
    assert np.all(np.isfinite(cap.images)) and cap.images.max() > 0
    with open(tmp_path / f"cap{SEEDS[0]}" / "scene.json") as f:
        scene = TeethScene.from_dict(json.load(f))
    # the written scene is the one rendered: the synthetic scene's boundaries, a sharp blend, the capture's masks
    truth = make_scene(n_teeth=1, resolution=12)
    assert scene.teeth[0].eta == truth.teeth[0].eta != 1.0 and scene.gums.eta == truth.gums.eta != 1.0
    np.testing.assert_array_equal(scene.teeth[0].a_t, truth.teeth[0].a_t)
    assert np.all(scene.teeth[0].a_t < 1.0) and scene.blend_spread == 1e-5
    np.testing.assert_array_equal(tooth_masks(scene, cap.cameras), cap.masks)
    for c in caps[1:]:
        np.testing.assert_array_equal(c.masks, cap.masks)
    theirs = np.array([c.images for c in caps])  # (seeds, n_cam, n_light, H, W, 3)
    ours = np.array([render(scene, cap.cameras, cap.lights, RenderSettings(spp=128, seed=100 + s)).images
                     for s in range(3)])
    for li in range(len(cap.lights)):
        a, sa = _tooth_mean(ours[:, :, li], cap.masks)
        b, sb = _tooth_mean(theirs[:, :, li], cap.masks)
        assert np.all(np.abs(a - b) < 4 * np.hypot(sa, sb) + 0.01 * b), (li, a, b, sa, sb)


def test_render_capture_mitsuba_refuses_a_textured_a_t():
    """Mitsuba's thin boundary takes one a_t per part: an a_t that varies over a tooth is refused in one line."""
    from material_structures.core.teeth.mitsuba_capture import render_capture_mitsuba

    sc = make_scene(n_teeth=1, resolution=12)
    sc.teeth[0].eta = 1.63
    sc.teeth[0].a_t = np.full((2, 2, 3), 0.9)
    sc.teeth[0].a_t[0, 1] = 0.7
    cams, lights = default_rig(target=scene_target(sc), width=8, height=6, n_lights=1, n_cameras=1)
    with pytest.raises(ValueError, match=r"tooth0 has a_t in \[0.7, 0.9\]"):
        render_capture_mitsuba(sc, cams, lights, 4, 0)
    assert sc.teeth[0].eta == 1.63 and sc.teeth[0].a_t[0, 1, 0] == 0.7  # the scene is not changed
