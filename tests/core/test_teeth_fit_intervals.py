"""The fit report's intervals (core/teeth/fit_intervals.py): the capture's noise estimated from its own pixels
(against a known sigma), the literature prior (against sampling its range), the intervals and open combinations
of a known information matrix (closed form), their coverage of the truth (Monte Carlo), and the whole report on
a small capture."""

from __future__ import annotations

import numpy as np
import pytest

from material_structures.core.teeth.capture import Capture, default_rig
from material_structures.core.teeth.fit_intervals import (
    LOG_STEP,
    OPEN_STEPS,
    calibration,
    capture_noise_variance,
    intervals_from_information,
    literature_range,
    parameter_intervals,
    parameter_lines,
    prior_covariance,
    summary,
)
from material_structures.core.teeth.literature_init import ALBEDO_RANGE, SIGMA_RANGE_MM


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


def test_the_literature_prior_matches_sampling_its_range():
    """Sigma_0 of the sigma_s, sigma_a pair against 400 000 samples of log sigma_t and log10(1 - albedo) uniform
    over the literature's range (within 1 %), and a uniform range's variance (hi - lo)^2 / 12 for the others."""
    rng = np.random.default_rng(5)
    n = 400_000
    log_st = rng.uniform(np.log(SIGMA_RANGE_MM[0]), np.log(SIGMA_RANGE_MM[1]), n)
    kappa = rng.uniform(np.log10(1 - ALBEDO_RANGE[1]), np.log10(1 - ALBEDO_RANGE[0]), n)
    albedo = 1.0 - 10.0 ** kappa
    sampled = np.cov(np.stack([log_st + np.log(albedo), log_st + np.log(1.0 - albedo)]))
    names = ["gums.sigma_s[1]", "gums.sigma_a[1]", "tooth0.dentin.g1", "tooth0.enamel.beta", "tooth0.c[2]"]
    cov = prior_covariance(names, [0.1, 0.1, 0.05, 0.05, 0.05])
    np.testing.assert_allclose(cov[:2, :2] * LOG_STEP ** 2, sampled, rtol=0.01)
    g_lo, g_hi = literature_range("tooth0.dentin.g1")
    assert (g_lo, g_hi) == (0.3, 0.9)
    np.testing.assert_allclose(np.diag(cov)[2:], np.array([0.6, 1.0, 1.6]) ** 2 / 12 / 0.05 ** 2, rtol=1e-12)
    assert np.count_nonzero(cov - np.diag(np.diag(cov))) == 2  # only the pair is correlated


def _g1_sd0_steps() -> float:
    return 0.6 / np.sqrt(12.0) / 0.05


def test_intervals_of_a_known_information_matrix():
    """g1 with information 25 (in steps of 0.05): the posterior sd is 1 / sqrt(25 + 1 / sd0^2) steps (closed form,
    sd0 from the literature's 0.3-0.9); the fit's reduced chi-square b divides the information (b = 4: 6.25);
    b below 1 or unknown changes nothing. Determined is sd <= sd0 / 3, i.e. information >= 8 / sd0^2."""
    names, steps = ["tooth0.enamel.g1"], [0.05]
    sd0 = _g1_sd0_steps()
    for b, info in ((1.0, 25.0), (4.0, 6.25), (0.5, 25.0), (float("nan"), 25.0)):
        rep = intervals_from_information(np.array([[25.0]]), names, steps, [0.6], reduced_chi2=b)
        (p,) = rep["parameters"]
        half = 2.0 * 0.05 / np.sqrt(info + 1.0 / sd0 ** 2)
        assert p["interval_2sigma"] == pytest.approx([0.6 - half, 0.6 + half], abs=1e-12)
        assert p["determined"] and p["interval_from"] == "capture"
        assert rep["reduced_chi2"] == (b if b > 1 else 1.0)
    for f, det in ((1.01, True), (0.99, False)):
        rep = intervals_from_information(np.array([[f * 8.0 / sd0 ** 2]]), names, steps, [0.6])
        assert rep["parameters"][0]["determined"] is det
        assert rep["parameters"][0]["narrowing"] == pytest.approx(1 / np.sqrt(f * 8 + 1), rel=1e-12)
    # nothing measured: the literature's range (the hull with value +- 2 sd0, clipped to the valid range, for a
    # tooth's g1 the literature's 0.3-0.9 the fit keeps to; the gums' g1 the phase function's -0.9-0.95)
    for name, top in (("tooth0.enamel.g1", 0.9), ("gums.g1", 0.95)):
        (p,) = intervals_from_information(np.zeros((1, 1)), [name], steps, [0.8])["parameters"]
        assert not p["determined"] and p["interval_from"].startswith("literature range")
        assert p["interval_2sigma"] == pytest.approx([0.3, min(0.8 + 2 * 0.6 / np.sqrt(12), top)], abs=1e-12)
    # a relative step: sigma_s and sigma_a intervals are value * exp(+-2 sd LOG_STEP)
    pair = ["tooth0.enamel.sigma_s[0]", "tooth0.enamel.sigma_a[0]"]
    info = np.diag([400.0, 100.0])
    rep = intervals_from_information(info, pair, [0.1, 0.1], [0.8, 0.03])
    post = np.linalg.inv(info + np.linalg.inv(prior_covariance(pair, [0.1, 0.1])))
    for p, v, var in zip(rep["parameters"], (0.8, 0.03), np.diag(post), strict=True):
        assert p["interval_2sigma"] == pytest.approx(v * np.exp(np.array([-2, 2]) * np.sqrt(var) * LOG_STEP),
                                                     rel=1e-12)


