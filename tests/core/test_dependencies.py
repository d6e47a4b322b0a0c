"""One place for each dependency and for the version: pyproject.toml says what each environment holds (humans
edit it), uv.lock the exact versions (``make lock`` writes it), blender_manifest.toml the version. A pin
(``NAME==VERSION``) anywhere else, a stale lock or a second version string fails here."""

from __future__ import annotations

import os
import re
import tomllib

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

import material_structures

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SKIP_DIRS = {".git", "build", "dist", "out", "samples", "__pycache__", ".pytest_cache", ".ruff_cache"}
TEXT = (".py", ".sh", ".toml", ".txt", ".md", ".cfg", ".ini", ".yml", ".yaml", ".json", "Makefile", "run")


def _load(name: str) -> dict:
    with open(os.path.join(ROOT, name), "rb") as f:
        return tomllib.load(f)


def _files():
    for dirpath, dirnames, filenames in os.walk(ROOT):
        dirnames[:] = [d for d in dirnames if d not in SKIP_DIRS and not d.startswith(".venv")
                       and not d.endswith(".egg-info")]
        for name in filenames:
            if name.endswith(TEXT) and os.path.getsize(os.path.join(dirpath, name)) < 2_000_000:
                yield os.path.relpath(os.path.join(dirpath, name), ROOT)


def test_pins_live_in_pyproject_and_uv_lock_only():
    names = {p["name"] for p in _load("uv.lock")["package"]} - {"material-structures"}
    alternation = "|".join(sorted({re.escape(n).replace(r"\-", "[-_.]") for n in names}, key=len, reverse=True))
    pin = re.compile(rf"(?<![\w.-])({alternation})(\[[\w,]+\])?\s*==\s*\d", re.IGNORECASE)
    found = []
    for rel in _files():
        if rel in ("uv.lock", "pyproject.toml"):
            continue
        with open(os.path.join(ROOT, rel), encoding="utf-8", errors="replace") as f:
            for n, line in enumerate(f, 1):
                if pin.search(line):
                    found.append(f"{rel}:{n}: {line.strip()}")
    assert not found, "pins outside pyproject.toml / uv.lock:\n" + "\n".join(found)
    assert not [r for r in os.listdir(ROOT) if r.startswith("requirements") and r.endswith(".txt")]


def test_pyproject_pins_a_package_once_per_python():
    project = _load("pyproject.toml")["project"]
    reqs = [Requirement(r) for r in project["dependencies"]]
    reqs += [Requirement(r) for extra in project["optional-dependencies"].values() for r in extra]
    seen = set()
    for req in reqs:
        if any(s.operator == "==" for s in req.specifier):
            key = (canonicalize_name(req.name), str(req.marker))
            assert key not in seen, f"{req} is pinned twice"
            seen.add(key)
    assert {name for name, _ in seen} == {"bpy", "numpy"}  # the Blender versions; everything else: uv.lock


def test_lock_is_up_to_date_with_pyproject():
    """uv.lock records the requirements it was resolved from; after an edit of pyproject's dependencies this
    fails until `make lock` (and bootstrap's `uv sync --locked` refuses the stale lock)."""
    project = _load("pyproject.toml")["project"]
    want = {(canonicalize_name(Requirement(r).name), str(Requirement(r).specifier), None)
            for r in project["dependencies"]}
    want |= {(canonicalize_name(Requirement(r).name), str(Requirement(r).specifier), extra)
             for extra, reqs in project["optional-dependencies"].items() for r in reqs}
    [root] = [p for p in _load("uv.lock")["package"] if p["name"] == "material-structures"]
    got = set()
    for r in root["metadata"]["requires-dist"]:
        extra = re.search(r"extra == '([\w-]+)'", r.get("marker", ""))
        got.add((r["name"], str(Requirement(r["name"] + r.get("specifier", "")).specifier),
                 extra.group(1) if extra else None))
    assert got == want, "uv.lock is stale: run `make lock`"
    assert sorted(root["metadata"]["provides-extras"]) == sorted(project["optional-dependencies"])


def test_version_lives_in_the_manifest_only():
    version = _load("blender_manifest.toml")["version"]
    pyproject = _load("pyproject.toml")
    assert "version" not in pyproject["project"] and "version" in pyproject["project"]["dynamic"]
    assert pyproject["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "material_structures.__version__"}
    assert material_structures.__version__ == version
    with open(os.path.join(ROOT, "__init__.py"), encoding="utf-8") as f:
        assert version not in f.read()
    assert "version" not in next(p for p in _load("uv.lock")["package"] if p["name"] == "material-structures")


def test_installed_metadata_has_the_manifest_version():
    import importlib.metadata

    try:
        installed = importlib.metadata.version("material-structures")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("material-structures is not installed here")
    assert installed == _load("blender_manifest.toml")["version"]
