"""The fit's choice among starts (``start_trials``): the fit's first iterations from each start, common
random numbers, the lowest mean loss over their last half wins, and the fit resumes the winner's trial."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from material_structures.core.teeth.capture import default_rig
from material_structures.core.teeth.fit_settings import FitSettings
from material_structures.core.teeth.optimise import fit
from material_structures.core.teeth.scene import TeethScene, VolumeMaterial, load_scene
from material_structures.core.teeth.start_trials import DROP_RATIO, best_start, trial_dir, trial_score
from material_structures.core.teeth.synthetic import make_scene, render_capture, scene_target


def test_trial_score_is_the_mean_of_the_last_half():
    log = [{"loss": v} for v in (9.0, 7.0, 2.0, 4.0)]
    assert trial_score(log) == pytest.approx(3.0, abs=1e-15)
    assert trial_score(log[:3]) == pytest.approx(4.5, abs=1e-15)  # the last 2 of 3
    assert trial_score(log[:1]) == pytest.approx(9.0, abs=1e-15)


def _tiny_capture():
    # as a fit's scene comes, from a file (its meshes rounded to 1e-9 mm): a resumed fit reads the scene
    # back from its checkpoint, so it continues to the bit only from a scene that rounding leaves alone
    truth = TeethScene.from_dict(make_scene(n_teeth=1, resolution=12).to_dict())
    cams, lights = default_rig(target=scene_target(truth), width=16, height=12, n_lights=6, n_cameras=1,
                               fov_x_deg=3.0)
    return truth, render_capture(truth, cams, lights, spp=16, spp_background=0, seed=3)


@pytest.mark.heavy
def test_best_start_picks_the_start_near_the_capture(tmp_path):
    """Two starts, one 1.25x the capture's extinction, one 4x with g 0.9: the trials' paired losses pick
    the first (whichever order), the far one stops at half its trial, and the near one's trial folder
    holds the near start's iterate."""
    truth, cap = _tiny_capture()
    near, far = truth.copy(), truth.copy()
    for t in near.teeth:
        t.enamel = VolumeMaterial(1.25 * t.enamel.sigma_t, t.enamel.albedo, t.enamel.g1)
    for t in far.teeth:
        t.enamel = VolumeMaterial(4 * t.enamel.sigma_t, t.enamel.albedo, 0.9)
        t.dentin = VolumeMaterial(4 * t.dentin.sigma_t, t.dentin.albedo, 0.9)
    s = replace(FitSettings(), start_trials=4, lights_per_iteration=2, image_spp=4, spp=2, held_out_lights=0,
                free=("*.sigma_t",))
    for starts, right in (([near, far], 0), ([far, near], 1)):
        work = str(tmp_path / f"order{right}")
        skipped = []
        trials = best_start(starts, cap, s, work, dropped=skipped.append)
        assert trials.chosen == right and len(trials.scores) == 2
        assert trials.iterations[right] == 4 and trials.iterations[1 - right] == 2 and skipped == [2]
        assert trials.scores[1 - right] > DROP_RATIO * trials.scores[right]
        got = load_scene(f"{trial_dir(work, right)}/scene_best.json").teeth[0].enamel.sigma_t
        assert np.all(np.abs(got / truth.teeth[0].enamel.sigma_t - 1) < 0.5), got  # not the far one's 4x


@pytest.mark.heavy
def test_no_start_stops_early_under_the_drop_ratio(tmp_path):
    """Two equally good starts (the same scene twice): neither stops at the half, both trials run to the
    end with the same losses, and the first is chosen."""
    truth, cap = _tiny_capture()
    s = replace(FitSettings(), start_trials=4, lights_per_iteration=2, image_spp=4, spp=2, held_out_lights=0,
                free=("*.sigma_t",))
    trials = best_start([truth, truth.copy()], cap, s, str(tmp_path / "w"))
    assert trials.iterations == [4, 4] and trials.chosen == 0
    assert trials.scores[0] == pytest.approx(trials.scores[1], rel=1e-8)


@pytest.mark.heavy
def test_the_fit_resumed_from_a_trial_is_the_fit_from_its_start(tmp_path):
    """The winner's trial is the fit's first ``start_trials`` iterations: resumed to the end, its log and
    result are those of the uninterrupted fit from the same start, to the bit."""
    truth, cap = _tiny_capture()
    start = truth.copy()
    for t in start.teeth:
        t.enamel = VolumeMaterial(1.5 * t.enamel.sigma_t, t.enamel.albedo, 0.5)
    s = replace(FitSettings(), iterations=6, start_trials=3, lights_per_iteration=2, image_spp=4, spp=2,
                held_out_lights=0, free=("*.sigma_t", "*.albedo"))
    work = str(tmp_path / "trials")
    trials = best_start([start, truth], cap, s, work)
    chosen, scores = trials.chosen, trials.scores
    resumed, log = fit([start, truth][chosen], cap, s, out_dir=trial_dir(work, chosen), resume=True)
    whole, whole_log = fit([start, truth][chosen], cap, s)
    assert len(log) == 6 and [e["loss"] for e in log] == [e["loss"] for e in whole_log]
    assert scores[chosen] == trial_score(whole_log[:3])
    np.testing.assert_array_equal(resumed.teeth[0].enamel.sigma_t, whole.teeth[0].enamel.sigma_t)
    np.testing.assert_array_equal(resumed.teeth[0].dentin.albedo, whole.teeth[0].dentin.albedo)
    assert np.abs(whole.teeth[0].enamel.sigma_t / start.teeth[0].enamel.sigma_t - 1).max() > 1e-3  # it moved


def test_one_start_or_no_trials_runs_no_trial():
    truth = make_scene(n_teeth=1, resolution=8)
    s = FitSettings()
    assert best_start([truth], None, s, "unused") is None
    assert best_start([truth, truth.copy()], None, replace(s, start_trials=0), "unused") is None
    with pytest.raises(ValueError, match="no start"):
        best_start([], None, s, "unused")
    with pytest.raises(ValueError, match="start_trials"):
        FitSettings(start_trials=-1)


def test_every_drop_is_announced_before_the_second_halves_run(monkeypatch, tmp_path):
    """The progress total shrinks before any second half runs, so the last progress event reads
    "done of done" even where the last start is the one dropped (a fake fit: start k's loss is given); every
    trial renders where the fit does (its gradient and task map)."""
    from material_structures.core.teeth import start_trials

    loss = {0: 1.0, 1: 1.1, 2: 5.0}  # start 2 is over DROP_RATIO times start 0's: dropped at the half
    events = []

    backends = (object(), object())  # the gradient and task map the trials render with (a cluster's)

    def fake_fit(scene, capture, settings, out_dir, resume, progress, until, gradient, task_map):
        k = int(out_dir[-1])
        assert (gradient, task_map) == backends
        events.append(("run", k, until))
        return scene, [{"loss": loss[k]} for _ in range(until)]

    monkeypatch.setattr(start_trials, "fit", fake_fit)
    settings = replace(FitSettings(), start_trials=10, iterations=40)
    out = start_trials.best_start([0, 1, 2], None, settings, str(tmp_path),
                                  dropped=lambda n: events.append(("dropped", n)), gradient=backends[0],
                                  task_map=backends[1])
    assert events == [("run", 0, 5), ("run", 1, 5), ("run", 2, 5), ("dropped", 5), ("run", 0, 10), ("run", 1, 10)]
    assert out.chosen == 0 and out.iterations == [10, 10, 5]
