"""Acceptance: parameter recovery from a synthetic capture (2 teeth, 3 cameras at 96 x 64,
54 lights) from a perturbed start: sigma_t and albedo within 10 %, dentin coefficients within 0.05."""

from __future__ import annotations

import pytest

from material_structures.benchmarks.teeth import run_recovery


@pytest.mark.slow
@pytest.mark.timeout(3600)
@pytest.mark.xfail(strict=True, reason="issue 8 acceptance not met yet: after 200 Adam iterations (6 lights, "
                   "32-spp pass A, 4-spp pass B; bench/results/teeth.json) the errors are 21 % (sigma_t), 16 % "
                   "(albedo), 0.09 (c): the capture barely constrains dentin absorption and the shape coefficients "
                   "(`teeth sensitivity`: chi2 4-120 per +10 % sigma_a, 12-160 per +0.05 c, vs 6,600-14,000 for "
                   "dentin sigma_s), and dentin green/blue sigma_a stay 0.4-2x off; remove this marker once it passes")
def test_parameter_recovery_acceptance():
    out = run_recovery()
    start = out["recovery_start"]
    # the start is genuinely perturbed ...
    assert start["recovery_sigma_t_rel_err"] > 0.2 and start["recovery_dentin_abs_err"] >= 0.2
    # ... and the fit recovers the ground truth
    assert out["recovery_sigma_t_rel_err"] < 0.10, out
    assert out["recovery_albedo_rel_err"] < 0.10, out
    assert out["recovery_dentin_abs_err"] < 0.05, out
