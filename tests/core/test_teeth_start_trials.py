"""The fit's choice among starts (``start_trials``): the fit's first iterations from each start, common
random numbers, the lowest mean loss over their last half wins, and the fit resumes the winner's trial."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from material_structures.core.teeth.capture import default_rig
from material_structures.core.teeth.fit_settings import FitSettings
from material_structures.core.teeth.optimise import fit
from material_structures.core.teeth.scene import VolumeMaterial, load_scene
from material_structures.core.teeth.start_trials import best_start, trial_dir, trial_score
from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target


def test_trial_score_is_the_mean_of_the_last_half():
    log = [{"loss": v} for v in (9.0, 7.0, 2.0, 4.0)]
    assert trial_score(log) == pytest.approx(3.0, abs=1e-15)
    assert trial_score(log[:3]) == pytest.approx(4.5, abs=1e-15)  # the last 2 of 3
    assert trial_score(log[:1]) == pytest.approx(9.0, abs=1e-15)


def _tiny_capture():
    truth = make_scene(n_teeth=1, resolution=12)
    cams, lights = default_rig(target=scene_target(truth), width=16, height=12, n_lights=6, n_cameras=1,
                               fov_x_deg=3.0)
    return truth, render_capture(truth, cams, lights, spp=16, spp_background=0, seed=3)


@pytest.mark.heavy
def test_best_start_picks_the_start_near_the_capture(tmp_path):
    """Two starts, one the capture's own materials, one 4x too dense with g 0.9: the trials' paired losses
    pick the first (whichever order), and its trial folder holds the near start's iterate."""
    truth, cap = _tiny_capture()
    far = truth.copy()
    for t in far.teeth:
        t.enamel = VolumeMaterial(4 * t.enamel.sigma_t, t.enamel.albedo, 0.9)
        t.dentin = VolumeMaterial(4 * t.dentin.sigma_t, t.dentin.albedo, 0.9)
    s = replace(FitSettings(), start_trials=4, lights_per_iteration=2, image_spp=4, spp=2, held_out_lights=0,
                free=("*.sigma_t",))
    for starts, right in (([truth, far], 0), ([far, truth], 1)):
        work = str(tmp_path / f"order{right}")
        chosen, scores = best_start(starts, cap, s, work)
        assert chosen == right and len(scores) == 2
        assert scores[1 - right] > 2 * scores[right]
        got = load_scene(f"{trial_dir(work, chosen)}/scene_best.json").teeth[0].enamel.sigma_t
        assert np.all(np.abs(got / truth.teeth[0].enamel.sigma_t - 1) < 0.5), got  # not the far one's 4x


@pytest.mark.heavy
def test_the_fit_resumed_from_a_trial_is_the_fit_from_its_start(tmp_path):
    """The winner's trial is the fit's first ``start_trials`` iterations: resumed to the end, its log and
    result are those of the uninterrupted fit from the same start. The trial's iterations are the same to
    the last bit; after the resume, with the scene equal to the bit, the compiled renderer's losses differed
    by 2e-10 relative (two uninterrupted fits agree exactly), hence rtol 1e-8."""
    truth, cap = _tiny_capture()
    start = truth.copy()
    for t in start.teeth:
        t.enamel = VolumeMaterial(1.5 * t.enamel.sigma_t, t.enamel.albedo, 0.5)
    s = replace(FitSettings(), iterations=6, start_trials=3, lights_per_iteration=2, image_spp=4, spp=2,
                held_out_lights=0, free=("*.sigma_t", "*.albedo"))
    work = str(tmp_path / "trials")
    chosen, scores = best_start([start, truth], cap, s, work)
    resumed, log = fit([start, truth][chosen], cap, s, out_dir=trial_dir(work, chosen), resume=True)
    whole, whole_log = fit([start, truth][chosen], cap, s)
    assert len(log) == 6 and [e["loss"] for e in log[:3]] == [e["loss"] for e in whole_log[:3]]
    np.testing.assert_allclose([e["loss"] for e in log], [e["loss"] for e in whole_log], rtol=1e-8, atol=0)
    assert scores[chosen] == trial_score(whole_log[:3])
    np.testing.assert_allclose(resumed.teeth[0].enamel.sigma_t, whole.teeth[0].enamel.sigma_t, rtol=1e-8)
    np.testing.assert_allclose(resumed.teeth[0].dentin.albedo, whole.teeth[0].dentin.albedo, rtol=1e-8)
    assert np.abs(whole.teeth[0].enamel.sigma_t / start.teeth[0].enamel.sigma_t - 1).max() > 1e-3  # it moved


def test_one_start_or_no_trials_runs_no_trial():
    truth = make_scene(n_teeth=1, resolution=8)
    s = FitSettings()
    assert best_start([truth], None, s, "unused") == (None, [])
    assert best_start([truth, truth.copy()], None, replace(s, start_trials=0), "unused") == (None, [])
    with pytest.raises(ValueError, match="no start"):
        best_start([], None, s, "unused")
    with pytest.raises(ValueError, match="start_trials"):
        FitSettings(start_trials=-1)
