"""Structural guarantees of the package that hold without Blender."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from material_structures.core.exr_io import ExrError, exr_channel_names, read_exr, write_exr

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_core_never_imports_bpy():
    """Import every module under core/ in a fresh interpreter; bpy must not be loaded."""
    code = (
        "import importlib, pkgutil, sys\n"
        "import material_structures.core as core\n"
        "names = [m.name for m in pkgutil.walk_packages(core.__path__, core.__name__ + '.')]\n"
        "for n in names: importlib.import_module(n)\n"
        "assert 'bpy' not in sys.modules, 'bpy imported'\n"
        "print(len(names))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 2


def test_core_sources_have_no_bpy_import_lines():
    offenders = []
    for dirpath, _, files in os.walk(os.path.join(ROOT, "core")):
        for f in files:
            if f.endswith(".py"):
                with open(os.path.join(dirpath, f)) as fh:
                    for line in fh:
                        s = line.strip()
                        if s.startswith(("import bpy", "from bpy")):
                            offenders.append(os.path.join(dirpath, f))
    assert offenders == []


def test_package_import_does_not_import_bpy():
    code = "import sys, material_structures, material_structures.cli; assert 'bpy' not in sys.modules"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_cli_help_lists_subcommands():
    proc = subprocess.run(
        [sys.executable, "-m", "material_structures", "--help"], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    for sub in ("render", "build", "bench", "demo"):
        assert sub in proc.stdout


def test_cli_reports_errors_cleanly():
    proc = subprocess.run(
        [sys.executable, "-m", "material_structures", "bench", "no-such-benchmark"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2
    assert "unknown benchmark" in proc.stderr and "Traceback" not in proc.stderr


def test_exr_roundtrip_exact(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 7, 3)).astype(np.float32)
    p = tmp_path / "a.exr"
    write_exr(p, a)
    np.testing.assert_array_equal(read_exr(p), a)
    b = rng.normal(size=(3, 2, 2)).astype(np.float32)
    write_exr(p, b, ["sigma_x", "sigma_y"])
    assert exr_channel_names(p) == ["sigma_x", "sigma_y"]
    np.testing.assert_array_equal(read_exr(p, ["sigma_y", "sigma_x"]), b[..., ::-1])


def test_exr_errors(tmp_path):
    with pytest.raises(ExrError, match="not found"):
        read_exr(tmp_path / "missing.exr")
    corrupt = tmp_path / "corrupt.exr"
    corrupt.write_bytes(b"v/1\x01" + b"\x00" * 64)
    with pytest.raises(ExrError, match="not a readable"):
        read_exr(corrupt)
    nan = np.zeros((2, 2, 3), np.float32)
    nan[1, 1, 2] = np.nan
    write_exr(tmp_path / "nan.exr", nan)
    with pytest.raises(ExrError, match="non-finite"):
        read_exr(tmp_path / "nan.exr")
    assert np.isnan(read_exr(tmp_path / "nan.exr", allow_nan=True)[1, 1, 2])
    with pytest.raises(ExrError, match="missing channel"):
        read_exr(tmp_path / "nan.exr", ["R", "Z"])
    with pytest.raises(ExrError, match="shape"):
        write_exr(tmp_path / "bad.exr", np.zeros(3))


def test_linear_to_srgb_matches_closed_form():
    from material_structures.core.imaging import linear_to_srgb

    x = np.array([0.0, 0.001, 0.0031308, 0.18, 0.5, 1.0, 2.0])
    expected = [0.0, 0.01292, 0.0404499, 0.4613561, 0.7353570, 1.0, 1.0]
    np.testing.assert_allclose(linear_to_srgb(x), expected, atol=1e-6)


def test_exr_backends_agree(tmp_path, monkeypatch):
    """The OpenEXR and the OpenImageIO (Blender-bundled) backends read and write the same data."""
    import glob

    import material_structures.core.exr_io as exr_io

    bundled = glob.glob(
        os.path.join(os.path.dirname(np.__file__), "..", "bpy", "*", "python", "lib", "*", "site-packages")
    )
    for path in bundled[:1]:
        monkeypatch.syspath_prepend(path)
    pytest.importorskip("OpenImageIO")
    a = np.random.default_rng(3).normal(size=(4, 6, 2)).astype(np.float32)
    monkeypatch.setattr(exr_io, "BACKEND", "oiio")
    write_exr(tmp_path / "oiio.exr", a, ["sigma_x", "sigma_y"])
    with pytest.raises(ExrError, match="not found"):
        read_exr(tmp_path / "missing.exr")
    from_oiio = read_exr(tmp_path / "oiio.exr", ["sigma_x", "sigma_y"])
    monkeypatch.setattr(exr_io, "BACKEND", "openexr")
    write_exr(tmp_path / "openexr.exr", a, ["sigma_x", "sigma_y"])
    np.testing.assert_array_equal(read_exr(tmp_path / "oiio.exr", ["sigma_x", "sigma_y"]), a)
    monkeypatch.setattr(exr_io, "BACKEND", "oiio")
    np.testing.assert_array_equal(read_exr(tmp_path / "openexr.exr", ["sigma_x", "sigma_y"]), a)
    np.testing.assert_array_equal(from_oiio, a)


def test_blender_script_entry_point(tmp_path):
    """``blender -b --python scripts/ms.py -- ARGS`` loads the checkout as the package, from anywhere."""
    proc = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "ms.py"), "--", "render", "--list"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert "test-card" in proc.stdout
