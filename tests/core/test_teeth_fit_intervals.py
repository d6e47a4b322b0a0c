"""The fit report's intervals (core/teeth/fit_intervals.py): the capture's noise estimated from its own pixels
(against a known sigma), the Cramer-Rao intervals and open combinations of a known information matrix (closed
form), and the whole report on a small capture."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.fit_intervals import (
    OPEN_STEPS,
    calibration,
    capture_noise_variance,
    intervals_from_information,
    parameter_intervals,
    summary,
)


def _flat_capture(sigma: float, seed: int = 0) -> Capture:
    cams, lights = default_rig(width=40, height=30, n_lights=3)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:30, 0:40]
    shading = (0.3 + 0.004 * xx + 0.003 * yy)[None, None, :, :, None]  # smooth image content
    images = shading + rng.normal(0.0, sigma, (len(cams), len(lights), 30, 40, 3))
    masks = np.zeros((len(cams), 30, 40), dtype=bool)
    masks[:, 5:25, 5:35] = True
    return Capture(cams, lights, images, masks)


@pytest.mark.parametrize("sigma", [0.01, 0.05])
def test_noise_is_estimated_from_the_capture_itself(sigma):
    """Gaussian noise of known sigma on smooth shading: the estimate is within 10 % of sigma^2."""
    assert capture_noise_variance(_flat_capture(sigma)) == pytest.approx(sigma ** 2, rel=0.10)


def test_intervals_and_open_combinations_of_a_known_information_matrix():
    """F with eigenvectors (1, -1, 0) / sqrt 2 (information 1e-4: open), (1, 1, 0) / sqrt 2 (400) and (0, 0, 1)
    (25): sigma_s and sigma_a of the enamel trade off one up, the other down, and get no interval; g1 gets
    2 / sqrt(25) = 0.4 steps of 0.05, i.e. +-0.02 (closed form)."""
    a = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    b = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    c = np.array([0.0, 0.0, 1.0])
    info = 1e-4 * np.outer(a, a) + 400.0 * np.outer(b, b) + 25.0 * np.outer(c, c)
    names = ["tooth0.enamel.sigma_s[0]", "tooth0.enamel.sigma_a[0]", "tooth0.enamel.g1"]
    rep = intervals_from_information(info, names, [0.1, 0.1, 0.05], [0.8, 0.03, 0.6])
    p = {q["name"]: q for q in rep["parameters"]}
    assert not p[names[0]]["determined"] and p[names[0]]["interval_2sigma"] is None
    assert not p[names[1]]["determined"]
    assert p[names[2]]["determined"]
    assert p[names[2]]["interval_2sigma"] == pytest.approx([0.58, 0.62], abs=1e-12)
    (u,) = rep["undetermined"]
    assert sorted(u["parameters"]) == sorted(names[:2])
    assert "one up and the other down" in u["text"] and "scattering (red)" in u["text"]
    assert "absorption (red)" in u["text"] and rep["determined_count"] == 1
    # an information at the threshold: 2 / sqrt(w) = OPEN_STEPS steps is still determined, a little less is not
    for w, det in (((2.0 / OPEN_STEPS) ** 2 * 1.01, True), ((2.0 / OPEN_STEPS) ** 2 * 0.99, False)):
        one = intervals_from_information(np.array([[w]]), names[2:], [0.05], [0.6])
        assert one["parameters"][0]["determined"] is det
    # estimator noise can make F indefinite: a negative eigenvalue is an open combination, not an error
    neg = intervals_from_information(np.diag([25.0, -3.0]), ["tooth0.c[0]", names[2]], [0.05, 0.05], [0.1, 0.6])
    assert [q["determined"] for q in neg["parameters"]] == [True, False]


def test_a_tissue_with_an_open_phase_function_has_no_scattering_or_absorption_interval():
    """The similarity relation: the enamel's g1 open (information 1e-4), its sigma_s and sigma_a determined by the
    local bound alone (400 each): both lose their intervals and the trade-off is named; the dentin, whose g1 is
    determined, keeps its scattering interval."""
    names = ["tooth0.enamel.sigma_s[0]", "tooth0.enamel.sigma_a[0]", "tooth0.enamel.g1", "tooth0.dentin.sigma_s[0]",
             "tooth0.dentin.g1"]
    info = np.diag([400.0, 400.0, 1e-4, 400.0, 25.0])
    rep = intervals_from_information(info, names, [0.1, 0.1, 0.05, 0.1, 0.05], [0.8, 0.03, 0.6, 1.5, 0.4])
    p = {q["name"]: q for q in rep["parameters"]}
    assert [p[n]["determined"] for n in names] == [False, False, False, True, True]
    assert p[names[0]]["interval_2sigma"] is None and p[names[1]]["interval_2sigma"] is None
    assert p[names[3]]["interval_2sigma"] == pytest.approx([1.5 * 0.99, 1.5 * 1.01], rel=1e-12)
    assert rep["determined_count"] == 2
    (alone, similarity) = rep["undetermined"]
    assert alone["parameters"] == ["tooth0.enamel.g1"]
    assert similarity["parameters"] == ["tooth0.enamel.sigma_s", "tooth0.enamel.g1"]
    assert "tooth0 enamel scattering and its phase function trade off" in similarity["text"]


def test_calibration_counts_the_truth_inside_and_names_the_determined_misses():
    """A report with one interval holding the truth's value (the synthetic scene's enamel g1), one missing it
    (its red absorption, sigma_t (1 - albedo)) and one undetermined parameter: 1 of 3 inside, the miss named."""
    from material_structures.core.teeth.synthetic import make_scene

    truth = make_scene(n_teeth=1)
    g1 = truth.teeth[0].enamel.g1
    sa = float(truth.teeth[0].enamel.sigma_t[0] * (1.0 - truth.teeth[0].enamel.albedo[0]))
    report = {"parameters": [
        {"name": "tooth0.enamel.g1", "value": g1 + 0.01, "interval_2sigma": [g1 - 0.01, g1 + 0.03]},
        {"name": "tooth0.enamel.sigma_a[0]", "value": 2.0 * sa, "interval_2sigma": [1.5 * sa, 2.5 * sa]},
        {"name": "tooth0.enamel.sigma_s[0]", "value": 1.0, "interval_2sigma": None}]}
    cal = calibration(report, truth)
    assert cal["inside"] == 1 and cal["parameters"] == 3 and cal["inside_share"] == pytest.approx(1 / 3)
    assert cal["outside_determined"] == ["tooth0.enamel.sigma_a[0]"]
    assert cal["undetermined"] == ["tooth0.enamel.sigma_s[0]"]
    assert cal["per_parameter"][1]["truth"] == pytest.approx(sa, rel=1e-12)


def test_the_report_on_a_small_capture():
    """A tiny synthetic capture (one tooth, 3 lights): every determined parameter's interval holds its value
    and is finite; the phase functions under 3 lights are open and named in words; the summary line says so."""
    from material_structures.core.teeth.synthetic import make_scene, render_capture

    scene = make_scene(n_teeth=1, resolution=10, with_gums=False, with_cavity=False)
    cams, lights = default_rig(width=16, height=12, n_lights=3)
    cap = render_capture(scene, cams, lights, spp=4, seed=1)
    rep = parameter_intervals(scene, cap, passes=3)
    assert rep["noise_variance"] > 0
    by_name = {p["name"]: p for p in rep["parameters"]}
    assert "tooth0.enamel.sigma_s[0]" in by_name and "tooth0.enamel.g1" in by_name
    for p in rep["parameters"]:
        if p["determined"]:
            lo, hi = p["interval_2sigma"]
            assert np.isfinite(lo) and np.isfinite(hi) and lo <= p["value"] <= hi
    assert rep["undetermined"] and all("trade off" in u["text"] or "not measured" in u["text"]
                                       for u in rep["undetermined"])
    assert summary(rep).startswith(f"{rep['determined_count']} of {len(rep['parameters'])} parameters determined")
