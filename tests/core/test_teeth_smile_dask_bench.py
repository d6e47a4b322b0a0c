"""``bench teeth-smile-dask`` (benchmarks/teeth_smile_dask.py): its projection schedules tasks as a cluster would,
and (nightly) a short run on a tiny capture gives every figure."""

from __future__ import annotations

import json

import pytest

from material_structures.benchmarks import teeth_smile_dask as bench


def test_makespan_is_longest_first_list_scheduling():
    """Closed forms: one worker adds everything up; as many workers as tasks take the longest; 3, 3, 2, 2, 2 on
    two workers: longest first gives 3 + 2 + 2 | 3 + 2, finishing at 7 (the optimum is 6: a bound, not the
    optimum); no task, nothing."""
    assert bench.makespan([1.0, 2.0, 3.0], 1) == pytest.approx(6.0)
    assert bench.makespan([1.0, 2.0, 3.0], 5) == pytest.approx(3.0)
    assert bench.makespan([3.0, 3.0, 2.0, 2.0, 2.0], 2) == pytest.approx(7.0)
    assert bench.makespan([], 4) == 0.0


@pytest.mark.slow
def test_a_short_run_on_a_tiny_capture(monkeypatch, tmp_path):
    """Nightly: a 3-camera, 8-light capture of one tooth: every step is timed on the local cluster and the projection
    falls as workers are added until the tasks run out."""
    pytest.importorskip("distributed")
    from material_structures.cli import main

    assert main(["teeth", "synth", "--out", str(tmp_path / "capture"), "--teeth", "1", "--width", "24", "--height",
                 "16", "--lights", "8", "--cameras", "3", "--samples", "2", "--samples-background", "1",
                 "--mesh-resolution", "12"]) == 0
    monkeypatch.setenv("TEETH_SMILE_KEEP", str(tmp_path))
    monkeypatch.setenv("TEETH_SMILE_DASK_ITERATIONS", "1")
    out = json.loads(json.dumps(bench.teeth_smile_dask()))
    steps = out["steps"]
    assert steps["iteration"]["count"] == 300 and steps["gauss_newton"]["count"] == 6
    assert steps["iteration"]["tasks"] >= 4 and steps["intervals"]["tasks"] > 6  # bands; shape dirs + chunks
    minutes = [out["projected_fit_minutes"][str(n)] for n in bench.PROJECT_WORKERS]
    assert all(b <= a + 1e-12 for a, b in zip(minutes, minutes[1:], strict=False)) and minutes[1] < minutes[0]
    assert out["workers_below_30_min"] == 1
