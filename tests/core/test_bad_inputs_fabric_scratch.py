"""Bad input to the fabric and scratch commands: each case is a one-line ``error: ...`` naming the problem
(exit 2), nothing written, no traceback; the input folder is byte-identical afterwards."""

from __future__ import annotations

import hashlib

import pytest

from material_structures.cli import main
from material_structures.cli.checks import check_memory


def _tree(path) -> dict:
    return {p.relative_to(path).as_posix(): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("in")
    # 4 lights x 4 views: what ``fabric synth`` writes when asked, too few directions to fit
    assert main(["fabric", "synth", "--out", str(d / "btf16"), "--width", "3", "--height", "3", "--lights", "4",
                 "--views", "4"]) == 0
    assert main(["scratch", "generate", "--kind", "wear", "--count", "20", "--out", str(d / "s.npz")]) == 0
    return d


@pytest.mark.parametrize("argv, said", [
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--no-dask"], "16 light/view pairs cover 0 of the"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--workers", "1"], "16 light/view pairs cover 0 of the"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--tile", "0"], "--tile: must be >= 1, got 0"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--workers", "-3"], "--workers: must be >= 1, got -3"),
    (["fabric", "synth", "--out", "{o}/b", "--width", "-5"], "--width: must be >= 1, got -5"),
    (["fabric", "synth", "--out", "{o}/b", "--lights", "0"], "--lights: must be >= 1, got 0"),
    (["fabric", "synth", "--out", "{o}/b", "--noise", "nan"], "'nan' is not a finite number"),
    (["fabric", "synth", "--out", "{o}/b", "--theta-max", "120"], "--theta-max: must be <= 89, got 120"),
    (["fabric", "ndf", "{d}/btf16", "--resolution", "0", "--out", "{o}/n.exr"], "--resolution: must be >= 4"),
    (["scratch", "generate", "--count", "-5", "--out", "{o}/g.npz"], "--count: must be >= 1, got -5"),
    (["scratch", "generate", "--count", "50000000", "--out", "{o}/g.npz"], "--count: must be <= 16777216"),
    (["scratch", "generate", "--sigma-um", "nan", "--out", "{o}/g.npz"], "--sigma-um: 'nan' is not a finite"),
    (["scratch", "generate", "--patch-mm", "0", "--out", "{o}/g.npz"], "--patch-mm: must be >= 0.001, got 0"),
    (["scratch", "eval", "{d}/s.npz", "--size", "200000", "--out", "{o}/e.exr"], "--size: must be <= 16384"),
    (["scratch", "eval", "{d}/s.npz", "--light", "0", "0", "1", "0", "--out", "{o}/e.exr"], "radius R must be > 0"),
    (["scratch", "eval", "{d}/s.npz", "--view-deg", "inf", "--out", "{o}/e.exr"], "'inf' is not a finite number"),
])
def test_bad_numbers_and_unfittable_btfs_are_one_line_errors(inputs, tmp_path, capsys, argv, said):
    before = _tree(inputs)
    assert main([a.format(d=inputs, o=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert _tree(inputs) == before
    assert list(tmp_path.iterdir()) == []  # nothing written, not even a cache folder


def test_work_larger_than_memory_is_refused_before_allocating():
    with pytest.raises(ValueError, match=r"a test needs about 1024.0 GiB of memory; .* GiB is available"):
        check_memory(2.0**40, "a test")
    check_memory(1024, "a test")  # a small allocation passes
