"""The fit's choice among starts (``start_trials``): short trial fits with common random numbers, the lowest
mean loss over their last half wins."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from material_structures.core.teeth.capture import default_rig
from material_structures.core.teeth.fit_settings import FitSettings
from material_structures.core.teeth.scene import VolumeMaterial
from material_structures.core.teeth.start_trials import best_start, trial_score
from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target


def test_trial_score_is_the_mean_of_the_last_half():
    log = [{"loss": v} for v in (9.0, 7.0, 2.0, 4.0)]
    assert trial_score(log) == pytest.approx(3.0, abs=1e-15)
    assert trial_score(log[:3]) == pytest.approx(4.5, abs=1e-15)  # the last 2 of 3
    assert trial_score(log[:1]) == pytest.approx(9.0, abs=1e-15)


@pytest.mark.heavy
def test_best_start_goes_on_from_the_start_near_the_capture():
    """Two starts, one the capture's own materials, one 4x too dense with g 0.9: the trials' paired losses
    pick the first (whichever order), and the result is its trial's, not the other's."""
    truth = make_scene(n_teeth=1, resolution=12)
    cams, lights = default_rig(target=scene_target(truth), width=16, height=12, n_lights=6, n_cameras=1,
                               fov_x_deg=3.0)
    cap = render_capture(truth, cams, lights, spp=16, spp_background=0, seed=3)
    far = truth.copy()
    for t in far.teeth:
        t.enamel = VolumeMaterial(4 * t.enamel.sigma_t, t.enamel.albedo, 0.9)
        t.dentin = VolumeMaterial(4 * t.dentin.sigma_t, t.dentin.albedo, 0.9)
    s = replace(FitSettings(), start_trials=4, lights_per_iteration=2, image_spp=4, spp=2, held_out_lights=0,
                free=("*.sigma_t",))
    for starts, right in (([truth, far], 0), ([far, truth], 1)):
        result, scores = best_start(starts, cap, s)
        assert len(scores) == 2 and int(np.argmin(scores)) == right
        assert scores[1 - right] > 2 * scores[right]
        got = result.teeth[0].enamel.sigma_t / truth.teeth[0].enamel.sigma_t
        assert np.all(np.abs(got - 1) < 0.5), got  # the near start's trial, not the far one's (about 4x)


def test_one_start_or_no_trials_is_that_start():
    truth = make_scene(n_teeth=1, resolution=8)
    s = FitSettings()
    assert best_start([truth], None, s) == (truth, [])
    assert best_start([truth, truth.copy()], None, replace(s, start_trials=0)) == (truth, [])
    with pytest.raises(ValueError, match="no start"):
        best_start([], None, s)
    with pytest.raises(ValueError, match="start_trials"):
        FitSettings(start_trials=-1)