def test_open_combinations_are_named_in_words():
    """F with eigenvectors (1, -1, 0) / sqrt 2 (information 1e-4: open), (1, 1, 0) / sqrt 2 (400) and (0, 0, 1)
    (25): sigma_s and sigma_a of the enamel trade off one up, the other down, and their intervals are the
    literature's range; estimator noise making F indefinite is an open combination, not an error."""
    a = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    b = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    c = np.array([0.0, 0.0, 1.0])
    info = 1e-4 * np.outer(a, a) + 400.0 * np.outer(b, b) + 25.0 * np.outer(c, c)
    names = ["tooth0.enamel.sigma_s[0]", "tooth0.enamel.sigma_a[0]", "tooth0.enamel.g1"]
    rep = intervals_from_information(info, names, [0.1, 0.1, 0.05], [0.8, 0.03, 0.6])
    p = {q["name"]: q for q in rep["parameters"]}
    assert [p[n]["determined"] for n in names] == [False, False, True]
    s_lo, s_hi = literature_range(names[0])
    assert p[names[0]]["interval_2sigma"][0] <= s_lo and p[names[0]]["interval_2sigma"][1] >= s_hi
    (u,) = rep["undetermined"]
    assert sorted(u["parameters"]) == sorted(names[:2])
    assert "one up and the other down" in u["text"] and "scattering (red)" in u["text"]
    assert "absorption (red)" in u["text"] and rep["determined_count"] == 1
    # the open combination's threshold: 2 / sqrt(w) = OPEN_STEPS steps is still measured, a little less is not
    for w, opened in (((2.0 / OPEN_STEPS) ** 2 * 1.01, 0), ((2.0 / OPEN_STEPS) ** 2 * 0.99, 1)):
        combos = intervals_from_information(np.array([[w]]), names[2:], [0.05], [0.6])["undetermined"]
        assert sum(c["parameters"] == names[2:] for c in combos) == opened
    neg = intervals_from_information(np.diag([25.0, -3.0]), ["tooth0.c[0]", names[2]], [0.05, 0.05], [0.1, 0.6])
    assert [q["determined"] for q in neg["parameters"]] == [True, False]


def test_a_tissue_with_an_open_phase_function_has_its_scattering_absorption_and_other_lobe_open():
    """The similarity relation: the enamel's g1 open (information 1e-4), its sigma_s, sigma_a and g2 narrowed by
    the local bound alone (400 each): all three are named undetermined and get the literature's range, the
    trade-off is named; the dentin, whose g1 is determined, keeps its scattering interval from the capture."""
    names = ["tooth0.enamel.sigma_s[0]", "tooth0.enamel.sigma_a[0]", "tooth0.enamel.g2", "tooth0.enamel.g1",
             "tooth0.dentin.sigma_s[0]", "tooth0.dentin.g1"]
    info = np.diag([400.0, 400.0, 400.0, 1e-4, 400.0, 25.0])
    rep = intervals_from_information(info, names, [0.1, 0.1, 0.05, 0.05, 0.1, 0.05], [0.8, 0.03, -0.3, 0.6, 1.5,
                                                                                       0.4])
    p = {q["name"]: q for q in rep["parameters"]}
    assert [p[n]["determined"] for n in names] == [False, False, False, False, True, True]
    assert p["tooth0.enamel.g2"]["interval_2sigma"] == list(literature_range("tooth0.enamel.g2"))
    for n in names[:2]:
        lo, hi = literature_range(n)
        assert p[n]["interval_2sigma"][0] <= lo and p[n]["interval_2sigma"][1] >= hi
        assert p[n]["interval_from"].startswith("literature range")
    sd = 1.0 / np.sqrt(400.0 + 1.0 / prior_covariance(names[4:5], [0.1])[0, 0])
    assert p[names[4]]["interval_2sigma"] == pytest.approx(1.5 * np.exp(np.array([-2, 2]) * sd * LOG_STEP),
                                                           rel=1e-12)
    assert rep["determined_count"] == 2
    (alone, similarity) = rep["undetermined"]
    assert alone["parameters"] == ["tooth0.enamel.g1"]
    assert similarity["parameters"] == ["tooth0.enamel.sigma_s", "tooth0.enamel.g1"]
    assert "tooth0 enamel scattering and its phase function trade off" in similarity["text"]


