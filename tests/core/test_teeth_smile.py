"""The smile ground truth (``core.teeth.smile``) and ``teeth synth --smile`` (issue 69's capture)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from material_structures.cli import main
from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.param_vector import TOOTH_G1_RANGE
from material_structures.core.teeth.scene import load_scene
from material_structures.core.teeth.smile import (
    INCISOR_MIN_PIXELS,
    SMILE_CAPTURE_SIZE,
    smile_framing,
    smile_scene,
    smile_truth,
)
from material_structures.core.teeth.synthetic import GROUND_TRUTH


@pytest.fixture(scope="module")
def smile():
    return smile_scene(resolution=16)


def test_smile_truth_gives_every_tooth_its_own_materials_and_shape(smile):
    truth = smile_truth(smile, seed=5)
    assert len(truth.teeth) == 16
    assert sum(t.name.startswith("upper-") for t in truth.teeth) == 8
    for a, b in itertools.combinations(truth.teeth, 2):
        for part in ("enamel", "dentin"):  # no two teeth share a tissue (translucency, shade and phase drawn apart)
            ma, mb = getattr(a, part), getattr(b, part)
            assert max(np.max(np.abs(np.log(ma.sigma_t / mb.sigma_t))), np.max(np.abs(ma.albedo - mb.albedo)),
                       abs(ma.g1 - mb.g1)) > 1e-3
        assert np.max(np.abs(a.c - b.c)) > 1e-3
    # and they differ by much: the 16 teeth span most of each drawn range
    factors = np.array([t.enamel.sigma_t[0] / GROUND_TRUTH["enamel"].sigma_t[0] for t in truth.teeth])
    assert factors.min() < 0.8 and factors.max() > 1.3
    assert np.ptp([t.dentin.g1 for t in truth.teeth]) > 0.25 and np.ptp([t.c[0] for t in truth.teeth]) > 0.4
    for t in truth.teeth:
        for part in ("enamel", "dentin"):
            m, base = getattr(t, part), GROUND_TRUTH[part]
            ratio = m.sigma_t / base.sigma_t
            assert np.allclose(ratio, ratio[0]) and 0.6 <= ratio[0] <= 1.6  # translucency, hue kept
            assert TOOTH_G1_RANGE[0] <= m.g1 <= TOOTH_G1_RANGE[1]
            assert np.all((m.albedo >= 0.5) & (m.albedo <= 0.995))
            # the shade moves between white and yellow (never green): blue's shift - green's = green's - red's
            d = np.log10(1 - m.albedo) - np.log10(1 - base.albedo)
            if np.all((m.albedo > 0.5) & (m.albedo < 0.995)):
                assert d[2] - d[1] == pytest.approx(d[1] - d[0], abs=1e-9) and -0.1 <= 2 * (d[1] - d[0]) <= 0.3
        assert np.all(np.abs(t.c) <= 0.3)
    # the gums and the cavity keep the base's; the input scene is left alone; the seed decides
    np.testing.assert_array_equal(truth.gums.material.sigma_t, GROUND_TRUTH["gums"].sigma_t)
    np.testing.assert_array_equal(truth.cavity.albedo, GROUND_TRUTH["cavity_albedo"])
    np.testing.assert_array_equal(smile.teeth[0].enamel.sigma_t, GROUND_TRUTH["enamel"].sigma_t)
    again, other = smile_truth(smile, seed=5), smile_truth(smile, seed=6)
    np.testing.assert_array_equal(again.teeth[3].dentin.albedo, truth.teeth[3].dentin.albedo)
    assert not np.allclose(other.teeth[3].dentin.albedo, truth.teeth[3].dentin.albedo)


def test_smile_framing_shows_the_arches_and_a_central_incisor_30_pixels_across(smile):
    target, fov = smile_framing(smile)
    cams, _ = default_rig(target, *SMILE_CAPTURE_SIZE, fov_x_deg=fov)
    centre = cams[1]
    for t in smile.teeth:
        x = centre.project(t.enamel_mesh.vertices)[:, 0]
        assert x.min() >= 0.0 and x.max() <= centre.width  # every tooth in the frame
        if t.name.endswith("central") and t.name.startswith("upper-"):
            assert x.max() - x.min() >= INCISOR_MIN_PIXELS


def test_synth_smile_options_give_the_smile_truth_and_its_rig(smile, tmp_path, capsys):
    """``teeth synth --smile``: the truth of --truth-seed, 3 cameras framing the arches at the default 208 x 128;
    one-line usage errors for --smile with --scene and for --truth-seed without --smile, before any work."""
    from material_structures.cli import build_parser
    from material_structures.cli.teeth import synth_scene_and_rig

    args = build_parser().parse_args(["teeth", "synth", "--smile", "--truth-seed", "5", "--out", str(tmp_path / "c"),
                                      "--mesh-resolution", "16"])
    scene, cams, lights = synth_scene_and_rig(args)
    truth = smile_truth(smile, seed=5)  # the fixture's smile is the same (mesh resolution 16)
    assert [t.name for t in scene.teeth] == [t.name for t in truth.teeth]
    for w, t in zip(scene.teeth, truth.teeth, strict=True):
        np.testing.assert_array_equal(w.enamel.sigma_t, t.enamel.sigma_t)
        np.testing.assert_array_equal(w.c, t.c)
    assert len(cams) == 3 and len(lights) == 54 and (cams[1].width, cams[1].height) == SMILE_CAPTURE_SIZE
    target, fov = smile_framing(truth)
    expected, _ = default_rig(target, *SMILE_CAPTURE_SIZE, fov_x_deg=fov)
    np.testing.assert_allclose(cams[1].K, expected[1].K)
    for args, words in ((["--smile", "--scene", str(tmp_path / "scene.json")], "not both"),
                        (["--truth-seed", "3"], "add --smile")):
        assert main(["teeth", "synth", "--out", str(tmp_path / "cap2"), *args]) == 2
        err = capsys.readouterr().err
        assert words in err and "Traceback" not in err
    assert not (tmp_path / "cap2").exists()


@pytest.mark.slow  # about 10 s (the gums' BVH): the options' part above runs in `make test`
def test_synth_smile_writes_the_truth_and_masks_every_tooth(tmp_path):
    out = tmp_path / "cap"
    assert main(["teeth", "synth", "--smile", "--truth-seed", "5", "--out", str(out), "--width", "52", "--height",
                 "32", "--lights", "2", "--cameras", "3", "--samples", "1", "--samples-background", "0",
                 "--mesh-resolution", "8"]) == 0
    written = load_scene(out / "scene.json")
    truth = smile_truth(smile_scene(resolution=8), seed=5)
    assert [t.name for t in written.teeth] == [t.name for t in truth.teeth]
    for w, t in zip(written.teeth, truth.teeth, strict=True):
        np.testing.assert_allclose(w.enamel.sigma_t, t.enamel.sigma_t, rtol=1e-12)
        np.testing.assert_allclose(w.c, t.c, rtol=1e-12)
    cap = Capture.load(out)
    assert cap.images.shape == (3, 2, 32, 52, 3)
    assert np.all(cap.masks.mean(axis=(1, 2)) > 0.1)  # teeth fill a sixth of each view at this framing
