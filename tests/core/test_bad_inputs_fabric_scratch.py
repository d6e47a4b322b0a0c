"""Bad input to the fabric and scratch commands: each case is a one-line ``error: ...`` naming the problem
(exit 1; a bad command line: 2), nothing written, no traceback; the input folder is byte-identical afterwards."""

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


RUNTIME_ERRORS = ("16 light/view pairs cover 0 of the", "GiB of memory;", "is more than the tables can address")


@pytest.mark.parametrize("argv, said", [
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--no-dask"], "16 light/view pairs cover 0 of the"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--workers", "1"], "16 light/view pairs cover 0 of the"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--tile", "0"], "--tile: must be >= 1, got 0"),
    (["fabric", "fit", "{d}/btf16", "--out", "{o}/fit", "--workers", "-3"], "--workers: must be >= 1, got -3"),
    (["fabric", "synth", "--out", "{o}/b", "--width", "-5"], "--width: must be >= 1, got -5"),
    (["fabric", "synth", "--out", "{o}/b", "--lights", "0"], "--lights: must be >= 1, got 0"),
    (["fabric", "synth", "--out", "{o}/b", "--noise", "nan"], "'nan' is not a finite number"),
    (["fabric", "synth", "--out", "{o}/b", "--theta-max-deg", "120"], "--theta-max-deg: must be <= 89, got 120"),
    (["fabric", "ndf", "{d}/btf16", "--size", "0", "--out", "{o}/n.exr"], "--size: must be >= 4"),
    (["scratch", "generate", "--count", "-5", "--out", "{o}/g.npz"], "--count: must be >= 1, got -5"),
    (["scratch", "generate", "--count", "50000000", "--out", "{o}/g.npz"], "--count: must be <= 16777216"),
    (["scratch", "generate", "--sigma-um", "nan", "--out", "{o}/g.npz"], "--sigma-um: 'nan' is not a finite"),
    (["scratch", "generate", "--patch-mm", "0", "--out", "{o}/g.npz"], "--patch-mm: must be >= 0.001, got 0"),
    (["scratch", "eval", "{d}/s.npz", "--size", "200000", "--out", "{o}/e.exr"], "--size: must be <= 16384"),
    (["scratch", "eval", "{d}/s.npz", "--light", "0", "0", "1", "0", "--out", "{o}/e.exr"], "radius R must be > 0"),
    (["scratch", "eval", "{d}/s.npz", "--view-deg", "inf", "--out", "{o}/e.exr"], "'inf' is not a finite number"),
    (["fabric", "synth", "--out", "{o}/b", "--width", "1000000"], "--width: must be <= 16384, got 1000000"),
    (["fabric", "synth", "--out", "{o}/b", "--width", "16384", "--height", "16384", "--lights", "1024", "--views",
      "1024"], "GiB of memory;"),
    (["teeth", "synth", "--out", "{o}/t", "--width", "100000"], "--width: must be <= 16384, got 100000"),
    (["teeth", "synth", "--out", "{o}/t", "--lights", "10000000"], "--lights: must be <= 4096"),
    (["teeth", "synth", "--out", "{o}/t", "--mesh-resolution", "100000"], "--mesh-resolution: must be <= 1024"),
    (["scratch", "generate", "--patch-mm", "10000", "--sigma-um", "0.1", "--max-footprint-um", "0.1", "--count",
      "10", "--out", "{o}/g.npz"], "is more than the tables can address"),
])
def test_bad_numbers_and_unfittable_btfs_are_one_line_errors(inputs, tmp_path, capsys, argv, said):
    before = _tree(inputs)
    runtime = said in RUNTIME_ERRORS  # found in the files or the machine: 1; a bad command line: 2
    assert main([a.format(d=inputs, o=tmp_path) for a in argv]) == (1 if runtime else 2)
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert _tree(inputs) == before
    assert list(tmp_path.iterdir()) == []  # nothing written, not even a cache folder


def test_work_larger_than_memory_is_refused_before_allocating():
    with pytest.raises(ValueError, match=r"a test needs about 1024.0 GiB of memory; .* GiB is available"):
        check_memory(2.0**40, "a test")
    check_memory(1024, "a test")  # a small allocation passes


@pytest.mark.heavy  # 5-10 s each: outside `make test-fast`
@pytest.mark.parametrize("pool", ["--no-dask", "dask"])
def test_sigterm_stops_a_fabric_fit_with_its_workers_and_it_resumes(tmp_path, pool):
    import subprocess
    import sys

    from ._interrupt import interrupt_when

    btf, out = tmp_path / "btf", tmp_path / "fit"
    # 36 tiles of 4 x 4 texels: 6-11 are done when the fit has stopped (2 workers), the rest fitted on resuming
    assert main(["fabric", "synth", "--out", str(btf), "--width", "24", "--height", "24"]) == 0
    argv = [sys.executable, "-m", "material_structures", "fabric", "fit", str(btf), "--out", str(out), "--workers", "2",
            "--tile", "4", "--no-progress"] + (["--no-dask"] if pool == "--no-dask" else [])
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    tiles = out / ".fit_cache" / "tiles"
    interrupt_when(proc, lambda: tiles.is_dir() and len(list(tiles.rglob("*.npz"))) >= 4, 120)
    done = len(list(tiles.rglob("*.npz")))
    assert 4 <= done < 36
    r = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    import json

    assert json.loads(r.stdout)["tiles_fitted_this_run"] == 36 - done


