"""The render-regression helper itself: it must fail on changed pixels and write its evidence."""

from __future__ import annotations

import numpy as np
import pytest
from regression import RegressionMismatch, compare_to_reference


def test_identical_passes_changed_fails(tmp_path):
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    img = np.random.default_rng(1).uniform(size=(6, 5, 4)).astype(np.float32)
    compare_to_reference("x", img, update=True, reference_dir=refs, output_dir=outs)
    compare_to_reference("x", img.copy(), update=False, reference_dir=refs, output_dir=outs)
    changed = img.copy()
    changed[2, 3, 1] += 1e-3
    with pytest.raises(RegressionMismatch, match=r"x: 1 of 120 values differ") as info:
        compare_to_reference("x", changed, update=False, reference_dir=refs, output_dir=outs)
    assert "x.diff.exr" in str(info.value)
    from material_structures.core.exr_io import read_exr

    diff = read_exr(f"{outs}/x.diff.exr", ["R", "G", "B", "A"])
    assert diff[2, 3, 1] == pytest.approx(1e-3, rel=1e-3)
    assert np.count_nonzero(diff) == 1
    # within tolerance passes
    compare_to_reference("x", changed, update=False, atol=2e-3, reference_dir=refs, output_dir=outs)


def test_missing_reference_fails_with_instructions(tmp_path):
    with pytest.raises(RegressionMismatch, match="make refs"):
        compare_to_reference(
            "nothing",
            np.zeros((2, 2, 3)),
            update=False,
            reference_dir=str(tmp_path),
            output_dir=str(tmp_path),
        )
