"""The render-regression helper itself: it must fail on changed pixels and write its evidence."""

from __future__ import annotations

import numpy as np
import pytest
from regression import RegressionMismatch, compare_to_reference


def test_identical_passes_changed_fails(tmp_path):
    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    img = np.random.default_rng(1).uniform(size=(6, 5, 4)).astype(np.float32)
    compare_to_reference("x", img, update=True, reference_dir=refs, output_dir=outs, cls="")
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


def test_cpu_class_has_its_own_references(tmp_path):
    from regression import cpu_class

    refs, outs = str(tmp_path / "refs"), str(tmp_path / "out")
    img = np.random.default_rng(2).uniform(size=(4, 3, 4)).astype(np.float32)
    other = img.copy()
    other[1, 1, 0] += 0.01
    compare_to_reference("y", img, update=True, reference_dir=refs, output_dir=outs, cls="")
    # a class without references of its own compares against the default ones
    compare_to_reference("y", img, update=False, reference_dir=refs, output_dir=outs, cls="avx512")
    with pytest.raises(RegressionMismatch):
        compare_to_reference("y", other, update=False, reference_dir=refs, output_dir=outs, cls="avx512")
    # make refs on such a machine writes no reference of its own where its render matches the default one
    compare_to_reference("y", img, update=True, reference_dir=refs, output_dir=outs, cls="avx512")
    assert not (tmp_path / "refs" / "avx512" / "y.exr").exists()
    # ... and one where it differs, which it then uses; the default class keeps its own
    compare_to_reference("y", other, update=True, reference_dir=refs, output_dir=outs, cls="avx512")
    assert (tmp_path / "refs" / "avx512" / "y.exr").is_file()
    compare_to_reference("y", other, update=False, reference_dir=refs, output_dir=outs, cls="avx512")
    with pytest.raises(RegressionMismatch):
        compare_to_reference("y", img, update=False, reference_dir=refs, output_dir=outs, cls="avx512")
    compare_to_reference("y", img, update=False, reference_dir=refs, output_dir=outs, cls="")
    with pytest.raises(RegressionMismatch):
        compare_to_reference("y", other, update=False, reference_dir=refs, output_dir=outs, cls="")
    # the class from Linux's CPU flags
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 avx512f avx512vl\n")
    assert cpu_class(str(info)) == "avx512"
    info.write_text("processor\t: 0\nflags\t\t: fpu sse avx2 fma\n")
    assert cpu_class(str(info)) == ""
    assert cpu_class(str(tmp_path / "missing")) == ""
    # a new reference made on a machine of another class becomes the default one
    compare_to_reference("z", img, update=True, reference_dir=refs, output_dir=outs, cls="avx512")
    assert (tmp_path / "refs" / "z.exr").is_file() and not (tmp_path / "refs" / "avx512" / "z.exr").exists()
    compare_to_reference("z", img, update=False, reference_dir=refs, output_dir=outs, cls="")
    # a class's reference that is no longer needed is removed by the next update that matches the default
    compare_to_reference("y", img, update=True, reference_dir=refs, output_dir=outs, cls="avx512")
    assert not (tmp_path / "refs" / "avx512" / "y.exr").exists()
