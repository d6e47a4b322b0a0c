"""``bench teeth-extrapolation`` (benchmarks/teeth_extrapolation.py): its truths differ from the defaults, its
novel conditions lie outside the capture's, its figures are what they say; and (nightly) a short run end to end."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.benchmarks import teeth_extrapolation as bench


def test_truths_differ_from_the_defaults_in_every_tissue_and_phase_function():
    from material_structures.core.teeth.synthetic import GROUND_TRUTH

    for name in bench.TRUTHS:
        scene = bench.truth_scene(name, resolution=10)
        for tissue in ("enamel", "dentin"):
            got, default = getattr(scene.teeth[0], tissue), GROUND_TRUTH[tissue]
            assert not np.allclose(got.sigma_t, default.sigma_t) and got.g1 != default.g1, (name, tissue)


def test_novel_conditions_are_outside_the_capture_rig():
    """The side camera is 45 degrees off the mouth axis (the capture's reach 30), every novel light 56-84
    degrees (the capture's lights within 75, most of them well inside)."""
    from material_structures.core.teeth.synthetic import scene_target

    scene = bench.truth_scene("dense-diffuse", resolution=10)
    target = scene_target(scene)
    cams, lights = bench.novel_rig(scene, 24, 16)
    side = cams[0].center - target
    assert np.degrees(np.arctan2(side[0], side[1])) == pytest.approx(45.0, abs=1e-6)
    off = [np.degrees(np.arccos((li.position - target)[1] / np.linalg.norm(li.position - target)))
           for li in lights]
    assert min(off) == pytest.approx(56.0, abs=1e-6) and max(off) == pytest.approx(84.0, abs=1e-6)


def test_compare_reports_relative_errors_of_tooth_means_and_tiles():
    """A prediction 2 % too bright everywhere: every figure is 0.02 (closed form)."""
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.1, 1.0, (2, 3, 16, 24, 3))
    masks = np.zeros((2, 16, 24), dtype=bool)
    masks[:, 2:14, 3:21] = True
    fig = bench.compare(1.02 * ref, ref, masks)
    for key in ("tooth_mean_rel_err_worst", "tooth_mean_rel_err_median", "tiles_median_rel_err"):
        assert fig[key] == pytest.approx(0.02, rel=1e-9)


@pytest.mark.slow
def test_a_short_run_end_to_end(monkeypatch, tmp_path):
    """Nightly: one truth, 4-spp capture of 24 x 16 pixels, a 2-iteration fit from the scene's values, 8-spp
    novel renders (about a minute): every figure is there and finite. Run again in the same kept folder, it
    reuses the capture (3 Mitsuba renders instead of 4: the novel ones) and gives the same figures; with other
    capture samples it renders the capture again."""
    pytest.importorskip("mitsuba")
    from material_structures.core.teeth import mitsuba_capture

    for key, value in (("TRUTHS", "1"), ("CAPTURE_SPP", "4"), ("NOVEL_SPP", "8"), ("SIZE", "24,16"),
                       ("FIT_ARGS", "--init scene --iterations 2"), ("KEEP", str(tmp_path / "kept"))):
        monkeypatch.setenv(f"TEETH_EXTRAPOLATION_{key}", value)
    renders = []
    original = mitsuba_capture.render_capture_mitsuba

    def counted(*args, **kwargs):
        renders.append(kwargs)
        return original(*args, **kwargs)

    monkeypatch.setattr(mitsuba_capture, "render_capture_mitsuba", counted)
    out = bench.teeth_extrapolation()
    assert list(out["truths"]) == ["translucent-forward"] and len(renders) == 4
    for key in ("tooth_mean_rel_err_worst", "tooth_mean_rel_err_median", "tiles_median_rel_err",
                "truth_tooth_mean_rel_err_worst", "fit_seconds_max"):
        assert np.isfinite(out[key]) and out[key] > 0, key
    again = bench.teeth_extrapolation()
    assert len(renders) == 7
    assert again["tooth_mean_rel_err_worst"] == out["tooth_mean_rel_err_worst"]  # the same capture, fit, renders
    monkeypatch.setenv("TEETH_EXTRAPOLATION_CAPTURE_SPP", "2")
    bench.teeth_extrapolation()
    assert len(renders) == 11


def test_start_trials_bench_refuses_an_unknown_truth(monkeypatch):
    """``bench teeth-start-trials`` names its truths before any render."""
    from material_structures.benchmarks import teeth_start_trials

    monkeypatch.setenv("TEETH_START_TRIALS_TRUTHS", "translucent-forward,chalky")
    with pytest.raises(ValueError, match=r"unknown truth\(s\) \['chalky'\]"):
        teeth_start_trials.teeth_start_trials()
