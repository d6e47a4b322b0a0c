"""A teeth scene owns its values: scenes made from one material do not share it."""

from __future__ import annotations

import numpy as np


def test_scenes_made_from_one_material_do_not_share_it():
    """Editing one scene's media in place (a fit, a test) changes no other scene: the synthetic truth stays the
    truth. (Before, every tooth held the module's GROUND_TRUTH objects: a test's in-place a_t and sigma_t edits
    changed the teeth of every scene made later in that process.)"""
    from material_structures.core.teeth.synthetic import GROUND_TRUTH, make_scene

    truth = GROUND_TRUTH["enamel"].sigma_t.copy()
    a = make_scene(n_teeth=2, resolution=8)
    a.teeth[0].enamel.sigma_t *= 2.0
    a.teeth[0].enamel.g1 = 0.1
    a.teeth[0].a_t[:] = 0.5
    a.gums.material.albedo[:] = 0.1
    np.testing.assert_array_equal(GROUND_TRUTH["enamel"].sigma_t, truth)
    assert a.teeth[1].enamel.g1 == GROUND_TRUTH["enamel"].g1
    b = make_scene(n_teeth=2, resolution=8)
    np.testing.assert_array_equal(b.teeth[0].enamel.sigma_t, truth)
    assert np.all(b.teeth[0].a_t == 0.95) and np.all(b.gums.material.albedo == GROUND_TRUTH["gums"].albedo)
