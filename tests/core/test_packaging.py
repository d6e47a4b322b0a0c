"""A non-editable install ships every package: pyproject's list is the tree's packages, and a wheel
built from it holds every module of the tree and the OSL shaders."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SKIP = {"tests", "docs", "bench", "build", "dist", "out", "scripts"}


def _tree_packages() -> set[str]:
    found = set()
    for dirpath, dirnames, filenames in os.walk(ROOT):
        rel = os.path.relpath(dirpath, ROOT)
        dirnames[:] = [d for d in dirnames if not d.startswith(".") and d not in SKIP and d != "__pycache__"
                       and not d.endswith(".egg-info")]
        if "__init__.py" in filenames:
            found.add("material_structures" + ("" if rel == "." else "." + rel.replace(os.sep, ".")))
    return found


def test_pyproject_lists_every_package():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        listed = set(tomllib.load(f)["tool"]["setuptools"]["packages"])
    assert listed == _tree_packages()


@pytest.mark.slow
def test_wheel_holds_every_module(tmp_path):
    had_build = os.path.isdir(os.path.join(ROOT, "build"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                    str(tmp_path), ROOT], check=True, timeout=600)
    if not had_build:  # setuptools builds in the source tree
        shutil.rmtree(os.path.join(ROOT, "build"), ignore_errors=True)
    [wheel] = [p for p in os.listdir(tmp_path) if p.endswith(".whl")]
    names = set(zipfile.ZipFile(tmp_path / wheel).namelist())
    for pkg in _tree_packages():
        folder = os.path.join(ROOT, *pkg.split(".")[1:])
        for f in os.listdir(folder):
            if f.endswith(".py"):
                assert "/".join(pkg.split(".")) + "/" + f in names, (pkg, f)
    assert any(n.startswith("material_structures/cycles_osl/") and n.endswith(".osl") for n in names)