def test_intervals_cover_the_truth_when_the_fit_misses_by_more_than_the_noise():
    """Monte Carlo of the linearised model: truths uniform over the literature's range of g1 and beta, fits
    scattered about them by b F^-1 (a fit whose residual is b = 4 times the noise, F = diag(400, 100) in steps).
    Reported with its reduced chi-square, 95.4 % of the 2-sigma intervals hold the truth (4000 draws: within
    [0.94, 0.97], binomial sd 0.33 %); reported as if the fit were at the noise, about 68 %."""
    rng = np.random.default_rng(11)
    names, steps, info, b = ["tooth0.enamel.g1", "tooth0.enamel.beta"], [0.05, 0.05], np.diag([400.0, 100.0]), 4.0
    lo = np.array([literature_range(n)[0] for n in names])
    hi = np.array([literature_range(n)[1] for n in names])
    hits = {4.0: np.zeros(2), 1.0: np.zeros(2)}
    n = 4000
    for _ in range(n):
        truth = rng.uniform(lo + 0.1, hi - 0.1)  # away from the valid range's clip
        fit = truth + np.array(steps) * rng.normal(0.0, np.sqrt(b / np.diag(info)))
        for told in hits:
            rep = intervals_from_information(info, names, steps, list(fit), reduced_chi2=told)
            hits[told] += [p["interval_2sigma"][0] <= t <= p["interval_2sigma"][1]
                           for p, t in zip(rep["parameters"], truth, strict=True)]
    assert np.all((hits[4.0] / n > 0.94) & (hits[4.0] / n < 0.97)), hits[4.0] / n
    assert np.all(hits[1.0] / n < 0.75), hits[1.0] / n


def test_calibration_counts_the_truth_inside_and_names_the_determined_misses():
    """A report with one interval holding the truth's value (the synthetic scene's enamel g1), one determined
    interval missing it (its red absorption, sigma_t (1 - albedo)) and one undetermined parameter whose range
    misses too: 1 of 3 inside, the determined miss and the undetermined one named apart."""
    from material_structures.core.teeth.synthetic import make_scene

    truth = make_scene(n_teeth=1)
    g1 = truth.teeth[0].enamel.g1
    sa = float(truth.teeth[0].enamel.sigma_t[0] * (1.0 - truth.teeth[0].enamel.albedo[0]))
    report = {"parameters": [
        {"name": "tooth0.enamel.g1", "value": g1 + 0.01, "interval_2sigma": [g1 - 0.01, g1 + 0.03],
         "determined": True},
        {"name": "tooth0.enamel.sigma_a[0]", "value": 2.0 * sa, "interval_2sigma": [1.5 * sa, 2.5 * sa],
         "determined": True},
        {"name": "tooth0.enamel.sigma_s[0]", "value": 1e3, "interval_2sigma": [500.0, 2000.0], "determined": False}]}
    cal = calibration(report, truth)
    assert cal["inside"] == 1 and cal["parameters"] == 3 and cal["inside_share"] == pytest.approx(1 / 3)
    assert cal["outside_determined"] == ["tooth0.enamel.sigma_a[0]"]
    assert cal["outside_undetermined"] == cal["undetermined"] == ["tooth0.enamel.sigma_s[0]"]
    assert cal["per_parameter"][1]["truth"] == pytest.approx(sa, rel=1e-12)


def test_the_report_on_a_small_capture():
    """A tiny synthetic capture (one tooth, 3 lights): every determined parameter's interval holds its value
    and is finite; the phase functions under 3 lights are open and named in words; the summary line says so."""
    from material_structures.core.teeth.synthetic import make_scene, render_capture

    scene = make_scene(n_teeth=1, resolution=10, with_gums=False, with_cavity=False)
    cams, lights = default_rig(width=16, height=12, n_lights=3)
    cap = render_capture(scene, cams, lights, spp=4, seed=1)
    rep = parameter_intervals(scene, cap, passes=3)
    assert rep["noise_variance"] > 0 and rep["reduced_chi2"] >= 1.0
    by_name = {p["name"]: p for p in rep["parameters"]}
    assert "tooth0.enamel.sigma_s[0]" in by_name and "tooth0.enamel.g1" in by_name
    for p in rep["parameters"]:  # every parameter has an interval; an undetermined one spans the literature's
        lo, hi = p["interval_2sigma"]
        assert np.isfinite(lo) and np.isfinite(hi) and lo <= p["value"] <= hi
        assert p["interval_from"] == "capture" if p["determined"] else p["interval_from"].startswith("literature")
    assert rep["undetermined"] and all("trade off" in u["text"] or "not measured" in u["text"]
                                       for u in rep["undetermined"])
    assert summary(rep).startswith(f"The capture determines {rep['determined_count']} of {len(rep['parameters'])} "
                                   "parameters")
    lines = parameter_lines(rep)  # the panel's list, in words, with the unit and where each interval comes from
    assert len(lines) == len(rep["parameters"])
    first = rep["parameters"][0]
    assert lines[0].startswith(f"{first['words']}: ") and " /mm, " in lines[0]
    assert lines[0].endswith("(measured)" if first["determined"] else "(open: the literature's range)")
