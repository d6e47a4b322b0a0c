"""Structural guarantees of the package that hold without Blender."""

from __future__ import annotations

import ast
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


# The layers and what each may import (by package of ``material_structures``). ``core`` is the model; ``render`` is
# the headless harness, which knows no feature; ``addon`` is the Blender layer of the features; ``showcase``
# builds the sample library on both. Lazy imports (inside functions) count the same as top-level ones.
FORBIDDEN = {
    "core": {"addon", "render", "showcase", "cli", "scaleout", "benchmarks"},
    "render": {"addon", "showcase", "cli", "scaleout", "benchmarks"},
    "addon": {"showcase", "cli", "scaleout", "benchmarks"},
}
PACKAGE = "material_structures"


def _module_name(path: str, root: str) -> str:
    rel = os.path.relpath(path, root)[: -len(".py")].split(os.sep)
    if rel[-1] == "__init__":
        rel = rel[:-1]
    return ".".join([PACKAGE, *rel])


def imported_modules(path: str, root: str = ROOT) -> set[str]:
    """Absolute names of every module ``path`` (a file of the package rooted at ``root``) imports, anywhere
    in it (function bodies included); ``from X import Y`` counts as X and as X.Y (Y may be a submodule)."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), path)
    name = _module_name(path, root)
    package = name if path.endswith("__init__.py") else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.add(module)
            out.update(f"{module}.{alias.name}" for alias in node.names)
    return out


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == PACKAGE else None


def _python_files(folder: str):
    for dirpath, dirnames, files in os.walk(os.path.join(ROOT, folder)):
        dirnames[:] = [d for d in dirnames if d != "__pycache__"]
        yield from (os.path.join(dirpath, f) for f in sorted(files) if f.endswith(".py"))


def test_imported_modules_resolves_relative_and_lazy_imports(tmp_path):
    pkg = tmp_path / "render"
    pkg.mkdir()
    (pkg / "mod.py").write_text(
        "from .. import addon\nfrom ..showcase.library import x\nimport numpy\n"
        "def f():\n    from ...outside import y\n    from .scene import z\n"
    )
    found = imported_modules(str(pkg / "mod.py"), str(tmp_path))
    assert {"material_structures.addon", "material_structures.showcase.library", "numpy",
            "material_structures.render.scene"} <= found


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_import_direction(layer):
    """render (the harness) never imports addon or showcase, addon never imports showcase, core imports
    none of them: no cycle between the layers, and none hidden in a function body."""
    offenders = []
    files = list(_python_files(layer))
    assert files
    for path in files:
        for module in sorted(imported_modules(path)):
            if _layer(module) in FORBIDDEN[layer]:
                offenders.append(f"{os.path.relpath(path, ROOT)} imports {module}")
    assert offenders == []


def test_showcase_is_a_package_apart_from_the_harness():
    """The library's scenes, stage, contact sheet and asset library live in ``showcase/``; ``render/`` holds
    the harness only."""
    render = {os.path.basename(p) for p in _python_files("render")}
    assert render == {"__init__.py", "session.py", "osl.py", "scene.py", "output.py"}
    showcase = {os.path.basename(p) for p in _python_files("showcase")}
    assert {"library.py", "stage.py", "contact_sheet.py", "asset_library.py", "scenes.py"} <= showcase


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


def test_a_damaged_exr_keeps_what_else_the_process_prints(tmp_path, capfd):
    """Reading a damaged EXR holds the OpenEXR library's own lines (the error names the damage instead); lines
    another thread prints meanwhile still reach the terminal."""
    import threading

    write_exr(tmp_path / "ok.exr", np.random.default_rng(0).random((64, 64, 3)))
    data = (tmp_path / "ok.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[: len(data) // 2])
    stop = threading.Event()

    def talk():
        i = 0
        while not stop.is_set():
            print(f"line {i}", flush=True)
            i += 1

    capfd.readouterr()
    thread = threading.Thread(target=talk)
    thread.start()
    try:
        for _ in range(50):
            with pytest.raises(ExrError, match="corrupt leader"):
                read_exr(tmp_path / "cut.exr")
    finally:
        stop.set()
        thread.join()
    out, err = capfd.readouterr()
    said = [int(ln.split()[1]) for ln in (out + err).splitlines() if ln.startswith("line ")]
    assert sorted(said) == list(range(max(said) + 1)), "a line of the other thread was lost"
    assert "EXR_ERR" not in out + err and "Warning" not in out + err


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
