"""Smoke test of ``bench teeth``'s recovery path (the acceptance scene and rig, 1-spp capture, 2 iterations):
it runs, reports the fit's result, its best-loss parameters and the start, and says what it measured."""

from __future__ import annotations

import pytest

from material_structures.benchmarks.teeth import RECOVERY_SETTINGS, run_recovery

pytestmark = pytest.mark.heavy  # seconds each: outside `make test-fast`


def test_run_recovery_on_a_small_rig_reports_result_best_and_start(monkeypatch):
    """``test_run_recovery_reports_result_best_and_start`` (nightly) with the acceptance scene and rig at 24 x 16
    pixels instead of 96 x 64 (the same views; 30 of the 37 s were the 2 iterations' renders)."""
    from material_structures.core.teeth import capture

    real_rig, rigs = capture.default_rig, []

    def small_rig(*a, **kw):
        rigs.append(kw)
        return real_rig(*a, **{**kw, "width": 24, "height": 16})

    monkeypatch.setattr(capture, "default_rig", small_rig)
    _check_recovery(run_recovery(iterations=2, synth_spp=1))
    assert [(r["width"], r["height"]) for r in rigs] == [(96, 64)]  # the acceptance rig's call


@pytest.mark.slow
def test_run_recovery_reports_result_best_and_start():
    """Short counterpart in `make test`: test_run_recovery_on_a_small_rig_reports_result_best_and_start."""
    _check_recovery(run_recovery(iterations=2, synth_spp=1))


def _check_recovery(out):
    keys = ("recovery_sigma_t_rel_err", "recovery_albedo_rel_err", "recovery_dentin_abs_err")
    assert out["recovery_iterations"] == 2
    for part in (out, out["recovery_best_loss_params"], out["recovery_start"]):
        assert all(0.0 <= part[k] < 1.0 for k in keys), part
    # the start is the perturbed one (sigma_t x exp(+-0.25), c reset by 0.2), and two Adam steps of at
    # most lr = 0.04 each in the optimiser domain cannot undo it
    assert out["recovery_start"]["recovery_sigma_t_rel_err"] > 0.2
    assert out["recovery_dentin_abs_err"] > 0.2 - 2 * RECOVERY_SETTINGS["lr"] - 1e-9
    assert "capture 1 spp" in out["recovery_config"] and "average_tail" in out["recovery_config"]
