"""The extension build's wheel list: pinned as the project's environments pin them, written into the staged
manifest with the Blender range of its CPython (no network: the download is exercised by make build)."""

from __future__ import annotations

import os
import tomllib

import pytest

from material_structures.cli import build

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _pins(name: str) -> dict[str, str]:
    out = {}
    with open(os.path.join(ROOT, name)) as f:
        for line in f:
            line = line.split("#")[0].strip()
            if "==" in line:
                pkg, ver = line.split("==")
                out[pkg.split("[")[0].lower()] = ver
    return out


def test_wheels_are_pinned_as_the_environments():
    main, compat = _pins("requirements.txt"), _pins("requirements-compat.txt")
    for python, pins in (("3.13", main), ("3.11", compat)):
        for req in build.WHEELS[python]:
            pkg, ver = req.split("==")
            if pkg in pins:  # numba / llvmlite are not in the compat venv: the same as the main one
                assert pins[pkg] == ver, (python, req, pins[pkg])
            else:
                assert pkg in ("numba", "llvmlite") and main.get(pkg, ver) == ver, (python, req)


def test_staged_manifest_lists_wheels_platforms_and_range():
    with open(os.path.join(ROOT, "blender_manifest.toml")) as f:
        text = f.read()
    wheels = ["/x/scipy-1.13.1-cp311-cp311-win_amd64.whl", "/x/numba-0.68.1-cp311-cp311-win_amd64.whl"]
    m = tomllib.loads(build._staged_manifest(text, "3.11", wheels, ["windows-x64"]))
    assert m["wheels"] == ["./wheels/scipy-1.13.1-cp311-cp311-win_amd64.whl",
                           "./wheels/numba-0.68.1-cp311-cp311-win_amd64.whl"]
    assert m["platforms"] == ["windows-x64"]
    assert (m["blender_version_min"], m["blender_version_max"]) == ("4.5.0", "5.1.0")
    m = tomllib.loads(build._staged_manifest(text, "3.13", wheels, ["linux-x64", "macos-arm64"]))
    assert m["blender_version_min"] == "5.1.0" and "blender_version_max" not in m
    assert m["id"] == "material_structures" and m["build"]["paths_exclude_pattern"]


def test_checkout_manifest_leaves_wheels_to_the_build():
    with open(os.path.join(ROOT, "blender_manifest.toml")) as f:
        text = f.read()
    with pytest.raises(RuntimeError, match="written by the build"):
        build._staged_manifest(text + 'wheels = ["./wheels/x.whl"]\n', "3.13", [], ["linux-x64"])
