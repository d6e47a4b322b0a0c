"""Acceptance: parameter recovery from a synthetic capture (2 teeth, 3 cameras at 96 x 64,
54 lights) from a perturbed start: sigma_t and albedo within 10 %, dentin coefficients within 0.05."""

from __future__ import annotations

import pytest

from material_structures.benchmarks.teeth import run_recovery


@pytest.mark.slow
@pytest.mark.timeout(5400)
@pytest.mark.xfail(strict=True, reason="issue 8 acceptance not met yet: after 200 Adam iterations (6 lights, "
                   "32-spp pass A, 4-spp pass B; bench/results/teeth.json) the errors are 21 % (sigma_t), 16 % "
                   "(albedo), 0.09 (c). Adam stalls in the valley where enamel and dentin absorption trade off "
                   "(the stall is chi2 ~9,000 from the truth under the capture noise, and the gradient there "
                   "points to the truth); the experimental Gauss-Newton option reached 12 % / 11 % / 0.10 at "
                   "iteration 100 but then diverged (README, 'Why Adam stalls'); remove this marker once it passes")
def test_parameter_recovery_acceptance():
    out = run_recovery()
    start = out["recovery_start"]
    # the start is genuinely perturbed ...
    assert start["recovery_sigma_t_rel_err"] > 0.2 and start["recovery_dentin_abs_err"] >= 0.2
    # ... and the fit recovers the ground truth
    assert out["recovery_sigma_t_rel_err"] < 0.10, out
    assert out["recovery_albedo_rel_err"] < 0.10, out
    assert out["recovery_dentin_abs_err"] < 0.05, out