@pytest.mark.parametrize("damage, said", [
    ("sigma0", "map 'sigma' must be > 0; 1 texels are not"),
    ("kd-1", "map 'kd' has negative albedo in 1 texels"),
    ("ks-nan", "ks.exr: 3 non-finite value(s)"),
    ("basis0", "map 'basis' has quaternions of zero length"),
    ("json", "params.json: not valid JSON"),
])
def test_parameter_maps_that_cannot_be_shaded_are_refused(tmp_path, capsys, damage, said):
    import numpy as np

    from material_structures.core.exr_io import read_exr, write_exr

    params = tmp_path / "params"
    assert main(["fabric", "synth", "--out", str(tmp_path / "btf"), "--width", "3", "--height", "3",
                 "--gt-out", str(params)]) == 0
    if damage == "json":
        (params / "params.json").write_text("{")
    else:
        name = {"sigma0": "sigma", "kd-1": "kd", "ks-nan": "ks", "basis0": "basis"}[damage]
        a = read_exr(str(params / f"{name}.exr"), channels=("R", "G", "B", "A")[:{"kd": 3, "ks": 3, "sigma": 2,
                                                                                  "basis": 4}[name]])
        a[1, 2] = {"sigma0": 0.0, "kd-1": -1.0, "ks-nan": np.nan, "basis0": 0.0}[damage]
        write_exr(str(params / f"{name}.exr"), a)
    capsys.readouterr()
    assert main(["fabric", "eval", str(params), "--directions", str(tmp_path / "btf"), "--out",
                 str(tmp_path / "pred")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and said in err and err.count("\n") == 1, err
    assert not (tmp_path / "pred").exists()


def test_an_unreadable_btf_image_leaves_no_cache_behind(tmp_path, capsys):
    btf = tmp_path / "btf"
    assert main(["fabric", "synth", "--out", str(btf), "--width", "4", "--height", "4", "--lights", "8", "--views",
                 "8"]) == 0
    (btf / "0005.exr").write_bytes(b"not an exr")
    capsys.readouterr()
    assert main(["fabric", "fit", str(btf), "--out", str(tmp_path / "fit"), "--no-dask", "--workers", "1",
                 "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "0005.exr" in err and err.count("\n") == 1, err
    assert not (tmp_path / "fit" / ".fit_cache").exists()
    assert not (tmp_path / "fit").exists()  # nor the (empty) output folder this fit made
    (tmp_path / "kept").mkdir()  # an output folder that was there before stays
    assert main(["fabric", "fit", str(btf), "--out", str(tmp_path / "kept"), "--no-dask", "--workers", "1",
                 "--no-progress"]) == 1
    assert (tmp_path / "kept").is_dir()


def test_an_error_after_the_progress_bar_started_is_a_line_of_its_own(tmp_path, capsys, monkeypatch):
    """A fit that fails with its tile bar on screen: the bar's line is ended first, the error is one line below."""
    from material_structures.core.errors import UserError
    from material_structures.core.fabric import btf_fitter

    def fail_after_one_tile(values, hdr, cache, todo, runner, done):
        done((todo[0], None, 3))
        raise UserError("a tile of the BTF could not be fitted")

    btf = tmp_path / "btf"
    assert main(["fabric", "synth", "--out", str(btf), "--width", "4", "--height", "4", "--lights", "8", "--views",
                 "8"]) == 0
    monkeypatch.setattr(btf_fitter, "fit_all_bands", fail_after_one_tile)
    capsys.readouterr()
    assert main(["fabric", "fit", str(btf), "--out", str(tmp_path / "fit"), "--no-dask", "--workers", "1",
                 "--tile", "2"]) == 1
    err = capsys.readouterr().err
    assert "fit tiles" in err and "1/4" in err, err  # the bar was drawn
    assert err.endswith("\nerror: a tile of the BTF could not be fitted\n"), err


def test_a_size_the_machine_cannot_hold_is_one_line(monkeypatch, capsys):
    import material_structures.cli.scratch as scratch_cli

    def allocate(args):
        raise MemoryError("Unable to allocate 8.00 TiB for an array with shape (1048576, 1048576)")

    monkeypatch.setattr(scratch_cli, "run_info", allocate)
    assert main(["scratch", "info", "whatever.npz"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: not enough memory for this size (Unable to allocate") and err.count("\n") == 1


@pytest.mark.parametrize("pool", [["--no-dask"], []])
def test_a_second_fabric_fit_into_a_busy_folder_is_refused(tmp_path, capsys, pool):
    import subprocess

    btf, out = tmp_path / "btf", tmp_path / "fit"
    assert main(["fabric", "synth", "--out", str(btf), "--width", "4", "--height", "4"]) == 0
    out.mkdir()
    other = subprocess.Popen(["sleep", "60"])  # stands for the first fit, still writing
    try:
        (out / ".fit.lock").write_text(str(other.pid))
        capsys.readouterr()
        assert main(["fabric", "fit", str(btf), "--out", str(out), "--no-progress", *pool]) == 1
        err = capsys.readouterr().err
        assert err.startswith("error: ") and f"another fit (process {other.pid})" in err and err.count("\n") == 1
        assert sorted(p.name for p in out.iterdir()) == [".fit.lock"]  # nothing of the second fit
    finally:
        other.kill()
        other.wait()
