"""``FitSettings.average_tail``: the fit's result is the mean of its last iterates (Polyak-Ruppert
averaging), checked against the iterates the callback sees; the best-loss scene stays in
scene_best.json; an interrupted fit resumes to the same mean; bad values are clear errors."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from material_structures.core.teeth.optimise import FitSettings, fit, tail_start
from material_structures.core.teeth.param_vector import ParamLayout, scene_to_vector, to_optimiser
from material_structures.core.teeth.scene import TeethScene, VolumeMaterial

from ._teeth_scenes import slab_fit_problem


def _problem():
    return slab_fit_problem(8, 16, VolumeMaterial([1.5, 0.9, 2.4], [0.85, 0.95, 0.6], 0.5, -0.3, 0.7), max_depth=4)


BASE = dict(iterations=6, spp=1, lights_per_iteration=2, free=("slab.enamel.sigma_t", "slab.enamel.albedo"),
            lr=0.1, seed=2, max_depth=4, checkpoint_every=1, average_tail=0.5)


def _vec(scene, layout) -> np.ndarray:
    return to_optimiser(scene_to_vector(scene, layout), layout)


def test_tail_start():
    assert tail_start(10, 0.0) == 10  # nothing averaged
    assert tail_start(10, 0.3) == 7
    assert tail_start(10, 0.01) == 9  # at least the last iterate
    assert tail_start(300, 0.3) == 210


def test_fit_result_is_the_mean_of_the_last_iterates_and_resumes(tmp_path):
    theta, cap = _problem()
    layout = ParamLayout(theta)
    seen: list = []
    out = str(tmp_path / "straight")
    result, log = fit(theta, cap, FitSettings(**BASE), out_dir=out,
                      callback=lambda e, sc: seen.append(_vec(sc, layout)))
    assert len(seen) == 6
    expected = np.mean(seen[3:], axis=0)  # iterations 3, 4, 5
    np.testing.assert_allclose(_vec(result, layout), expected, rtol=1e-10, atol=1e-12)
    # the mean differs from every single iterate and from the start (the fit moved)
    assert min(np.abs(expected - s).max() for s in seen) > 1e-6
    with open(os.path.join(out, "scene_fit.json")) as f:
        np.testing.assert_allclose(_vec(TeethScene.from_dict(json.load(f)), layout), expected, rtol=1e-10, atol=1e-12)
    with open(os.path.join(out, "scene_best.json")) as f:
        best = _vec(TeethScene.from_dict(json.load(f)), layout)
    np.testing.assert_allclose(best, seen[int(np.argmin([e["loss"] for e in log]))], rtol=1e-10, atol=1e-12)
    # without averaging the result is the best-loss scene, as in the thesis
    plain, _ = fit(theta, cap, FitSettings(**{**BASE, "average_tail": 0.0}))
    np.testing.assert_allclose(_vec(plain, layout), best, rtol=1e-10, atol=1e-12)
    # interrupted inside the averaged iterations (after 4), resumed: the same mean
    cut = str(tmp_path / "cut")
    fit(theta, cap, FitSettings(**{**BASE, "iterations": 4, "average_tail": 0.5}), out_dir=cut)
    with open(os.path.join(cut, "checkpoint.json")) as f:
        ck = json.load(f)
    assert ck["avg_count"] == 2  # iterations 2 and 3 of the 4-iteration run
    # resuming with the 6-iteration settings keeps the sum so far (iterations 2 and 3) and adds 4 and 5,
    # which equal the straight run's
    resumed, _ = fit(theta, cap, FitSettings(**BASE), out_dir=cut, resume=True)
    np.testing.assert_allclose(_vec(resumed, layout), np.mean(seen[2:], axis=0), rtol=1e-10, atol=1e-12)
    again = str(tmp_path / "again")
    fit(theta, cap, FitSettings(**{**BASE, "iterations": 4, "average_tail": 0.5}), out_dir=again)
    np.testing.assert_allclose(_vec(fit(theta, cap, FitSettings(**BASE), out_dir=again, resume=True)[0], layout),
                               _vec(resumed, layout), rtol=1e-12)


@pytest.mark.parametrize("value", [-0.1, 1.0, 1.5])
def test_bad_average_tail_is_a_clear_error(value):
    with pytest.raises(ValueError, match="average_tail"):
        FitSettings(average_tail=value)
