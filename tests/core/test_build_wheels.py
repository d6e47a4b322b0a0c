"""The extension build's wheel list: uv.lock's versions of pyproject's extra ``wheels``, as the project's
environments install them, written into the staged manifest with the Blender range of its CPython (no network:
the download is exercised by make build)."""

from __future__ import annotations

import os
import tomllib

import pytest

from material_structures.cli import build
from material_structures.core.errors import UserError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_zips_bundle_the_locked_wheels_the_environments_test():
    """Each zip bundles pyproject's extra ``wheels`` at uv.lock's versions for its CPython; the 4.5 compat and
    the main environment install that same extra (so the 4.5 tests run the tracer 4.5 users get)."""
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        extras = tomllib.load(f)["project"]["optional-dependencies"]
    assert "material-structures[wheels]" in extras["compat"] and "material-structures[compat]" in extras["dev"]
    for python in build.BLENDER_RANGE:
        pins = build.wheel_pins(python)
        assert [p.split("==")[0] for p in pins] == ["scipy", "numba", "llvmlite"], (python, pins)
        assert all(hashes for _, _, hashes in build.locked_wheels(python))  # pip checks the downloads against them
    assert build.wheel_pins("3.11")[0] != build.wheel_pins("3.13")[0]  # scipy differs: 1.18 needs CPython 3.12+


def test_wheels_match_this_environment():
    """The running project venv holds the versions the zip of its CPython bundles (uv sync --locked)."""
    import importlib.metadata
    import sys

    python = f"{sys.version_info[0]}.{sys.version_info[1]}"
    if python not in build.BLENDER_RANGE:
        pytest.skip(f"no zip for CPython {python}")
    for pin in build.wheel_pins(python):
        name, version = pin.split("==")
        try:
            assert importlib.metadata.version(name) == version, pin
        except importlib.metadata.PackageNotFoundError:
            pytest.skip(f"{name} is not installed here (not a project venv)")


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
    with pytest.raises(UserError, match="written by the build"):
        listed = text.replace("[permissions]", 'wheels = ["./wheels/x.whl"]\n\n[permissions]')
        build._staged_manifest(listed, "3.13", [], ["linux-x64"])
