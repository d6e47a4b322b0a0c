"""Acceptance: parameter recovery from a synthetic capture (2 teeth, 3 cameras at 96 x 64,
54 lights) from a perturbed start: sigma_t and albedo within 10 %, dentin coefficients within 0.05."""

from __future__ import annotations

import pytest

from material_structures.benchmarks.teeth import run_recovery


@pytest.mark.slow
@pytest.mark.timeout(5400)
@pytest.mark.xfail(strict=True, reason="issue 8 acceptance not met yet for the dentin coefficients: after 200 "
                   "iterations (Adam, then Gauss-Newton from iteration 80; bench/results/teeth.json) the errors "
                   "are 7.5 % (sigma_t), 6.0 % (albedo), 0.095 (c; target 0.05). c's gradient is mostly noise, "
                   "and its iterate wanders about 0.1 around the optimum (README, 'Why Adam stalls'); remove "
                   "this marker once it passes")
def test_parameter_recovery_acceptance():
    out = run_recovery()
    start = out["recovery_start"]
    # the start is genuinely perturbed ...
    assert start["recovery_sigma_t_rel_err"] > 0.2 and start["recovery_dentin_abs_err"] >= 0.2
    # ... and the fit recovers the ground truth
    assert out["recovery_sigma_t_rel_err"] < 0.10, out
    assert out["recovery_albedo_rel_err"] < 0.10, out
    assert out["recovery_dentin_abs_err"] < 0.05, out
